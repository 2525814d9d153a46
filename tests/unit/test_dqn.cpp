// DQN learner core: the double-Q target against hand-computed values, the exploration schedule,
// the discrete-Q policy head the workers run, target copies, a small learning problem, and
// checkpoints.
#include <gtest/gtest.h>

#include <torch/torch.h>
#include "config.h"

#include <cmath>
#include <filesystem>
#include <random>
#include <vector>

#include "dqn.h"
#include "mlp.h"
#include "paths.h"  // remove_tree: std::filesystem::remove_all crashes the GPU build

using namespace farm;

TEST(DqnTarget, DoubleQUsesOnlineArgmaxAndTargetValue) {
  // Two transitions, three actions.
  const auto reward = torch::tensor({1.0f, -0.5f});
  const auto terminated = torch::tensor({0.0f, 0.0f});
  const auto online = torch::tensor({{0.1f, 0.9f, 0.3f}, {2.0f, -1.0f, 1.0f}});
  const auto target = torch::tensor({{5.0f, 2.0f, 7.0f}, {0.5f, 4.0f, 3.0f}});
  // Double: online argmax is action 1 for row 0, action 0 for row 1 -> target values 2.0, 0.5.
  auto y = dqn_target(reward, terminated, online, target, 0.9, true);
  EXPECT_NEAR(y[0].item<float>(), 1.0 + 0.9 * 2.0, 1e-6);
  EXPECT_NEAR(y[1].item<float>(), -0.5 + 0.9 * 0.5, 1e-6);
  // Plain DQN: max of the target network -> 7.0 and 4.0.
  y = dqn_target(reward, terminated, online, target, 0.9, false);
  EXPECT_NEAR(y[0].item<float>(), 1.0 + 0.9 * 7.0, 1e-6);
  EXPECT_NEAR(y[1].item<float>(), -0.5 + 0.9 * 4.0, 1e-6);
  // A terminated transition does not bootstrap.
  y = dqn_target(reward, torch::tensor({1.0f, 0.0f}), online, target, 0.9, true);
  EXPECT_NEAR(y[0].item<float>(), 1.0, 1e-6);
  EXPECT_NEAR(y[1].item<float>(), -0.5 + 0.9 * 0.5, 1e-6);
  // Multi-step rows bootstrap with gamma^horizon: row 0 spans 3 steps, row 1 one.
  y = dqn_target(reward, terminated, online, target, 0.9, true, torch::tensor({3.0f, 1.0f}));
  EXPECT_NEAR(y[0].item<float>(), 1.0 + 0.729 * 2.0, 1e-6);
  EXPECT_NEAR(y[1].item<float>(), -0.5 + 0.9 * 0.5, 1e-6);
}

TEST(DqnSchedule, EpsilonFallsLinearlyThenStays) {
  config::DqnConfig c;  // mobile-robots paper table 3: fraction 0.35 of 3,000,000 steps; sb3 1.0 -> 0.05
  EXPECT_DOUBLE_EQ(dqn_epsilon(c, 0), 1.0);
  EXPECT_NEAR(dqn_epsilon(c, 525000), 1.0 - 0.5 * 0.95, 1e-12);
  EXPECT_NEAR(dqn_epsilon(c, 1050000), 0.05, 1e-12);
  EXPECT_NEAR(dqn_epsilon(c, 2000000), 0.05, 1e-12);
  c.set_schedule_env_steps(1000);
  c.set_exploration_fraction(0.5);
  EXPECT_NEAR(dqn_epsilon(c, 250), 0.525, 1e-12);
  // The learner's step count reaches the exported policy.
  Dqn dqn(c, 3, 4, 1);
  dqn.set_env_steps(250);
  EXPECT_NEAR(dqn.export_policy(1).epsilon, 0.525, 1e-6);
}

TEST(DqnConfig, DefaultsAreSeedTableThree) {
  config::DqnConfig c;
  EXPECT_EQ(c.buffer_size(), 800000);
  EXPECT_DOUBLE_EQ(c.learning_rate(), 0.00015);
  EXPECT_DOUBLE_EQ(c.exploration_fraction(), 0.35);
  EXPECT_EQ(c.schedule_env_steps(), 3000000);
  c.set_gamma(1.5);
  try {
    farm::check_config(c);
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("gamma"), std::string::npos) << e.what();
  }
}

