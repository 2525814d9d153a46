// Generalized advantage estimation (Schulman et al. 2016) over one env's trajectory segment.
// Terminations and truncations both end an episode, but only a termination has no future:
// a truncated step (time limit) and the segment's last step bootstrap on the value of the true
// next observation.
#pragma once

#include <cstdint>

namespace farm {

// rewards, values (V(s_t)), next_values (V(s'_t), the observation after step t: the true final
// observation where an episode ended, the segment's bootstrap observation after its last step,
// else V(s_{t+1})), terminated and truncated: n entries each. Writes advantages and returns
// (advantage + value), n entries each.
//   delta_t = r_t + gamma * (1 - terminated_t) * next_values_t - values_t
//   A_t     = delta_t + gamma * lambda * (1 - terminated_t) * (1 - truncated_t) * A_{t+1}
// with A_n = 0.
void compute_gae(const float* rewards, const float* values, const float* next_values, const uint8_t* terminated,
                 const uint8_t* truncated, int64_t n, double gamma, double lambda, float* advantages, float* returns);

}  // namespace farm
