// What the off-policy algorithms (SAC, DQN) share about the size of their step: the learning-rate
// schedule (sac.lr_decay_*, dqn.lr_decay_*), and the start line's words for it, for n-step returns
// and for the larger step where the data outrun the updates (max_step_scale).
// The schedule: the configured rates fall linearly to `decay_to` times their value over the first
// `decay_updates` updates, then stay. The fall goes in 16 equal steps, so that a CUDA graph, which
// holds the rates it was captured with, is captured again at most 16 times.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>

#include "config_validator.h"

namespace farm {

// The factor on the configured rates after `updates` updates; 1 throughout where decay_updates is 0.
inline double lr_decay_factor(int64_t decay_updates, double decay_to, int64_t updates) {
  constexpr int kSteps = 16;
  if (decay_updates <= 0) return 1.0;
  const double progress = std::min(1.0, double(std::max<int64_t>(updates, 0)) / double(decay_updates));
  return 1.0 - (1.0 - decay_to) * std::floor(progress * kSteps) / kSteps;
}

// The factor on the configured rate of an update on batch * step_scale samples: sqrt(step_scale)
// (max_step_scale's rule), or where reference_batch > 0 sqrt(batch * step_scale / reference_batch),
// the square-root rule for Adam (dqn.lr_reference_batch) for any batch against the one the rate
// was tuned at.
inline double batch_lr_factor(int64_t batch, int step_scale, int64_t reference_batch) {
  if (reference_batch <= 0) return std::sqrt(double(step_scale));
  return std::sqrt(double(batch) * double(step_scale) / double(reference_batch));
}

// The start line's words for dqn.lr_reference_batch: ", learning rate x11.3 for its batch of 4096
// (rate tuned at 32)", or nothing where it is off or the factor is 1.
inline std::string batch_lr_phrase(int64_t batch, int64_t reference_batch) {
  if (reference_batch <= 0 || batch == reference_batch) return "";
  return ", learning rate x" + config_checks::num(batch_lr_factor(batch, 1, reference_batch)) + " for its batch of " +
         std::to_string(batch) + " (rate tuned at " + std::to_string(reference_batch) + ")";
}

// The start line's words for a schedule: ", learning rates to x0.1 over 400000 updates", or
// nothing where the rates stay.
inline std::string lr_decay_phrase(int64_t decay_updates, double decay_to) {
  if (decay_updates <= 0 || decay_to >= 1) return "";
  return ", learning rates to x" + config_checks::num(decay_to) + " over " + std::to_string(decay_updates) + " updates";
}

// The start line's words for n-step returns and the step scale of config section `section` ("sac",
// "dqn"): ", 3-step returns, step up to x4 where the data outrun the updates", or on the CPU, which
// keeps the configured step, ", the configured step (sac.max_step_scale is for a GPU learner)".
inline std::string step_phrase(const std::string& section, int n_step, int max_step_scale, bool on_gpu) {
  std::string s = n_step > 1 ? ", " + std::to_string(n_step) + "-step returns" : "";
  if (max_step_scale > 1)
    s += on_gpu ? ", step up to x" + std::to_string(max_step_scale) + " where the data outrun the updates"
                : ", the configured step (" + section + ".max_step_scale is for a GPU learner)";
  return s;
}

}  // namespace farm