TEST(DqnPolicy, WorkersActGreedilyOnTheExportedNetwork) {
  config::DqnConfig c;
  Dqn dqn(c, 5, 4, 3);
  PolicyParams p = dqn.export_policy(7);
  p.epsilon = 0.f;
  Policy policy(p);
  EXPECT_EQ(policy.act_dim(), 1);
  EXPECT_EQ(policy.num_actions(), 4);
  const auto obs = torch::randn({64, 5});
  const auto greedy = dqn.q_values(obs).argmax(1);
  std::vector<float> actions(64);
  std::mt19937_64 rng(1);
  policy.act(obs.data_ptr<float>(), 64, rng, false, actions.data(), nullptr);
  for (int i = 0; i < 64; ++i) EXPECT_EQ(int(actions[i]), greedy[i].item<int64_t>()) << i;
}

TEST(DqnPolicy, EpsilonGreedyExploresUniformly) {
  config::DqnConfig c;
  Dqn dqn(c, 2, 5, 3);
  PolicyParams p = dqn.export_policy(1);
  p.epsilon = 1.f;
  Policy policy(p);
  const int rows = 5000;
  std::vector<float> obs(rows * 2, 0.1f), actions(rows), logp(rows);
  std::mt19937_64 rng(2);
  policy.act(obs.data(), rows, rng, false, actions.data(), logp.data());
  std::vector<int> counts(5, 0);
  for (float a : actions) counts[int(a)]++;
  for (int k = 0; k < 5; ++k) EXPECT_NEAR(counts[k], rows / 5, 150) << "action " << k;
  EXPECT_NEAR(logp[0], std::log(0.2f), 1e-5);
  // Deterministic ignores epsilon: every row takes the same greedy action.
  policy.act(obs.data(), rows, rng, true, actions.data(), nullptr);
  for (float a : actions) EXPECT_EQ(a, actions[0]);
  p.epsilon = 1.5f;
  EXPECT_THROW(Policy{p}, std::invalid_argument);
}

TEST(DqnUpdate, TargetNetworkIsCopiedEveryKUpdates) {
  config::DqnConfig c;
  c.set_target_update_updates(3);
  c.set_learning_rate(1e-2);
  Dqn dqn(c, 3, 2, 1);
  SampledBatch b{torch::randn({8, 3}), torch::randint(0, 2, {8, 1}).to(torch::kFloat), torch::randn({8}),
                 torch::zeros({8}), torch::randn({8, 3})};
  auto same = [&] {
    auto o = dqn.online_parameters(), t = dqn.target_parameters();
    for (size_t i = 0; i < o.size(); ++i)
      if (!torch::equal(o[i], t[i])) return false;
    return true;
  };
  EXPECT_TRUE(same());
  dqn.update(b);
  EXPECT_FALSE(same());
  dqn.update(b);
  EXPECT_FALSE(same());
  dqn.update(b);
  EXPECT_TRUE(same());
}

// Two states (one-hot), three actions, one step: Q must learn r(s, a) and pick the best action.
TEST(DqnUpdate, LearnsAContextualBandit) {
  config::DqnConfig c;
  c.set_learning_rate(3e-3);
  c.set_target_update_updates(50);
  Dqn dqn(c, 2, 3, 5);
  const float r[2][3] = {{0.f, 1.f, -1.f}, {0.5f, -0.5f, 2.f}};
  std::mt19937_64 rng(3);
  for (int it = 0; it < 1500; ++it) {
    const int B = 32;
    auto obs = torch::zeros({B, 2}), act = torch::zeros({B, 1}), rew = torch::zeros({B});
    for (int i = 0; i < B; ++i) {
      const int s = int(rng() % 2), a = int(rng() % 3);
      obs[i][s] = 1.f;
      act[i][0] = float(a);
      rew[i] = r[s][a];
    }
    dqn.update({obs, act, rew, torch::ones({B}), torch::zeros({B, 2})});
  }
  const auto q = dqn.q_values(torch::eye(2));
  EXPECT_EQ(q[0].argmax().item<int64_t>(), 1);
  EXPECT_EQ(q[1].argmax().item<int64_t>(), 2);
  for (int s = 0; s < 2; ++s)
    for (int a = 0; a < 3; ++a) EXPECT_NEAR(q[s][a].item<float>(), r[s][a], 0.1) << s << "," << a;
}

