// What the SAC unit tests share (test_sac.cpp, test_sac_cuda.cpp): a small config, random
// batches and replays, and comparisons of networks and update figures.
#pragma once

#include "device_replay.h"
#include "paths.h"  // remove_tree: std::filesystem::remove_all crashes the GPU build
#include "sac.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

namespace farm::sac_test {

inline config::SacConfig small_config() {
  config::SacConfig cfg;
  cfg.add_hidden(32);
  cfg.add_hidden(32);
  return cfg;
}

inline SampledBatch random_batch(int rows, int obs_dim, int act_dim, uint64_t seed) {
  torch::manual_seed(seed);
  SampledBatch b;
  b.obs = torch::randn({rows, obs_dim});
  b.actions = torch::rand({rows, act_dim}) * 2 - 1;
  b.rewards = torch::randn({rows});
  b.terminated = (torch::rand({rows}) < 0.1).to(torch::kFloat32);
  b.next_obs = torch::randn({rows, obs_dim});
  return b;
}

inline std::vector<torch::Tensor> copies(const std::vector<torch::Tensor>& ts) {
  std::vector<torch::Tensor> out;
  for (const auto& t : ts) out.push_back(t.detach().clone());
  return out;
}

inline std::string temp_dir(const std::string& name) {
  const auto d = std::filesystem::temp_directory_path() / (name + "_" + std::to_string(::getpid()));
  farm::remove_tree(d.string());
  return d.string();
}

inline bool all_equal(const std::vector<torch::Tensor>& a, const std::vector<torch::Tensor>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    if (!torch::equal(a[i], b[i])) return false;
  return true;
}

// |a - b| relative to b's norm, over a network's parameter tensors.
inline double relative_difference(const std::vector<torch::Tensor>& a, const std::vector<torch::Tensor>& b) {
  double num = 0, den = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    num += (a[i] - b[i]).to(torch::kDouble).square().sum().item<double>();
    den += b[i].to(torch::kDouble).square().sum().item<double>();
  }
  return std::sqrt(num / den);
}

inline void expect_stats_near(const SacStats& got, const SacStats& want, double tol, int update) {
  auto near = [&](double g, double w, const char* name) {
    EXPECT_LE(std::abs(g - w), tol * std::max(1.0, std::abs(w))) << name << " at update " << update;
  };
  near(got.critic_loss, want.critic_loss, "critic_loss");
  near(got.actor_loss, want.actor_loss, "actor_loss");
  near(got.alpha_loss, want.alpha_loss, "alpha_loss");
  near(got.alpha, want.alpha, "alpha");
  near(got.entropy, want.entropy, "entropy");
  near(got.q_mean, want.q_mean, "q_mean");
}

// small_config() on the GPU, and the same config updating eagerly (no CUDA graph): the pair the
// SacCuda tests hold against each other.
inline config::SacConfig cuda_config() {
  auto cfg = small_config();
  cfg.set_device("cuda");
  return cfg;
}

inline config::SacConfig without_graph(config::SacConfig cfg) {
  cfg.set_cuda_graph(false);
  return cfg;
}

// A DeviceReplay of `rows` random transitions (obs 3, act 2) on `device`, with its host twin;
// horizons 1, 2, 3, 1, ... (multi-step rows, sac.n_step 3).
inline void fill_replays(ReplayBuffer& host, DeviceReplay& dev, int rows, uint64_t seed) {
  const SampledBatch r = random_batch(rows, 3, 2, seed);
  const auto term = r.terminated.to(torch::kUInt8).contiguous();
  std::vector<float> horizon(rows);
  for (int k = 0; k < rows; ++k) horizon[k] = float(1 + k % 3);
  host.add_n(rows, r.obs.data_ptr<float>(), r.actions.data_ptr<float>(), r.rewards.data_ptr<float>(),
             term.data_ptr<uint8_t>(), r.next_obs.data_ptr<float>(), horizon.data());
  dev.add_n(rows, r.obs.data_ptr<float>(), r.actions.data_ptr<float>(), r.rewards.data_ptr<float>(),
            term.data_ptr<uint8_t>(), r.next_obs.data_ptr<float>(), horizon.data());
}

// The rows of `host` at indices [B] (int64, CPU), as ReplayBuffer::sample lays them out.
inline SampledBatch rows_at(const ReplayBuffer& host, const torch::Tensor& idx) {
  const SampledBatch s = host.stored();
  return {s.obs.index_select(0, idx),        s.actions.index_select(0, idx),  s.rewards.index_select(0, idx),
          s.terminated.index_select(0, idx), s.next_obs.index_select(0, idx), s.horizon.index_select(0, idx)};
}

}  // namespace farm::sac_test
