// Running mean and variance of observations (Chan et al.'s parallel update), kept by the learner
// and shipped with every PolicyWeights, so that workers and learner normalize the same way.
#pragma once

#include <cstdint>
#include <vector>

namespace farm {

class ObsNormalizer {
 public:
  ObsNormalizer() = default;
  // min_std floors the shipped std so a constant observation entry does not divide by zero.
  explicit ObsNormalizer(int dim, double min_std = 1e-4);
  // Adds rows x dim observations (row-major).
  void update(const float* obs, int64_t rows);
  int dim() const { return int(mean_.size()); }
  double count() const { return count_; }
  // Mean and std as PolicyParams ships them: mean 0 and std 1 until anything was seen.
  std::vector<float> mean() const;
  std::vector<float> std() const;
  // Restores a saved state (checkpoint).
  void set_state(double count, std::vector<double> mean, std::vector<double> m2);
  const std::vector<double>& raw_mean() const { return mean_; }
  const std::vector<double>& raw_m2() const { return m2_; }

 private:
  std::vector<double> mean_, m2_;  // m2: sum of squared deviations
  double count_ = 0.0, min_std_ = 1e-4;
};

}  // namespace farm
