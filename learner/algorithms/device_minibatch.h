// What the networks of TD3 and FastSAC take of a minibatch drawn on the host: its rows on their
// device, the observations normalized with the learner's running moments as the workers normalize
// them, and each row's discount gamma^h * (1 - terminated) for its horizon h (fold_horizon).
#pragma once

#include <torch/torch.h>

#include "obs_normalizer.h"
#include "replay_buffer.h"

namespace farm {

// (obs - mean) / std of `moments` on `device`; obs as it is where moments is null.
inline torch::Tensor normalized_obs(const torch::Tensor& obs, const ObsNormalizer* moments, torch::Device device) {
  if (!moments) return obs;
  const auto mean = torch::tensor(moments->mean()).to(device), std = torch::tensor(moments->std()).to(device);
  return (obs - mean) / std;
}

struct DeviceMinibatch {
  torch::Tensor obs, next_obs, actions, rewards, discount;
};

inline DeviceMinibatch device_minibatch(const SampledBatch& sampled, double gamma, torch::Device device,
                                        const ObsNormalizer* moments) {
  // gamma * (1 - terminated) of the folded batch is gamma^h * (1 - terminated) of the row.
  const SampledBatch host = fold_horizon(sampled, gamma);
  const auto on = [&](const torch::Tensor& t) { return device.is_cpu() ? t : t.to(device); };
  return {normalized_obs(on(host.obs), moments, device), normalized_obs(on(host.next_obs), moments, device),
          on(host.actions), on(host.rewards), (1.0 - on(host.terminated)) * gamma};
}

}  // namespace farm
