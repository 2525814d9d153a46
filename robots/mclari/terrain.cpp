#include "mclari/terrain.h"

#include <zlib.h>

#include <algorithm>
#include <cstdio>
#include <random>
#include <stdexcept>
#include <string>

#include "check.h"

namespace farm::robots::mclari {

const char* terrain_name(int terrain) {
  static const char* names[kNumTerrains] = {"plain-normal", "plain-wet", "plain-dry",
                                            "rough-normal", "rough-wet", "rough-dry"};
  if (terrain < 0 || terrain >= kNumTerrains) return "unknown";
  return names[terrain];
}

std::vector<float> gaussian_field(int n, double sigma, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> dist(0.0, sigma);
  std::vector<float> v(size_t(n) * n);
  for (auto& x : v) x = float(dist(rng));
  return v;
}

void normalize_min_max(std::vector<float>& v) {
  if (v.empty()) return;
  const auto [lo, hi] = std::minmax_element(v.begin(), v.end());
  const float a = *lo, span = *hi - *lo;
  for (auto& x : v) x = span > 0 ? (x - a) / span : 0.f;
}

std::vector<float> mean_filter(const std::vector<float>& v, int n, int k) {
  const int r = k / 2;
  std::vector<float> out(v.size());
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      double sum = 0;
      int count = 0;
      for (int di = -r; di <= r; ++di) {
        for (int dj = -r; dj <= r; ++dj) {
          const int a = i + di, b = j + dj;
          if (a < 0 || a >= n || b < 0 || b >= n) continue;
          sum += v[size_t(a) * n + b];
          ++count;
        }
      }
      out[size_t(i) * n + j] = float(sum / count);
    }
  }
  return out;
}

std::vector<float> rough_height_field(int n, double sigma, int k, uint64_t seed) {
  // The loader checks the config's hfield_* fields; these are the function's own arguments.
  farm::require(n >= 2, "rough_height_field: n (hfield_size) must be >= 2, got " + std::to_string(n));
  farm::require(sigma > 0, "rough_height_field: sigma (hfield_sigma) must be > 0, got " + std::to_string(sigma));
  farm::require(k >= 1 && k % 2 == 1,
                "rough_height_field: k (hfield_filter) must be odd and >= 1, got " + std::to_string(k));
  auto v = gaussian_field(n, sigma, seed);
  normalize_min_max(v);
  return mean_filter(v, n, k);
}

namespace {

void put_u32(std::vector<unsigned char>& out, uint32_t x) {
  for (int s = 24; s >= 0; s -= 8) out.push_back((unsigned char)(x >> s));
}

void put_chunk(std::vector<unsigned char>& out, const char* type, const std::vector<unsigned char>& data) {
  put_u32(out, uint32_t(data.size()));
  const size_t start = out.size();
  out.insert(out.end(), type, type + 4);
  out.insert(out.end(), data.begin(), data.end());
  const uLong crc = crc32(0L, out.data() + start, uInt(out.size() - start));
  put_u32(out, uint32_t(crc));
}

}  // namespace

void write_height_png(const std::string& path, const std::vector<float>& v, int n) {
  // Filter byte 0 (none) before every row, then zlib.
  std::vector<unsigned char> raw;
  raw.reserve(size_t(n) * (n + 1));
  for (int i = 0; i < n; ++i) {
    raw.push_back(0);
    for (int j = 0; j < n; ++j)
      raw.push_back((unsigned char)std::clamp(int(v[size_t(i) * n + j] * 255.f + 0.5f), 0, 255));
  }
  uLongf zlen = compressBound(uLong(raw.size()));
  std::vector<unsigned char> z(zlen);
  if (compress(z.data(), &zlen, raw.data(), uLong(raw.size())) != Z_OK)
    throw std::runtime_error("height field PNG " + path + ": zlib compression failed");
  z.resize(zlen);

  std::vector<unsigned char> png = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  std::vector<unsigned char> ihdr;
  put_u32(ihdr, uint32_t(n));
  put_u32(ihdr, uint32_t(n));
  ihdr.insert(ihdr.end(), {8, 0, 0, 0, 0});  // 8-bit greyscale, deflate, no filter, no interlace
  put_chunk(png, "IHDR", ihdr);
  put_chunk(png, "IDAT", z);
  put_chunk(png, "IEND", {});
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) throw std::runtime_error("height field PNG " + path + ": cannot open for writing");
  const bool ok = std::fwrite(png.data(), 1, png.size(), f) == png.size();
  if (std::fclose(f) != 0 || !ok) throw std::runtime_error("height field PNG " + path + ": write failed");
}

}  // namespace farm::robots::mclari
