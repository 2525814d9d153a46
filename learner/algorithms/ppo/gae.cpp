#include "gae.h"

#include <algorithm>
#include <cmath>

namespace farm {

void compute_gae(const float* rewards, const float* values, const float* next_values, const uint8_t* terminated,
                 const uint8_t* truncated, int64_t n, double gamma, double lambda, float* advantages, float* returns) {
  double next_adv = 0.0;
  for (int64_t t = n - 1; t >= 0; --t) {
    const double future = terminated[t] ? 0.0 : double(next_values[t]);
    const double delta = double(rewards[t]) + gamma * future - double(values[t]);
    const bool cut = terminated[t] || truncated[t];  // the next step starts another episode
    next_adv = delta + (cut ? 0.0 : gamma * lambda * next_adv);
    advantages[t] = float(next_adv);
    returns[t] = float(next_adv + double(values[t]));
  }
}

void compute_vtrace(const float* rewards, const float* values, const float* next_values, const uint8_t* terminated,
                    const uint8_t* truncated, const float* log_ratio, int64_t n, double gamma, double lambda,
                    double rho_bar, double c_bar, float* advantages, float* returns) {
  double next_adv = 0.0;
  for (int64_t t = n - 1; t >= 0; --t) {
    // exp of a clamped log: a far-off action's ratio cannot overflow before it is truncated.
    const double ratio = std::exp(std::min(double(log_ratio[t]), 50.0));
    const double rho = std::min(rho_bar, ratio), c = lambda * std::min(c_bar, ratio);
    const double future = terminated[t] ? 0.0 : double(next_values[t]);
    const double delta = rho * (double(rewards[t]) + gamma * future - double(values[t]));
    const bool cut = terminated[t] || truncated[t];
    next_adv = delta + (cut ? 0.0 : gamma * c * next_adv);
    advantages[t] = float(next_adv);
    returns[t] = float(next_adv + double(values[t]));
  }
}

}  // namespace farm
