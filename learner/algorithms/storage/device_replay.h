// The replay buffer's rows on the device the networks train on, kept in step with the host's
// ReplayBuffer (the same rows at the same ring positions: add_n follows ReplayBuffer::add_n), so
// that an update draws its minibatch where it runs: on a GPU inside its CUDA graph
// (sac.replay_on_device), with no host sampling and no host-to-device copy per update. The host
// buffer stays what checkpoints write; this copy is rebuilt from it after a load (load_from).
#pragma once

#include <torch/torch.h>

#include <cstdint>
#include <string>

#include "replay_buffer.h"

namespace farm {

class DeviceReplay {
 public:
  // Allocates capacity rows on `device` up front (one tensor whose address a captured graph keeps).
  // gamma: the discount a row's horizon is folded in with (fold_horizon). Throws
  // std::runtime_error naming the size when the device cannot hold them.
  DeviceReplay(int64_t capacity, int obs_dim, int act_dim, torch::Device device, double gamma);

  // As ReplayBuffer::add_n. The horizon is not a column of its own: it is folded into the
  // terminated column (fold_horizon), so that updates whose target is r + gamma * (1 - t) * v
  // bootstrap with gamma^h. On a GPU the rows go in one asynchronous copy on the current stream, so
  // updates queued before it draw from the rows before it and those queued after it from the rows
  // with it.
  void add_n(int64_t n, const float* obs, const float* actions, const float* rewards, const uint8_t* terminated,
             const float* next_obs, const float* horizon = nullptr);
  // The host buffer's rows and ring position (after ReplayBuffer::load), horizons folded as in
  // add_n. Throws std::invalid_argument when its capacity or dims are not this copy's.
  void load_from(const ReplayBuffer& host);

  int64_t size() const { return size_; }
  int64_t capacity() const { return capacity_; }
  int obs_dim() const { return obs_dim_; }
  int act_dim() const { return act_dim_; }
  // A row's floats: obs | action | reward | terminated, horizon folded in (fold_horizon; 0/1 for
  // one-step rows) | next_obs.
  int width() const { return 2 * obs_dim_ + act_dim_ + 2; }
  torch::Device device() const { return rows_.device(); }
  const torch::Tensor& rows() const { return rows_; }  // [capacity, width]
  // [1] int64 on the device: size(), updated in stream order with the rows.
  const torch::Tensor& fill() const { return fill_; }

  // Row indices [B] (int64) for u [B] float64 uniform in [0, 1): floor(u * size), at most size - 1;
  // device work only (graph-safe), so the size is read from fill().
  torch::Tensor indices(const torch::Tensor& u) const;
  // `batch` rows drawn uniformly with replacement (u from the device's default generator, as
  // torch::rand draws it), split into contiguous fields on the device; horizon undefined (folded
  // into terminated).
  // Throws std::logic_error when empty.
  SampledBatch sample(int64_t batch) const;
  // The rows at indices(u) (one gather), its fields as views of them: device work only (graph-safe).
  SampledBatch draw(const torch::Tensor& u) const;

 private:
  int64_t capacity_;
  int obs_dim_, act_dim_;
  double gamma_;
  int64_t size_ = 0, next_ = 0;
  torch::Tensor rows_, fill_;
};

// Throws std::invalid_argument, naming `section` ("sac"), where `replay` is not on `networks`: an
// update draws its minibatch where its networks are.
void require_same_device(const DeviceReplay& replay, torch::Device networks, const std::string& section);

}  // namespace farm
