// Terrains of the mCLARI thesis §3.3: plain or rough (a height field) x normal / wet / extra-dry friction
// (table I), and the rough height field's generator.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace farm::robots::mclari {

constexpr int kNumTerrains = 6;
// 0 plain-normal, 1 plain-wet, 2 plain-dry, 3 rough-normal, 4 rough-wet, 5 rough-dry.
const char* terrain_name(int terrain);
inline bool terrain_is_rough(int terrain) { return terrain >= 3; }
inline int terrain_slipperiness(int terrain) { return terrain % 3; }  // 0 normal, 1 wet, 2 dry

// Samples n x n values from N(0, sigma) (row-major).
std::vector<float> gaussian_field(int n, double sigma, uint64_t seed);
// Maps min..max to 0..1 in place; a constant field becomes all 0.
void normalize_min_max(std::vector<float>& v);
// k x k mean filter (k odd), the mean over the in-bounds part of the window at the borders.
std::vector<float> mean_filter(const std::vector<float>& v, int n, int k);
// The thesis's rough field: gaussian_field, normalize_min_max, then mean_filter(k); values in [0, 1].
// Throws std::invalid_argument naming the parameter when n < 2, sigma <= 0 or k is not odd >= 1.
std::vector<float> rough_height_field(int n, double sigma, int k, uint64_t seed);

// 8-bit greyscale PNG of a field in [0, 1] (mCLARI thesis §3.3 stores it as a PNG for debugging);
// throws std::runtime_error naming the path when it cannot be written.
void write_height_png(const std::string& path, const std::vector<float>& v, int n);

}  // namespace farm::robots::mclari
