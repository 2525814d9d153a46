// The learner trains in LibTorch and the workers act in Eigen: the exported flat parameters must
// mean the same network on both sides.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "mlp.h"
#include "sac.h"

namespace farm {
namespace {

config::SacConfig net_config(std::vector<int> hidden) {
  config::SacConfig cfg;
  for (int h : hidden) cfg.add_hidden(h);
  return cfg;
}

// Some training first, so the exported weights are not only the initial ones.
void train_a_little(Sac& sac, int obs_dim, int act_dim) {
  for (int k = 0; k < 5; ++k) {
    SampledBatch b;
    b.obs = torch::randn({64, obs_dim});
    b.actions = torch::rand({64, act_dim}) * 2 - 1;
    b.rewards = torch::randn({64});
    b.terminated = torch::zeros({64});
    b.next_obs = torch::randn({64, obs_dim});
    sac.update(b);
  }
}

// The raw actor output [mean | log_std] from the live LibTorch parameters.
torch::Tensor actor_output(const Sac& sac, const torch::Tensor& obs) {
  torch::NoGradGuard no_grad;
  const auto p = sac.actor_parameters();
  torch::Tensor x = obs;
  for (size_t i = 0; i < p.size(); i += 2) {
    x = torch::addmm(p[i + 1], x, p[i].t());
    if (i + 2 < p.size()) x = torch::relu(x);
  }
  return x;
}

struct Shape {
  int obs, act;
  std::vector<int> hidden;
};

class PolicyExport : public ::testing::TestWithParam<Shape> {};

TEST_P(PolicyExport, DeterministicActionsMatchTorchActor) {
  const Shape s = GetParam();
  Sac sac(net_config(s.hidden), s.obs, s.act, 17);
  train_a_little(sac, s.obs, s.act);
  Policy policy(sac.export_policy(3));
  ASSERT_EQ(policy.obs_dim(), s.obs);
  ASSERT_EQ(policy.act_dim(), s.act);
  EXPECT_EQ(policy.version(), 3u);

  const int rows = 200;
  torch::manual_seed(5);
  const auto obs = (torch::randn({rows, s.obs}) * 2).contiguous();
  const auto want = sac.deterministic_action(obs).contiguous();
  std::vector<float> got(size_t(rows) * s.act);
  std::mt19937_64 rng(1);
  policy.act(obs.data_ptr<float>(), rows, rng, /*deterministic=*/true, got.data(), nullptr);
  const float* w = want.data_ptr<float>();
  double worst = 0;
  for (size_t i = 0; i < got.size(); ++i) worst = std::max(worst, double(std::abs(got[i] - w[i])));
  EXPECT_LE(worst, 1e-5);
}

// Sampled actions: the worker's log_prob must be the learner's log-density of the same action,
// which checks the [mean | log_std] split, the log_std clamp and the squashing correction.
TEST_P(PolicyExport, SampledLogProbMatchesTorchDensity) {
  const Shape s = GetParam();
  auto cfg = net_config(s.hidden);
  cfg.set_log_std_max(0.5);  // a clamp that binds for some rows
  Sac sac(cfg, s.obs, s.act, 23);
  train_a_little(sac, s.obs, s.act);
  Policy policy(sac.export_policy(1));

  const int rows = 200;
  torch::manual_seed(6);
  const auto obs = (torch::randn({rows, s.obs}) * 2).contiguous();
  std::vector<float> act(size_t(rows) * s.act), logp(rows);
  std::mt19937_64 rng(2);
  policy.act(obs.data_ptr<float>(), rows, rng, /*deterministic=*/false, act.data(), logp.data());

  const auto out = actor_output(sac, obs);
  const auto mean = out.narrow(1, 0, s.act);
  const auto log_std = out.narrow(1, s.act, s.act).clamp(cfg.log_std_min(), cfg.log_std_max());
  const auto a = torch::from_blob(act.data(), {rows, s.act}).clone();
  const auto want = squashed_gaussian_log_prob(mean, log_std, torch::atanh(a));
  int compared = 0;
  for (int r = 0; r < rows; ++r) {
    // Near |a| = 1 atanh amplifies float rounding of the action; those rows say nothing.
    if (a[r].abs().max().item<float>() > 0.95f) continue;
    ++compared;
    EXPECT_NEAR(logp[r], want[r].item<float>(), 2e-3) << "row " << r;
  }
  EXPECT_GT(compared, rows / 4);
}

INSTANTIATE_TEST_SUITE_P(Shapes, PolicyExport,
                         ::testing::Values(Shape{3, 1, {64, 64}}, Shape{5, 2, {32, 16, 8}}, Shape{3, 1, {}}));

}  // namespace
}  // namespace farm