TEST(DqnCheckpoint, SaveLoadRoundTripAndSizeMismatch) {
  const auto dir = std::filesystem::temp_directory_path() / ("dqn_ckpt_" + std::to_string(::getpid()));
  config::DqnConfig c;
  Dqn a(c, 4, 3, 1);
  a.set_env_steps(1234);
  SampledBatch b{torch::randn({8, 4}), torch::randint(0, 3, {8, 1}).to(torch::kFloat), torch::randn({8}),
                 torch::zeros({8}), torch::randn({8, 4})};
  for (int i = 0; i < 5; ++i) a.update(b);
  a.save(dir.string());
  Dqn c2(c, 4, 3, 99);
  c2.load(dir.string());
  EXPECT_EQ(c2.updates(), 5);
  EXPECT_EQ(c2.export_policy(1).params, a.export_policy(1).params);
  EXPECT_FLOAT_EQ(c2.export_policy(1).epsilon, a.export_policy(1).epsilon);
  Dqn wrong(c, 4, 5, 1);
  try {
    wrong.load(dir.string());
    FAIL() << "expected an error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("dqn.pt"), std::string::npos) << e.what();
  }
  farm::remove_tree(dir);
}

// dqn.max_step_scale's rate: learning_rate x the scale from the next update on (Adam's first step
// moves each weight by about its rate, so twice the rate moves the networks twice as far), kept
// across a load, which does not take the saved rate; a scale that is not a finite number > 0 is
// refused.
TEST(DqnStepScale, TheLearningRateScalesAndStaysAcrossALoad) {
  config::DqnConfig c;
  c.set_learning_rate(1e-3);
  Dqn plain(c, 4, 3, 1), scaled(c, 4, 3, 1);
  scaled.scale_learning_rate(2.0);
  EXPECT_DOUBLE_EQ(plain.learning_rate(), 1e-3);
  EXPECT_DOUBLE_EQ(scaled.learning_rate(), 2e-3);
  const auto before = plain.online_parameters();
  std::vector<torch::Tensor> start;
  for (const auto& p : before) start.push_back(p.detach().clone());
  SampledBatch b{torch::randn({32, 4}), torch::randint(0, 3, {32, 1}).to(torch::kFloat), torch::randn({32}),
                 torch::zeros({32}), torch::randn({32, 4})};
  plain.update(b);
  scaled.update(b);
  double moved_plain = 0, moved_scaled = 0;
  for (size_t i = 0; i < start.size(); ++i) {
    moved_plain += (plain.online_parameters()[i] - start[i]).abs().sum().item<double>();
    moved_scaled += (scaled.online_parameters()[i] - start[i]).abs().sum().item<double>();
  }
  EXPECT_NEAR(moved_scaled / moved_plain, 2.0, 0.01);

  const auto dir = std::filesystem::temp_directory_path() / ("dqn_lr_scale_" + std::to_string(::getpid()));
  scaled.save(dir.string());
  Dqn loaded(c, 4, 3, 9);
  loaded.load(dir.string());
  EXPECT_DOUBLE_EQ(loaded.learning_rate(), 1e-3) << "a load keeps this instance's scale (1), not the saved rate";
  Dqn loaded_scaled(c, 4, 3, 9);
  loaded_scaled.scale_learning_rate(4.0);
  loaded_scaled.load(dir.string());
  EXPECT_DOUBLE_EQ(loaded_scaled.learning_rate(), 4e-3);
  farm::remove_tree(dir);

  for (double bad : {0.0, -1.0, std::nan("")}) EXPECT_THROW(plain.scale_learning_rate(bad), std::invalid_argument);
}

namespace {

// Where a GPU and a CUDA LibTorch are there: dqn.device "cuda", with or without the CUDA graph.
config::DqnConfig cuda_dqn_config(bool graph) {
  config::DqnConfig c;
  c.set_device("cuda");
  c.set_cuda_graph(graph);
  c.set_learning_rate(1e-3);
  c.set_target_update_updates(7);
  c.set_max_grad_norm(0.5);  // small enough that some updates are clipped
  return c;
}

// Rows with multi-step horizons of 1-3, as the replay buffer samples them with dqn.n_step 3.
SampledBatch dqn_batch(int rows, int obs, int actions, uint64_t seed) {
  torch::manual_seed(seed);
  return {torch::randn({rows, obs}), torch::randint(0, actions, {rows, 1}).to(torch::kFloat),
          torch::randn({rows}),      (torch::rand({rows}) < 0.1).to(torch::kFloat),
          torch::randn({rows, obs}), torch::randint(1, 4, {rows}).to(torch::kFloat)};
}

double relative_gap(const std::vector<torch::Tensor>& a, const std::vector<torch::Tensor>& b) {
  double num = 0, den = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    num += (a[i].cpu() - b[i].cpu()).to(torch::kDouble).square().sum().item<double>();
    den += b[i].cpu().to(torch::kDouble).square().sum().item<double>();
  }
  return std::sqrt(num / std::max(den, 1e-30));
}

}  // namespace

