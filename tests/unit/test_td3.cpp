// TD3 with distributional critics (learner/algorithms/td3/): the C51 projection and the loss
// against hand computations, the clipped double-Q choice, the policy delay, the policy the workers
// receive, checkpoints, a large batch on the CPU, and a short learning problem.
#include "td3.h"

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

namespace farm {
namespace {

using namespace c51_test;

config::Td3Config small_config() {
  config::Td3Config cfg;
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

// Five atoms at -2, -1, 0, 1, 2 (spacing 1).
//  row 0: r 0.5, discount 0.5: atoms go to -0.5, 0, 0.5, 1, 1.5, i.e. fractional indices 1.5, 2,
//         2.5, 3, 3.5: 0.1 splits 0.05 / 0.05 over atoms 1, 2; 0.2 lands on atom 2; 0.3 splits
//         0.15 / 0.15 over 2, 3; 0.3 lands on 3; 0.1 splits 0.05 / 0.05 over 3, 4.
//  row 1: terminal (discount 0), r 0.25: every atom to index 2.25: 0.75 to atom 2, 0.25 to atom 3.
//  row 2: r 3, discount 1: atoms to 1, 2, 3, 4, 5, clamped to 1, 2, 2, 2, 2: 0.4 to atom 3, the rest
//         to atom 4.
struct HandCase {
  torch::Tensor probs =
      torch::tensor({0.1, 0.2, 0.3, 0.3, 0.1, 0.2, 0.2, 0.2, 0.2, 0.2, 0.4, 0.1, 0.1, 0.2, 0.2}, torch::kFloat)
          .view({3, 5});
  torch::Tensor rewards = torch::tensor({0.5, 0.25, 3.0}, torch::kFloat);
  torch::Tensor discount = torch::tensor({0.5, 0.0, 1.0}, torch::kFloat);
  std::vector<std::vector<double>> projected = {{0, 0.05, 0.4, 0.5, 0.05}, {0, 0, 0.75, 0.25, 0}, {0, 0, 0, 0.4, 0.6}};
};

TEST(Td3Math, ProjectionMatchesHandComputation) {
  HandCase h;
  const auto p = c51_projection(h.probs, h.rewards, h.discount, -2, 2);
  expect_rows(p, h.projected);
  // Mass is kept, also where a shifted atom lands exactly on an atom (row 0's 0 and 1).
  EXPECT_TRUE(torch::allclose(p.sum(1), torch::ones({3}), 1e-6, 1e-6));
}

TEST(Td3Math, CrossEntropyMatchesHandComputation) {
  HandCase h;
  const auto target = c51_projection(h.probs, h.rewards, h.discount, -2, 2);
  // Critic 1: equal logits, so every row's loss is log 5. Critic 2: logits log q, q of row 0 of
  // probs for every row, so a row's loss is -sum_k t_k log q_k.
  const std::vector<double> q = {0.1, 0.2, 0.3, 0.3, 0.1};
  const auto log_q = torch::tensor(
      std::vector<double>{std::log(0.1), std::log(0.2), std::log(0.3), std::log(0.3), std::log(0.1)}, torch::kFloat);
  const auto logits = torch::stack({torch::zeros({3, 5}), log_q.expand({3, 5})});
  double second = 0;
  for (const auto& row : h.projected)
    for (size_t k = 0; k < 5; ++k) second -= row[k] * std::log(q[k]) / 3.0;
  const double want = std::log(5.0) + second;
  const auto loss = c51_cross_entropy(torch::stack({target, target}), logits);
  EXPECT_NEAR(loss.item<double>(), want, 1e-5);
  // Its gradient moves each critic's distribution toward the target: softmax - target per row.
  auto l = logits.clone().requires_grad_(true);
  c51_cross_entropy(torch::stack({target, target}), l).backward();
  const auto want_grad = (torch::softmax(logits, -1) - torch::stack({target, target})) / 3.0;
  EXPECT_TRUE(torch::allclose(l.grad(), want_grad, 1e-5, 1e-6));
}

TEST(Td3Math, ClippedDoubleQTakesTheCriticOfTheSmallerExpectedValue) {
  // Row 0: critic 1 puts its mass high, critic 2 low; row 1 the other way round.
  const auto high = torch::tensor({0.0, 0.0, 0.1, 0.2, 0.7}, torch::kFloat);
  const auto low = torch::tensor({0.6, 0.3, 0.1, 0.0, 0.0}, torch::kFloat);
  const auto p1 = torch::stack({high, low}), p2 = torch::stack({low, high});
  const auto r = torch::tensor({0.3, -0.2}, torch::kFloat), d = torch::tensor({0.9, 0.9}, torch::kFloat);
  const auto proj1 = c51_projection(p1, r, d, -2, 2), proj2 = c51_projection(p2, r, d, -2, 2);
  const auto z = c51_support(5, -2, 2);
  ASSERT_GT(c51_expected_value(proj1[0], z).item<double>(), c51_expected_value(proj2[0], z).item<double>());
  ASSERT_LT(c51_expected_value(proj1[1], z).item<double>(), c51_expected_value(proj2[1], z).item<double>());

  const auto t = td3_critic_target(p1, p2, r, d, -2, 2, true);
  ASSERT_EQ(t.sizes(), (std::vector<int64_t>{2, 2, 5}));
  for (int c = 0; c < 2; ++c) {
    EXPECT_TRUE(torch::equal(t[c][0], proj2[0])) << "critic " << c << ", row 0: critic 2's is the smaller";
    EXPECT_TRUE(torch::equal(t[c][1], proj1[1])) << "critic " << c << ", row 1: critic 1's is the smaller";
  }
  // Without clipped double Q each critic learns its own projection.
  const auto own = td3_critic_target(p1, p2, r, d, -2, 2, false);
  EXPECT_TRUE(torch::equal(own[0], proj1));
  EXPECT_TRUE(torch::equal(own[1], proj2));
}

TEST(Td3, ConfigDefaultsAreFastTd3s) {
  const config::Td3Config c;
  EXPECT_EQ(c.batch_size(), 32768);
  EXPECT_EQ(c.num_atoms(), 101);
  EXPECT_DOUBLE_EQ(c.v_min(), -250);
  EXPECT_DOUBLE_EQ(c.v_max(), 250);
  EXPECT_DOUBLE_EQ(c.tau(), 0.1);
  EXPECT_EQ(c.policy_delay(), 2);
  EXPECT_DOUBLE_EQ(c.policy_noise(), 0.001);
  EXPECT_DOUBLE_EQ(c.noise_clip(), 0.5);
  EXPECT_DOUBLE_EQ(c.std_min(), 0.001);
  EXPECT_DOUBLE_EQ(c.std_max(), 0.4);
  EXPECT_DOUBLE_EQ(c.weight_decay(), 0.1);
  EXPECT_DOUBLE_EQ(c.samples_per_insert(), 512);  // 2 updates of 32768 rows per step of 128 envs
  Td3 td3(c, 5, 2, 1);
  EXPECT_EQ(td3.hidden(), (std::vector<int>{512, 256, 128}));
  EXPECT_EQ(td3.critic_hidden(), (std::vector<int>{1024, 512, 256}));
  EXPECT_EQ(td3.support().numel(), 101);
  // The output layer starts near zero (init_scale 0.01): the first actions are near 0.
  EXPECT_LT(td3.deterministic_action(torch::randn({16, 5})).abs().max().item<double>(), 0.1);
}

// The critics step every update, the actor every policy_delay-th, the target critics by tau.
TEST(Td3, ActorStepsEveryPolicyDelayUpdatesAndTargetsMoveByTau) {
  auto cfg = small_config();
  cfg.set_policy_delay(3);
  Td3 td3(cfg, 3, 2, 7);
  EXPECT_TRUE(all_equal(td3.critic_parameters(), td3.target_critic_parameters())) << "targets start as the critics";
  for (int i = 0; i < 6; ++i) {
    const auto actor = copies(td3.actor_parameters()), critic = copies(td3.critic_parameters());
    const auto target = copies(td3.target_critic_parameters());
    const Td3Stats st = td3.update(random_batch(32, 3, 2, 100 + i));
    const bool turn = i % 3 == 2;
    EXPECT_EQ(st.actor_stepped, turn) << "update " << i;
    EXPECT_EQ(!all_equal(actor, td3.actor_parameters()), turn) << "update " << i;
    EXPECT_FALSE(all_equal(critic, td3.critic_parameters())) << "update " << i;
    for (size_t k = 0; k < target.size(); ++k) {
      const auto want = target[k] + cfg.tau() * (td3.critic_parameters()[k] - target[k]);
      EXPECT_TRUE(torch::allclose(td3.target_critic_parameters()[k], want, 1e-5, 1e-7)) << "update " << i;
    }
    EXPECT_TRUE(std::isfinite(st.critic_loss) && std::isfinite(st.actor_loss) && std::isfinite(st.q_mean));
  }
}

// The workers' policy: the squashed-Gaussian head whose mean is the actor's and whose std is the
// exploration std, with the learner's observation normalizer.
TEST(Td3, ExportedPolicyActsAsTheActorAndExploresWithTheConfiguredStd) {
  auto cfg = small_config();
  cfg.set_std_min(0.1);
  cfg.set_std_max(0.3);
  Td3 td3(cfg, 3, 2, 11);
  const auto seen = torch::randn({200, 3}) * 3 + 2;
  td3.observe(seen.data_ptr<float>(), 200);
  for (int i = 0; i < 4; ++i) td3.update(random_batch(32, 3, 2, 200 + i));
  const PolicyParams p = td3.export_policy(9);
  EXPECT_EQ(p.version, 9u);
  EXPECT_EQ(p.head, PolicyHead::kSquashedGaussian);
  EXPECT_EQ(p.layout.sizes, (std::vector<int>{3, 32, 32, 4}));
  ASSERT_EQ(p.obs_mean.size(), 3u);
  EXPECT_NEAR(p.obs_mean[0], seen.select(1, 0).mean().item<double>(), 1e-4);
  EXPECT_NEAR(p.obs_std[0], seen.select(1, 0).std(false).item<double>(), 1e-3);
  Policy policy(p);
  const auto probe = torch::randn({8, 3}) * 3 + 2;
  std::vector<float> a(16);
  std::mt19937_64 rng(1);
  policy.act(probe.data_ptr<float>(), 8, rng, true, a.data(), nullptr);
  const auto want = td3.deterministic_action(probe);
  for (int i = 0; i < 16; ++i) EXPECT_NEAR(a[i], want.view(-1)[i].item<float>(), 1e-5) << i;
  // Exploring: atanh(a) - actor's pre-tanh output ~ N(0, (0.1 + 0.3) / 2).
  EXPECT_DOUBLE_EQ(td3.exploration_std(), 0.2);
  const int n = 20000;
  std::vector<float> obs(size_t(n) * 3), acts(size_t(n) * 2);
  for (int r = 0; r < n; ++r)
    for (int k = 0; k < 3; ++k) obs[size_t(r) * 3 + k] = probe[0][k].item<float>();
  policy.act(obs.data(), n, rng, false, acts.data(), nullptr);
  const double mean_pre = std::atanh(double(want[0][0].item<float>()));
  double s = 0, s2 = 0;
  for (int r = 0; r < n; ++r) {
    const double e = std::atanh(double(acts[size_t(r) * 2])) - mean_pre;
    s += e;
    s2 += e * e;
  }
  EXPECT_NEAR(s / n, 0.0, 0.01);
  EXPECT_NEAR(std::sqrt(s2 / n), 0.2, 0.01);
}

TEST(Td3, SaveLoadGivesTheSameActionsAndContinuesIdentically) {
  const auto cfg = small_config();
  Td3 a(cfg, 3, 2, 21);
  const auto seen = torch::randn({100, 3}) * 2 + 1;
  a.observe(seen.data_ptr<float>(), 100);
  for (int i = 0; i < 5; ++i) a.update(random_batch(32, 3, 2, 300 + i));  // odd: mid-way between actor steps
  const std::string dir = temp_dir("farm_td3_roundtrip");
  a.save(dir);
  Td3 b(cfg, 3, 2, 99);  // other initial weights
  EXPECT_FALSE(all_equal(a.actor_parameters(), b.actor_parameters()));
  b.load(dir);
  EXPECT_EQ(b.updates(), 5);
  const auto probe = torch::randn({16, 3});
  EXPECT_TRUE(torch::equal(a.deterministic_action(probe), b.deterministic_action(probe)));
  EXPECT_EQ(a.export_policy(1).params, b.export_policy(1).params);
  EXPECT_EQ(a.export_policy(1).obs_std, b.export_policy(1).obs_std);
  EXPECT_TRUE(all_equal(a.target_critic_parameters(), b.target_critic_parameters()));
  for (int i = 0; i < 3; ++i) {
    const auto batch = random_batch(32, 3, 2, 400 + i);
    torch::manual_seed(500 + i);  // the target smoothing noise
    const Td3Stats sa = a.update(batch);
    torch::manual_seed(500 + i);
    const Td3Stats sb = b.update(batch);
    EXPECT_EQ(sa.actor_stepped, sb.actor_stepped);
    EXPECT_EQ(sa.critic_loss, sb.critic_loss);
    EXPECT_EQ(sa.actor_loss, sb.actor_loss);
  }
  EXPECT_TRUE(all_equal(a.actor_parameters(), b.actor_parameters()));
  EXPECT_TRUE(all_equal(a.critic_parameters(), b.critic_parameters()));
  EXPECT_TRUE(all_equal(a.target_critic_parameters(), b.target_critic_parameters()));

  // A file of other sizes or another support is refused, naming the file.
  auto wider = cfg;
  wider.set_hidden(0, 48);
  Td3 c(wider, 3, 2, 1);
  try {
    c.load(dir);
    FAIL() << "loaded networks of other sizes";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(dir + "/td3.pt"), std::string::npos) << e.what();
  }
  auto shifted = cfg;
  shifted.set_v_max(6);
  Td3 d(shifted, 3, 2, 1);
  EXPECT_THROW(d.load(dir), std::runtime_error);
  remove_tree(dir);
}

// FastTD3's batch of tens of thousands of rows, on the CPU at 4096 with the default networks (1024-
// 512-256 critics of 101 atoms): two updates, the second with the actor's step, all finite.
TEST(Td3, LargeBatchOnTheCpuIsFinite) {
  config::Td3Config cfg;
  cfg.set_device("cpu");
  Td3 td3(cfg, 17, 6, 3);
  const auto actor = copies(td3.actor_parameters());
  auto batch = random_batch(4096, 17, 6, 4);
  batch.rewards = batch.rewards * 5;
  const auto start = std::chrono::steady_clock::now();
  for (int i = 0; i < 2; ++i) {
    const Td3Stats st = td3.update(batch);
    EXPECT_TRUE(std::isfinite(st.critic_loss) && std::isfinite(st.actor_loss) && std::isfinite(st.q_mean));
    EXPECT_GT(st.critic_loss, 0);
  }
  EXPECT_FALSE(all_equal(actor, td3.actor_parameters()));
  for (const auto& t : td3.critic_parameters()) EXPECT_TRUE(torch::isfinite(t).all().item<bool>());
  std::printf("two updates at batch 4096: %.2f s\n",
              std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
}

// A one-step contextual bandit (every transition terminal, so the return is the reward): the actor
// must move to the action that maximizes -(a - 0.6 s)^2, which the critics' distributions have to
// rank first; a sign error anywhere in the target, the loss, the choice of critic or the actor's
// step leaves it far off.
TEST(Td3, ActorLearnsContextualBandit) {
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
  Td3 td3(cfg, 1, 1, 31);
  auto best = [](const torch::Tensor& obs) { return 0.6 * obs.select(1, 0); };
  torch::manual_seed(32);
  const auto probe = torch::rand({64, 1}) * 2 - 1;
  auto error = [&] { return (td3.deterministic_action(probe).select(1, 0) - best(probe)).abs().mean().item<double>(); };
  const double before = error();
  for (int i = 0; i < 3000; ++i) {
    SampledBatch b;
    b.obs = torch::rand({128, 1}) * 2 - 1;
    b.actions = torch::rand({128, 1}) * 2 - 1;
    b.rewards = -(b.actions.select(1, 0) - best(b.obs)).square();
    b.terminated = torch::ones({128});
    b.next_obs = b.obs;
    td3.observe(b.obs.data_ptr<float>(), 128);
    td3.update(b);
  }
  const double after = error();
  EXPECT_LT(after, 0.1) << "before " << before;
  EXPECT_LT(after, 0.5 * before);
  // The critics' expected value at the best action is near its reward, 0.
  const auto q =
      c51_expected_value(torch::softmax(td3.critic_logits(probe, best(probe).unsqueeze(1)), -1), td3.support());
  EXPECT_NEAR(q.mean().item<double>(), 0.0, 0.15);
}

}  // namespace
}  // namespace farm
