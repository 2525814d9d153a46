#include "obs_normalizer.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace farm {

ObsNormalizer::ObsNormalizer(int dim, double min_std) : mean_(dim, 0.0), m2_(dim, 0.0), min_std_(min_std) {
  if (dim <= 0) throw std::invalid_argument("ObsNormalizer: dim must be > 0, got " + std::to_string(dim));
}

void ObsNormalizer::update(const float* obs, int64_t rows) {
  if (rows <= 0) return;
  const int d = dim();
  // Batch moments first, then one merge: exact for any split of the data into batches.
  std::vector<double> bm(d, 0.0), bm2(d, 0.0);
  for (int64_t r = 0; r < rows; ++r)
    for (int i = 0; i < d; ++i) bm[i] += obs[r * d + i];
  for (int i = 0; i < d; ++i) bm[i] /= double(rows);
  for (int64_t r = 0; r < rows; ++r)
    for (int i = 0; i < d; ++i) {
      const double x = obs[r * d + i] - bm[i];
      bm2[i] += x * x;
    }
  const double n = count_ + double(rows);
  for (int i = 0; i < d; ++i) {
    const double delta = bm[i] - mean_[i];
    mean_[i] += delta * double(rows) / n;
    m2_[i] += bm2[i] + delta * delta * count_ * double(rows) / n;
  }
  count_ = n;
}

std::vector<float> ObsNormalizer::mean() const {
  std::vector<float> m(mean_.begin(), mean_.end());
  return m;
}

std::vector<float> ObsNormalizer::std() const {
  std::vector<float> s(mean_.size(), 1.f);
  if (count_ < 2) return s;
  for (size_t i = 0; i < s.size(); ++i) s[i] = float(std::max(std::sqrt(m2_[i] / count_), min_std_));
  return s;
}

void ObsNormalizer::set_state(double count, std::vector<double> mean, std::vector<double> m2) {
  if (mean.size() != mean_.size() || m2.size() != mean_.size())
    throw std::invalid_argument("ObsNormalizer: saved state has " + std::to_string(mean.size()) +
                                " entries, expected " + std::to_string(mean_.size()));
  count_ = count;
  mean_ = std::move(mean);
  m2_ = std::move(m2);
}

}  // namespace farm