// The CUDA-graph update (warm-ups, capture, replays, target copies between them, clipped
// gradients) computes what the eager CUDA update computes from the same start on the same batches.
TEST(DqnCuda, GraphUpdateMatchesEager) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  Dqn graph(cuda_dqn_config(true), 5, 3, 4), eager(cuda_dqn_config(false), 5, 3, 4);
  if (!graph.uses_cuda_graph()) GTEST_SKIP() << "built against a LibTorch without CUDA";
  EXPECT_TRUE(graph.on_gpu());
  EXPECT_FALSE(eager.uses_cuda_graph());
  for (int k = 0; k < 40; ++k) {
    const auto b = dqn_batch(64, 5, 3, 900 + k);
    const DqnStats g = graph.update(b), e = eager.update(b);
    EXPECT_NEAR(g.loss, e.loss, 1e-3 * std::max(1.0, std::abs(e.loss))) << "update " << k;
    EXPECT_NEAR(g.q_mean, e.q_mean, 1e-3 * std::max(1.0, std::abs(e.q_mean))) << "update " << k;
    EXPECT_NEAR(g.target_mean, e.target_mean, 1e-3 * std::max(1.0, std::abs(e.target_mean))) << "update " << k;
  }
  EXPECT_EQ(graph.updates(), 40);
  EXPECT_LE(relative_gap(graph.online_parameters(), eager.online_parameters()), 1e-3);
  EXPECT_LE(relative_gap(graph.target_parameters(), eager.target_parameters()), 1e-3);
  // The policy the workers get comes off the GPU.
  EXPECT_EQ(graph.export_policy(1).params.size(), eager.export_policy(1).params.size());
}

// With dqn.max_step_scale the graph is captured again at the new rate and batch: a graph update
// after scale_learning_rate computes what the eager one does at the same rate.
TEST(DqnCuda, ScaledGraphMatchesEager) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  Dqn graph(cuda_dqn_config(true), 5, 3, 4), eager(cuda_dqn_config(false), 5, 3, 4);
  if (!graph.uses_cuda_graph()) GTEST_SKIP() << "built against a LibTorch without CUDA";
  for (int k = 0; k < 20; ++k) {
    if (k == 10) {
      graph.scale_learning_rate(2.0);
      eager.scale_learning_rate(2.0);
    }
    const auto b = dqn_batch(k < 10 ? 64 : 256, 5, 3, 1900 + k);
    const DqnStats g = graph.update(b), e = eager.update(b);
    EXPECT_NEAR(g.loss, e.loss, 1e-3 * std::max(1.0, std::abs(e.loss))) << "update " << k;
  }
  EXPECT_LE(relative_gap(graph.online_parameters(), eager.online_parameters()), 1e-3);
}

// A GPU run's checkpoint: a CPU learner loads it (the same networks), and a GPU learner that loads
// it goes on as the one that wrote it (optimizer state and step counts included, the graph
// captured again).
TEST(DqnCuda, GraphStateSurvivesSaveLoad) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  const auto dir = std::filesystem::temp_directory_path() / ("dqn_cuda_ckpt_" + std::to_string(::getpid()));
  Dqn a(cuda_dqn_config(true), 5, 3, 4);
  if (!a.uses_cuda_graph()) GTEST_SKIP() << "built against a LibTorch without CUDA";
  for (int k = 0; k < 20; ++k) a.update(dqn_batch(64, 5, 3, 300 + k));
  a.save(dir.string());
  config::DqnConfig cpu = cuda_dqn_config(true);
  cpu.set_device("cpu");
  Dqn on_cpu(cpu, 5, 3, 99), b(cuda_dqn_config(true), 5, 3, 99);
  on_cpu.load(dir.string());
  b.load(dir.string());
  EXPECT_EQ(on_cpu.updates(), 20);
  EXPECT_EQ(on_cpu.export_policy(1).params, a.export_policy(1).params);
  for (int k = 0; k < 10; ++k) {
    const auto batch = dqn_batch(64, 5, 3, 600 + k);
    const DqnStats x = a.update(batch), y = b.update(batch);
    EXPECT_NEAR(x.loss, y.loss, 1e-5 * std::max(1.0, std::abs(x.loss))) << "update " << k;
  }
  EXPECT_LE(relative_gap(b.online_parameters(), a.online_parameters()), 1e-5);
  EXPECT_LE(relative_gap(b.target_parameters(), a.target_parameters()), 1e-5);
  farm::remove_tree(dir);
}
