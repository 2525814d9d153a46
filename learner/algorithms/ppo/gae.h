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

// V-trace (Espeholt et al. 2018, IMPALA, eq. 1) over the same segment, for steps made by an older
// policy: log_ratio[t] = log pi(a_t|s_t) - log mu(a_t|s_t), the current policy against the one that
// acted. With rho_t = min(rho_bar, e^log_ratio) and c_t = lambda * min(c_bar, e^log_ratio):
//   delta_t = rho_t * (r_t + gamma * (1 - terminated_t) * next_values_t - values_t)
//   A_t     = delta_t + gamma * c_t * (1 - terminated_t) * (1 - truncated_t) * A_{t+1}
// returns (the value targets v_t) = A_t + values_t, advantages = A_t. With every log_ratio 0 this
// is compute_gae exactly (lambda as IMPALA's trace factor).
void compute_vtrace(const float* rewards, const float* values, const float* next_values, const uint8_t* terminated,
                    const uint8_t* truncated, const float* log_ratio, int64_t n, double gamma, double lambda,
                    double rho_bar, double c_bar, float* advantages, float* returns);

}  // namespace farm
