// What the unit tests of the C51 learners (test_td3, test_fastsac) share: random minibatches,
// parameter snapshots, a fresh temporary folder, and distributions compared row by row.
#pragma once

#include <gtest/gtest.h>
#include <torch/torch.h>
#include <unistd.h>

#include <filesystem>
#include <string>
#include <vector>

#include "paths.h"  // remove_tree: std::filesystem::remove_all crashes the GPU build
#include "replay_buffer.h"

namespace farm::c51_test {

// rows one-step transitions, ~10 % of them terminal, drawn from LibTorch seeded with `seed`.
inline SampledBatch random_batch(int rows, int obs_dim, int act_dim, uint64_t seed) {
  torch::manual_seed(seed);
  SampledBatch b;
  b.obs = torch::randn({rows, obs_dim}) * 2 + 1;
  b.actions = torch::rand({rows, act_dim}) * 2 - 1;
  b.rewards = torch::randn({rows});
  b.terminated = (torch::rand({rows}) < 0.1).to(torch::kFloat32);
  b.next_obs = torch::randn({rows, obs_dim}) * 2 + 1;
  return b;
}

inline std::vector<torch::Tensor> copies(const std::vector<torch::Tensor>& ts) {
  std::vector<torch::Tensor> out;
  for (const auto& t : ts) out.push_back(t.detach().clone());
  return out;
}

inline bool all_equal(const std::vector<torch::Tensor>& a, const std::vector<torch::Tensor>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    if (!torch::equal(a[i], b[i])) return false;
  return true;
}

// TMP/<name>_<pid>, removed if it is there.
inline std::string temp_dir(const std::string& name) {
  const auto d = std::filesystem::temp_directory_path() / (name + "_" + std::to_string(::getpid()));
  remove_tree(d.string());
  return d.string();
}

inline void expect_rows(const torch::Tensor& got, const std::vector<std::vector<double>>& want,
                        const std::string& what = "", double tol = 1e-6) {
  ASSERT_EQ(got.size(0), int64_t(want.size())) << what;
  const auto g = got.to(torch::kDouble).contiguous();
  for (size_t r = 0; r < want.size(); ++r)
    for (size_t k = 0; k < want[r].size(); ++k)
      EXPECT_NEAR(g[r][k].item<double>(), want[r][k], tol) << what << " row " << r << ", atom " << k;
}

}  // namespace farm::c51_test
