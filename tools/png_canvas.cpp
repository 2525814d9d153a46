#include "png_canvas.h"

#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <stdexcept>

namespace farm::tools {

Canvas::Canvas(int width, int height, Rgb bg) : w_(width), h_(height), rgb_(size_t(width) * height * 3) {
  for (size_t i = 0; i < rgb_.size(); i += 3) {
    rgb_[i] = bg.r;
    rgb_[i + 1] = bg.g;
    rgb_[i + 2] = bg.b;
  }
}

void Canvas::pixel(int x, int y, Rgb c) {
  if (x < 0 || y < 0 || x >= w_ || y >= h_) return;
  uint8_t* p = &rgb_[(size_t(y) * w_ + x) * 3];
  p[0] = c.r;
  p[1] = c.g;
  p[2] = c.b;
}

void Canvas::fill_rect(double x0, double y0, double x1, double y1, Rgb c) {
  for (int y = int(std::floor(std::min(y0, y1))); y <= int(std::ceil(std::max(y0, y1))); ++y)
    for (int x = int(std::floor(std::min(x0, x1))); x <= int(std::ceil(std::max(x0, x1))); ++x) pixel(x, y, c);
}

void Canvas::fill_circle(double cx, double cy, double r, Rgb c) {
  for (int y = int(cy - r - 1); y <= int(cy + r + 1); ++y)
    for (int x = int(cx - r - 1); x <= int(cx + r + 1); ++x)
      if ((x + 0.5 - cx) * (x + 0.5 - cx) + (y + 0.5 - cy) * (y + 0.5 - cy) <= r * r) pixel(x, y, c);
}

void Canvas::fill_polygon(const std::vector<double>& xs, const std::vector<double>& ys, Rgb c) {
  const size_t n = xs.size();
  const double x0 = *std::min_element(xs.begin(), xs.end()), x1 = *std::max_element(xs.begin(), xs.end());
  const double y0 = *std::min_element(ys.begin(), ys.end()), y1 = *std::max_element(ys.begin(), ys.end());
  for (int y = int(y0); y <= int(y1) + 1; ++y) {
    for (int x = int(x0); x <= int(x1) + 1; ++x) {
      const double px = x + 0.5, py = y + 0.5;
      bool pos = false, neg = false;
      for (size_t i = 0; i < n; ++i) {
        const size_t j = (i + 1) % n;
        const double cross = (xs[j] - xs[i]) * (py - ys[i]) - (ys[j] - ys[i]) * (px - xs[i]);
        pos |= cross > 0;
        neg |= cross < 0;
      }
      if (!(pos && neg)) pixel(x, y, c);
    }
  }
}

void Canvas::line(double x0, double y0, double x1, double y1, double width, Rgb c) {
  const double len = std::hypot(x1 - x0, y1 - y0);
  const int n = std::max(1, int(len * 2));
  for (int i = 0; i <= n; ++i) {
    const double t = double(i) / n;
    fill_circle(x0 + t * (x1 - x0), y0 + t * (y1 - y0), width / 2, c);
  }
}

namespace {

void put_u32(std::string& s, uint32_t v) {
  for (int i = 3; i >= 0; --i) s.push_back(char((v >> (8 * i)) & 0xff));
}

void chunk(std::string& out, const char* type, const std::string& data) {
  put_u32(out, uint32_t(data.size()));
  std::string body(type, 4);
  body += data;
  out += body;
  put_u32(out, uint32_t(crc32(0, reinterpret_cast<const Bytef*>(body.data()), uInt(body.size()))));
}

}  // namespace

void Canvas::write_png(const std::string& path) const {
  std::string raw;
  raw.reserve(size_t(h_) * (w_ * 3 + 1));
  for (int y = 0; y < h_; ++y) {
    raw.push_back(0);  // filter: none
    raw.append(reinterpret_cast<const char*>(&rgb_[size_t(y) * w_ * 3]), size_t(w_) * 3);
  }
  uLongf zlen = compressBound(uLong(raw.size()));
  std::string z(zlen, '\0');
  if (compress2(reinterpret_cast<Bytef*>(z.data()), &zlen, reinterpret_cast<const Bytef*>(raw.data()),
                uLong(raw.size()), 9) != Z_OK) {
    throw std::runtime_error(path + ": zlib compression failed");
  }
  z.resize(zlen);
  std::string ihdr;
  put_u32(ihdr, uint32_t(w_));
  put_u32(ihdr, uint32_t(h_));
  ihdr += std::string("\x08\x02\x00\x00\x00", 5);  // 8-bit RGB, deflate, no filter, no interlace
  std::string png("\x89PNG\r\n\x1a\n", 8);
  chunk(png, "IHDR", ihdr);
  chunk(png, "IDAT", z);
  chunk(png, "IEND", "");
  std::ofstream out(path, std::ios::binary);
  out.write(png.data(), std::streamsize(png.size()));
  if (!out) throw std::runtime_error("cannot write " + path);
}

}  // namespace farm::tools
