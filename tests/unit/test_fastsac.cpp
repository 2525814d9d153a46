// FastSAC (learner/algorithms/fastsac/): the soft C51 target, the temperature's and the actor's
// losses against hand computations, the critics' loss of an update recomputed by hand, the
// temperature's first AdamW step, the policy delay, the policy the workers receive, checkpoints, a
// large batch on the CPU, and a short learning problem.
#include "fastsac.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "c51_test_util.h"
#include "mlp.h"
#include "paths.h"  // remove_tree: std::filesystem::remove_all crashes the GPU build
#include "td3.h"    // c51_support, c51_expected_value

namespace farm {
namespace {

using namespace c51_test;

config::FastSacConfig small_config() {
  config::FastSacConfig cfg;
  for (int h : {32, 32}) cfg.add_hidden(h);
  for (int h : {32, 32}) cfg.add_critic_hidden(h);
  cfg.set_num_atoms(21);
  cfg.set_v_min(-5);
  cfg.set_v_max(5);
  cfg.set_batch_size(64);
  cfg.set_buffer_size(1000);
  cfg.set_learning_starts(0);
  return cfg;
}

torch::Tensor floats(const std::vector<double>& v) { return torch::tensor(v, torch::kFloat); }

// Five atoms at -2 .. 2 (spacing 1), temperature 0.5. Soft reward r - discount * alpha * log_prob:
//  row 0: r 0.5, discount 0.5, log_prob 1: 0.25; atoms go to 0.25 + 0.5 z = -0.75, -0.25, 0.25,
//         0.75, 1.25, fractional indices 1.25, 1.75, 2.25, 2.75, 3.25, each split 3:1 or 1:3
//         between its neighbours. Critic 1's (0.1, 0.2, 0.3, 0.3, 0.1) gives atom 1 0.075 + 0.05,
//         atom 2 0.025 + 0.15 + 0.225 + 0.075, atom 3 0.075 + 0.225 + 0.075, atom 4 0.025; critic
//         2's uniform 0.2 gives 0.2, 0.4, 0.35, 0.05 to atoms 1 to 4.
//  row 1: terminal (discount 0), r 0.25, log_prob 3: no entropy term; every atom to index 2.25.
//  row 2: r -1, discount 1, log_prob -2: soft reward -1 + 0.5 * 2 = 0, every atom stays.
struct SoftCase {
  torch::Tensor p1 = floats({0.1, 0.2, 0.3, 0.3, 0.1, 0.2, 0.2, 0.2, 0.2, 0.2, 0.4, 0.1, 0.1, 0.2, 0.2}).view({3, 5});
  torch::Tensor p2 = floats({0.2, 0.2, 0.2, 0.2, 0.2, 0.2, 0.2, 0.2, 0.2, 0.2, 0.4, 0.1, 0.1, 0.2, 0.2}).view({3, 5});
  torch::Tensor rewards = floats({0.5, 0.25, -1.0}), discount = floats({0.5, 0.0, 1.0});
  torch::Tensor log_prob = floats({1.0, 3.0, -2.0}), alpha = floats({0.5});
  std::vector<double> row1 = {0, 0, 0.75, 0.25, 0}, row2 = {0.4, 0.1, 0.1, 0.2, 0.2};
  std::vector<double> first = {0, 0.125, 0.475, 0.375, 0.025}, second = {0, 0.2, 0.4, 0.35, 0.05};
};

TEST(FastSacMath, SoftTargetMatchesHandComputation) {
  SoftCase h;
  // FastSAC's own: each critic learns its own target critic's projection.
  const auto own = fastsac_critic_target(h.p1, h.p2, h.rewards, h.discount, h.log_prob, h.alpha, -2, 2, false);
  ASSERT_EQ(own.sizes(), (std::vector<int64_t>{2, 3, 5}));
  expect_rows(own[0], {h.first, h.row1, h.row2}, "critic 1");
  expect_rows(own[1], {h.second, h.row1, h.row2}, "critic 2");
  // Clipped double Q: row 0's expected values are -0.125 + 0.375 + 0.05 = 0.3 and -0.2 + 0.35 +
  // 0.1 = 0.25: both critics learn critic 2's.
  const auto clipped = fastsac_critic_target(h.p1, h.p2, h.rewards, h.discount, h.log_prob, h.alpha, -2, 2, true);
  for (int c = 0; c < 2; ++c)
    expect_rows(clipped[c], {h.second, h.row1, h.row2}, "clipped, critic " + std::to_string(c));
}

TEST(FastSacMath, TemperatureLossMatchesHandComputation) {
  // alpha 0.2, log-probabilities 1 and -3 (entropy 1), target entropy 0.5: -0.2 * mean(1.5, -2.5) =
  // 0.1; its gradient in log_alpha is the same 0.1 > 0, so a descent step lowers the temperature
  // of a policy whose entropy is above the target.
  auto log_alpha = torch::full({1}, std::log(0.2)).requires_grad_(true);
  const auto loss = fastsac_temperature_loss(log_alpha, floats({1.0, -3.0}), 0.5);
  EXPECT_NEAR(loss.item<double>(), 0.1, 1e-6);
  loss.backward();
  EXPECT_NEAR(log_alpha.grad().item<double>(), 0.1, 1e-6);
  // Below the target (entropy 1 < 2) the gradient is negative: the temperature rises.
  auto again = torch::full({1}, std::log(0.2)).requires_grad_(true);
  fastsac_temperature_loss(again, floats({1.0, -3.0}), 2.0).backward();
  EXPECT_NEAR(again.grad().item<double>(), -0.2 * (3.0 - 1.0) / 2, 1e-6);
}

TEST(FastSacMath, ActorLossMatchesHandComputation) {
  // Critic values [[1, 2], [3, 0]], log-probabilities 0.5 and -1, alpha 0.1. The critics' mean,
  // 2 and 1: mean(0.05 - 2, -0.1 - 1) = -1.525. Their minimum, 1 and 0: mean(0.05 - 1, -0.1) = -0.525.
  const auto q = floats({1, 2, 3, 0}).view({2, 2});
  const auto lp = floats({0.5, -1.0});
  EXPECT_NEAR(fastsac_actor_loss(q, lp, floats({0.1}), false).item<double>(), -1.525, 1e-6);
  EXPECT_NEAR(fastsac_actor_loss(q, lp, floats({0.1}), true).item<double>(), -0.525, 1e-6);
  // No gradient reaches the temperature through the actor's loss.
  auto alpha = floats({0.1}).requires_grad_(true);
  auto lp_grad = lp.clone().requires_grad_(true);
  fastsac_actor_loss(q, lp_grad, alpha, false).backward();
  EXPECT_FALSE(alpha.grad().defined());
  EXPECT_TRUE(torch::allclose(lp_grad.grad(), floats({0.05, 0.05})));
}

TEST(FastSac, ConfigDefaultsAreFastSacs) {
  const config::FastSacConfig c;
  EXPECT_EQ(c.batch_size(), 8192);
  EXPECT_EQ(c.num_atoms(), 101);
  EXPECT_DOUBLE_EQ(c.v_min(), -20);
  EXPECT_DOUBLE_EQ(c.v_max(), 20);
  EXPECT_DOUBLE_EQ(c.gamma(), 0.97);
  EXPECT_DOUBLE_EQ(c.tau(), 0.125);
  EXPECT_EQ(c.policy_delay(), 4);
  EXPECT_DOUBLE_EQ(c.initial_alpha(), 0.001);
  EXPECT_DOUBLE_EQ(c.target_entropy_ratio(), 0.0);
  EXPECT_DOUBLE_EQ(c.weight_decay(), 0.001);
  EXPECT_DOUBLE_EQ(c.adam_beta2(), 0.95);
  EXPECT_FALSE(c.clipped_double_q());
  EXPECT_TRUE(c.critic_layer_norm());
  EXPECT_DOUBLE_EQ(c.samples_per_insert(), 16);  // 8 updates of 8192 rows per step of 4096 envs
  FastSac sac(c, 5, 2, 1);
  EXPECT_EQ(sac.hidden(), (std::vector<int>{512, 256, 128}));
  EXPECT_EQ(sac.critic_hidden(), (std::vector<int>{768, 384, 192}));
  EXPECT_EQ(sac.support().numel(), 101);
  EXPECT_NEAR(sac.alpha(), 0.001, 1e-9);
  EXPECT_DOUBLE_EQ(sac.target_entropy(), 0.0);
  // The head starts at zero mean and the middle of [-5, 0] as log-std.
  const auto out = sac.actor_output(torch::randn({16, 5}));
  EXPECT_TRUE(torch::equal(out.narrow(1, 0, 2), torch::zeros({16, 2})));
  EXPECT_TRUE(torch::allclose(out.narrow(1, 2, 2), torch::full({16, 2}, -2.5)));
}

// An update's critic loss, recomputed by hand from the critics' logits before it, on terminal
// rows (the target is the reward's projection alone, whatever the actor samples): reward 0.25 on
// atoms 0, 0.5, ... (spacing 0.5 on [-5, 5]) lands at index 10.5, half on atom 10 and half on 11;
// reward -1 lands on atom 8.
TEST(FastSac, CriticLossOfAnUpdateMatchesHandComputation) {
  FastSac sac(small_config(), 3, 2, 5);
  SampledBatch b = random_batch(4, 3, 2, 6);
  b.rewards = floats({0.25, -1.0, 0.25, -1.0});
  b.terminated = torch::ones({4});
  const auto logits = sac.critic_logits(b.obs, b.actions).to(torch::kDouble);
  double want = 0;
  for (int c = 0; c < 2; ++c)
    for (int r = 0; r < 4; ++r) {
      const auto log_p = torch::log_softmax(logits[c][r], -1);
      const double ce =
          r % 2 == 0 ? -(0.5 * log_p[10].item<double>() + 0.5 * log_p[11].item<double>()) : -log_p[8].item<double>();
      want += ce / 4;
    }
  const FastSacStats st = sac.update(b);
  EXPECT_NEAR(st.critic_loss, want, 1e-5);
  EXPECT_NEAR(st.alpha, small_config().initial_alpha(), 1e-9) << "the target's temperature is the one before its step";
}

// AdamW's first step moves log_alpha by lr against the gradient's sign, after the decay
// log_alpha * (1 - lr * weight_decay). The policy's entropy starts near that of N(0, e^-2.5) per
// dimension, below the default target 0: the temperature rises; with a target far below, it falls.
TEST(FastSac, TemperatureTakesAdamWsFirstStepTowardTheTargetEntropy) {
  for (double ratio : {0.0, 10.0}) {
    auto cfg = small_config();
    cfg.set_target_entropy_ratio(ratio);
    FastSac sac(cfg, 3, 2, 8);
    const FastSacStats st = sac.update(random_batch(32, 3, 2, 9));
    const double target = -2.0 * ratio;
    const double sign = st.entropy < target ? 1.0 : -1.0;
    EXPECT_EQ(sign, ratio == 0.0 ? 1.0 : -1.0) << "entropy " << st.entropy;
    const double want =
        std::log(cfg.initial_alpha()) * (1 - cfg.alpha_lr() * cfg.alpha_weight_decay()) + sign * cfg.alpha_lr();
    EXPECT_NEAR(std::log(sac.alpha()), want, 2e-6) << "ratio " << ratio;
  }
  auto fixed = small_config();
  fixed.set_autotune(false);
  FastSac sac(fixed, 3, 2, 8);
  sac.update(random_batch(32, 3, 2, 9));
  EXPECT_NEAR(sac.alpha(), fixed.initial_alpha(), 1e-9);
}

// The critics step every update, the actor at updates 1, 5, ... of delay 4 (FastSAC's i % 4 ==
// 1), the target critics by tau.
TEST(FastSac, ActorStepsOnceEveryPolicyDelayUpdatesAndTargetsMoveByTau) {
  const auto cfg = small_config();
  FastSac sac(cfg, 3, 2, 7);
  EXPECT_TRUE(all_equal(sac.critic_parameters(), sac.target_critic_parameters())) << "targets start as the critics";
  for (int i = 0; i < 8; ++i) {
    const auto actor = copies(sac.actor_parameters()), critic = copies(sac.critic_parameters());
    const auto target = copies(sac.target_critic_parameters());
    const FastSacStats st = sac.update(random_batch(32, 3, 2, 100 + i));
    const bool turn = i % 4 == 1;
    EXPECT_EQ(st.actor_stepped, turn) << "update " << i;
    EXPECT_EQ(!all_equal(actor, sac.actor_parameters()), turn) << "update " << i;
    EXPECT_FALSE(all_equal(critic, sac.critic_parameters())) << "update " << i;
    for (size_t k = 0; k < target.size(); ++k) {
      const auto want = target[k] + cfg.tau() * (sac.critic_parameters()[k] - target[k]);
      EXPECT_TRUE(torch::allclose(sac.target_critic_parameters()[k], want, 1e-5, 1e-7)) << "update " << i;
    }
    EXPECT_TRUE(std::isfinite(st.critic_loss) && std::isfinite(st.actor_loss) && std::isfinite(st.q_mean));
  }
}

// The workers' policy: the actor's squashed Gaussian with its log-std bounds and the learner's
// observation normalizer; at the start its std is e^-2.5.
TEST(FastSac, ExportedPolicyActsAsTheActor) {
  auto cfg = small_config();
  cfg.set_activation("elu");
  FastSac sac(cfg, 3, 2, 11);
  const auto seen = torch::randn({200, 3}) * 3 + 2;
  sac.observe(seen.data_ptr<float>(), 200);
  const PolicyParams p0 = sac.export_policy(0);
  EXPECT_EQ(p0.head, PolicyHead::kSquashedGaussian);
  EXPECT_EQ(p0.layout.sizes, (std::vector<int>{3, 32, 32, 4}));
  EXPECT_EQ(p0.layout.activation, Activation::kElu);
  EXPECT_EQ(p0.log_std_min, -5.f);
  EXPECT_EQ(p0.log_std_max, 0.f);
  ASSERT_EQ(p0.obs_mean.size(), 3u);
  EXPECT_NEAR(p0.obs_mean[0], seen.select(1, 0).mean().item<double>(), 1e-4);
  Policy initial(p0);
  const int n = 20000;
  std::vector<float> obs(size_t(n) * 3, 1.f), acts(size_t(n) * 2);
  std::mt19937_64 rng(1);
  initial.act(obs.data(), n, rng, false, acts.data(), nullptr);
  double s2 = 0;
  for (int r = 0; r < n; ++r) s2 += std::pow(std::atanh(double(acts[size_t(r) * 2])), 2);
  EXPECT_NEAR(std::sqrt(s2 / n), std::exp(-2.5), 0.003);

  for (int i = 0; i < 6; ++i) sac.update(random_batch(32, 3, 2, 200 + i));
  Policy policy(sac.export_policy(9));
  EXPECT_EQ(policy.version(), 9u);
  const auto probe = torch::randn({8, 3}) * 3 + 2;
  std::vector<float> a(16);
  policy.act(probe.data_ptr<float>(), 8, rng, true, a.data(), nullptr);
  const auto want = sac.deterministic_action(probe);
  ASSERT_GT(want.abs().max().item<double>(), 0) << "the actor has moved from its zero start";
  for (int i = 0; i < 16; ++i) EXPECT_NEAR(a[i], want.view(-1)[i].item<float>(), 1e-5) << i;
}

TEST(FastSac, SaveLoadGivesTheSameActionsAndContinuesIdentically) {
  const auto cfg = small_config();
  FastSac a(cfg, 3, 2, 21);
  const auto seen = torch::randn({100, 3}) * 2 + 1;
  a.observe(seen.data_ptr<float>(), 100);
  for (int i = 0; i < 3; ++i) a.update(random_batch(32, 3, 2, 300 + i));
  const std::string dir = temp_dir("farm_fastsac_roundtrip");
  a.save(dir);
  FastSac b(cfg, 3, 2, 99);  // other initial weights
  EXPECT_FALSE(all_equal(a.critic_parameters(), b.critic_parameters()));
  b.load(dir);
  EXPECT_EQ(b.updates(), 3);
  EXPECT_EQ(a.alpha(), b.alpha());
  const auto probe = torch::randn({16, 3});
  EXPECT_TRUE(torch::equal(a.actor_output(probe), b.actor_output(probe)));
  EXPECT_EQ(a.export_policy(1).params, b.export_policy(1).params);
  EXPECT_EQ(a.export_policy(1).obs_std, b.export_policy(1).obs_std);
  for (int i = 0; i < 4; ++i) {  // through the actor's next step (update 5)
    const auto batch = random_batch(32, 3, 2, 400 + i);
    torch::manual_seed(500 + i);  // the actor's samples
    const FastSacStats sa = a.update(batch);
    torch::manual_seed(500 + i);
    const FastSacStats sb = b.update(batch);
    EXPECT_EQ(sa.actor_stepped, sb.actor_stepped);
    EXPECT_EQ(sa.critic_loss, sb.critic_loss);
    EXPECT_EQ(sa.actor_loss, sb.actor_loss);
    EXPECT_EQ(sa.alpha_loss, sb.alpha_loss);
  }
  EXPECT_TRUE(all_equal(a.actor_parameters(), b.actor_parameters()));
  EXPECT_TRUE(all_equal(a.critic_parameters(), b.critic_parameters()));
  EXPECT_TRUE(all_equal(a.target_critic_parameters(), b.target_critic_parameters()));
  EXPECT_EQ(a.alpha(), b.alpha());

  // A file of other sizes or another support is refused, naming the file.
  auto wider = cfg;
  wider.set_critic_hidden(0, 48);
  FastSac c(wider, 3, 2, 1);
  try {
    c.load(dir);
    FAIL() << "loaded networks of other sizes";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(dir + "/fastsac.pt"), std::string::npos) << e.what();
  }
  auto shifted = cfg;
  shifted.set_v_max(6);
  FastSac d(shifted, 3, 2, 1);
  EXPECT_THROW(d.load(dir), std::runtime_error);
  remove_tree(dir);
}

// A batch of 4,096 on the CPU with the default networks (768-384-192 critics of 101 atoms with
// layer norm): two updates, the second with the actor's step, all finite.
TEST(FastSac, LargeBatchOnTheCpuIsFinite) {
  config::FastSacConfig cfg;
  cfg.set_device("cpu");
  FastSac sac(cfg, 17, 6, 3);
  const auto actor = copies(sac.actor_parameters());
  auto batch = random_batch(4096, 17, 6, 4);
  batch.rewards = batch.rewards * 5;
  const auto start = std::chrono::steady_clock::now();
  for (int i = 0; i < 2; ++i) {
    const FastSacStats st = sac.update(batch);
    EXPECT_TRUE(std::isfinite(st.critic_loss) && std::isfinite(st.actor_loss) && std::isfinite(st.q_mean) &&
                std::isfinite(st.entropy) && std::isfinite(st.alpha_loss));
    EXPECT_GT(st.critic_loss, 0);
  }
  EXPECT_FALSE(all_equal(actor, sac.actor_parameters()));
  for (const auto& t : sac.critic_parameters()) EXPECT_TRUE(torch::isfinite(t).all().item<bool>());
  std::printf("two updates at batch 4096: %.2f s\n",
              std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
}

// A one-step contextual bandit (every transition terminal, so the return is the reward): the
// actor's mean must move to the action that maximizes -(a - 0.6 s)^2, which the critics'
// distributions have to rank first; a sign error in the target, the loss or the actor's step
// leaves it far off.
TEST(FastSac, ActorLearnsContextualBandit) {
  auto cfg = small_config();
  cfg.clear_hidden();
  cfg.clear_critic_hidden();
  for (int h : {64, 64}) cfg.add_hidden(h);
  for (int h : {64, 64}) cfg.add_critic_hidden(h);
  cfg.set_num_atoms(51);
  cfg.set_v_min(-3);
  cfg.set_v_max(1);
  cfg.set_actor_lr(1e-3);
  cfg.set_critic_lr(1e-3);
  cfg.set_policy_delay(2);
  FastSac sac(cfg, 1, 1, 31);
  auto best = [](const torch::Tensor& obs) { return 0.6 * obs.select(1, 0); };
  torch::manual_seed(32);
  const auto probe = torch::rand({64, 1}) * 2 - 1;
  auto error = [&] { return (sac.deterministic_action(probe).select(1, 0) - best(probe)).abs().mean().item<double>(); };
  const double before = error();
  const auto start = std::chrono::steady_clock::now();
  for (int i = 0; i < 1200; ++i) {
    SampledBatch b;
    b.obs = torch::rand({128, 1}) * 2 - 1;
    b.actions = torch::rand({128, 1}) * 2 - 1;
    b.rewards = -(b.actions.select(1, 0) - best(b.obs)).square();
    b.terminated = torch::ones({128});
    b.next_obs = b.obs;
    sac.observe(b.obs.data_ptr<float>(), 128);
    sac.update(b);
  }
  const double after = error();
  std::printf("bandit: error %.3f -> %.3f in %.2f s\n", before, after,
              std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  EXPECT_LT(after, 0.1) << "before " << before;
  EXPECT_LT(after, 0.5 * before);
  // The critics' expected value at the best action is near its reward, 0.
  const auto q =
      c51_expected_value(torch::softmax(sac.critic_logits(probe, best(probe).unsqueeze(1)), -1), sac.support());
  EXPECT_NEAR(q.mean().item<double>(), 0.0, 0.15);
}

}  // namespace
}  // namespace farm
