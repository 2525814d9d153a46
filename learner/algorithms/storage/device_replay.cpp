#include "device_replay.h"

#include <algorithm>
#include <cstring>
#include <stdexcept>
#include <string>

namespace farm {

DeviceReplay::DeviceReplay(int64_t capacity, int obs_dim, int act_dim, torch::Device device, double gamma)
    : capacity_(capacity), obs_dim_(obs_dim), act_dim_(act_dim), gamma_(gamma) {
  if (capacity <= 0 || obs_dim <= 0 || act_dim <= 0)
    throw std::invalid_argument("DeviceReplay: expected positive sizes, got capacity " + std::to_string(capacity) +
                                ", obs_dim " + std::to_string(obs_dim) + ", act_dim " + std::to_string(act_dim));
  try {
    rows_ = torch::empty({capacity, width()}, torch::TensorOptions().dtype(torch::kFloat).device(device));
    fill_ = torch::zeros({1}, torch::TensorOptions().dtype(torch::kLong).device(device));
  } catch (const c10::Error& e) {
    throw std::runtime_error("replay buffer on " + device.str() + ": cannot allocate " +
                             std::to_string(capacity * width() * int64_t(sizeof(float)) >> 20) + " MiB for " +
                             std::to_string(capacity) +
                             " rows (the section's buffer_size; its replay_on_device: false keeps "
                             "the buffer in host memory only): " +
                             e.what_without_backtrace());
  }
}

void DeviceReplay::add_n(int64_t n, const float* obs, const float* actions, const float* rewards,
                         const uint8_t* terminated, const float* next_obs, const float* horizon) {
  if (n <= 0) return;
  const RingPlacement at = place_in_ring(capacity_, next_, n);
  n = at.first + at.rest;
  const int w = width(), o = obs_dim_, a = act_dim_;
  auto packed = torch::empty({n, w}, torch::TensorOptions().dtype(torch::kFloat).pinned_memory(rows_.is_cuda()));
  float* p = packed.data_ptr<float>();
  for (int64_t i = 0; i < n; ++i, p += w) {
    const int64_t r = at.skip + i;
    std::memcpy(p, obs + r * o, sizeof(float) * o);
    std::memcpy(p + o, actions + r * a, sizeof(float) * a);
    p[o + a] = rewards[r];
    const float done = terminated[r] ? 1.f : 0.f;
    p[o + a + 1] = horizon ? fold_horizon(done, horizon[r], gamma_) : done;
    std::memcpy(p + o + a + 2, next_obs + r * o, sizeof(float) * o);
  }
  // One copy, or two where the ring wraps; the pinned source stays alive until they are done
  // (LibTorch's host allocator holds a block behind its pending copies).
  rows_.narrow(0, at.at, at.first).copy_(packed.narrow(0, 0, at.first), /*non_blocking=*/true);
  if (at.rest > 0) rows_.narrow(0, 0, at.rest).copy_(packed.narrow(0, at.first, at.rest), /*non_blocking=*/true);
  next_ = at.next_after;
  size_ = std::min(capacity_, size_ + n);
  fill_.fill_(size_);
}

void DeviceReplay::load_from(const ReplayBuffer& host) {
  if (host.capacity() != capacity_ || host.obs_dim() != obs_dim_ || host.act_dim() != act_dim_)
    throw std::invalid_argument(
        "DeviceReplay::load_from: the host buffer has capacity " + std::to_string(host.capacity()) + ", obs_dim " +
        std::to_string(host.obs_dim()) + ", act_dim " + std::to_string(host.act_dim()) + ", this copy " +
        std::to_string(capacity_) + ", " + std::to_string(obs_dim_) + ", " + std::to_string(act_dim_));
  const SampledBatch s = fold_horizon(host.stored(), gamma_);
  if (host.size() > 0)
    rows_.narrow(0, 0, host.size())
        .copy_(torch::cat({s.obs, s.actions, s.rewards.unsqueeze(1), s.terminated.unsqueeze(1), s.next_obs}, 1));
  size_ = host.size();
  next_ = host.next_row();
  fill_.fill_(size_);
}

torch::Tensor DeviceReplay::indices(const torch::Tensor& u) const {
  const auto fill = fill_.to(torch::kDouble);
  return torch::minimum(u.mul(fill).to(torch::kLong), fill_ - 1);
}

SampledBatch DeviceReplay::sample(int64_t batch) const {
  if (size_ == 0) throw std::logic_error("DeviceReplay::sample: the buffer is empty");
  SampledBatch b = draw(torch::rand({batch}, torch::TensorOptions().dtype(torch::kDouble).device(rows_.device())));
  for (torch::Tensor* t : {&b.obs, &b.actions, &b.rewards, &b.terminated, &b.next_obs}) *t = t->contiguous();
  return b;
}

SampledBatch DeviceReplay::draw(const torch::Tensor& u) const {
  const auto picked = rows_.index_select(0, indices(u));
  const int o = obs_dim_, a = act_dim_;
  SampledBatch b;
  b.obs = picked.narrow(1, 0, o);
  b.actions = picked.narrow(1, o, a);
  b.rewards = picked.select(1, o + a);
  b.terminated = picked.select(1, o + a + 1);
  b.next_obs = picked.narrow(1, o + a + 2, o);
  return b;
}

void require_same_device(const DeviceReplay& replay, torch::Device networks, const std::string& section) {
  const torch::Device& from = replay.device();
  if (from.type() != networks.type() || (from.has_index() && networks.has_index() && from.index() != networks.index()))
    throw std::invalid_argument(section + ": minibatches drawn on " + from.str() + " for networks on " +
                                networks.str());
}

}  // namespace farm
