// DQN learner core: the double-Q target and the Huber loss against hand-computed values, the
// exploration schedule, the discrete-Q policy head the workers run, target copies, small learning
// problems, and checkpoints; the large-batch path on the CPU (several updates per call, minibatches
// drawn from a DeviceReplay, bfloat16 products, the learning rate for the batch).
#include <gtest/gtest.h>

#include <torch/torch.h>
#include "config.h"

#include <cmath>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "batch.h"
#include "device_replay.h"
#include "dqn.h"
#include "mlp.h"
#include "paths.h"  // remove_tree: std::filesystem::remove_all crashes the GPU build
#include "registry.h"
#include "step_size.h"
#include "task_spec.h"

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

// The Q networks obs 2 -> 2 -> 2 actions with identity weights and zero biases (online and
// target): Q(s) = relu(s).
Dqn identity_dqn(const config::DqnConfig& base) {
  config::DqnConfig c = base;
  c.clear_hidden();
  c.add_hidden(2);
  Dqn dqn(c, 2, 2, 1);
  torch::NoGradGuard no_grad;
  for (const auto& params : {dqn.online_parameters(), dqn.target_parameters()})
    for (const auto& p : params) p.dim() == 2 ? p.copy_(torch::eye(2)) : p.zero_();
  return dqn;
}

// Two rows. Row 0: Q(obs, a=0) = 1; the online argmax at next_obs (0.5, 4) is action 1, whose
// target value is 4: y = 1 + 0.9 * 4 = 4.6, Huber(1 - 4.6) = 3.6 - 0.5 = 3.1. Row 1 is
// terminated: Q(obs, a=1) = 0.5, y = -1, Huber(1.5) = 1.5 - 0.5 = 1.0. Mean loss 2.05.
SampledBatch hand_batch() {
  return {torch::tensor({{1.f, 2.f}, {3.f, 0.5f}}), torch::tensor({{0.f}, {1.f}}), torch::tensor({1.f, -1.f}),
          torch::tensor({0.f, 1.f}), torch::tensor({{0.5f, 4.f}, {2.f, 1.f}})};
}

}  // namespace

TEST(DqnLoss, HuberLossOnTheDoubleQTargetByHand) {
  config::DqnConfig c;
  c.set_gamma(0.9);
  for (const char* dtype : {"float32", "bfloat16"}) {  // every value here is exact in bfloat16
    c.set_matmul_dtype(dtype);
    Dqn dqn = identity_dqn(c);
    const DqnStats st = dqn.update(hand_batch());
    EXPECT_NEAR(st.loss, 2.05, 1e-6) << dtype;
    EXPECT_NEAR(st.q_mean, 0.75, 1e-6) << dtype;
    EXPECT_NEAR(st.target_mean, 0.5 * (4.6 - 1.0), 1e-6) << dtype;
  }
}

namespace {

// The same transitions in a host ReplayBuffer and its DeviceReplay on the CPU; horizons 1, 2, 3,
// 1, ... (dqn.n_step 3 rows), actions of 3.
void fill_replays(ReplayBuffer& host, DeviceReplay& dev, int rows, uint64_t seed) {
  torch::manual_seed(seed);
  const auto obs = torch::randn({rows, 4}), next_obs = torch::randn({rows, 4});
  const auto actions = torch::randint(0, 3, {rows, 1}).to(torch::kFloat), rewards = torch::randn({rows});
  const auto term = (torch::rand({rows}) < 0.1).to(torch::kUInt8);
  std::vector<float> horizon(rows);
  for (int k = 0; k < rows; ++k) horizon[k] = float(1 + k % 3);
  host.add_n(rows, obs.data_ptr<float>(), actions.data_ptr<float>(), rewards.data_ptr<float>(),
             term.data_ptr<uint8_t>(), next_obs.data_ptr<float>(), horizon.data());
  dev.add_n(rows, obs.data_ptr<float>(), actions.data_ptr<float>(), rewards.data_ptr<float>(), term.data_ptr<uint8_t>(),
            next_obs.data_ptr<float>(), horizon.data());
}

config::DqnConfig small_config() {
  config::DqnConfig c;
  c.add_hidden(16);
  c.add_hidden(16);
  c.set_learning_rate(1e-3);
  c.set_target_update_updates(3);
  c.set_max_grad_norm(0.5);  // small enough that some updates are clipped
  return c;
}

double relative_gap(const std::vector<torch::Tensor>& a, const std::vector<torch::Tensor>& b) {
  double num = 0, den = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    num += (a[i].cpu() - b[i].cpu()).to(torch::kDouble).square().sum().item<double>();
    den += b[i].cpu().to(torch::kDouble).square().sum().item<double>();
  }
  return std::sqrt(num / std::max(den, 1e-30));
}

bool same(const std::vector<torch::Tensor>& a, const std::vector<torch::Tensor>& b) {
  for (size_t i = 0; i < a.size(); ++i)
    if (!torch::equal(a[i], b[i])) return false;
  return a.size() == b.size();
}

SampledBatch random_batch(int rows, uint64_t seed) {
  torch::manual_seed(seed);
  return {torch::randn({rows, 4}), torch::randint(0, 3, {rows, 1}).to(torch::kFloat), torch::randn({rows}),
          (torch::rand({rows}) < 0.1).to(torch::kFloat), torch::randn({rows, 4})};
}

}  // namespace

// update_n(n, next) is n calls of update(next()): the same batches in the same order, the same
// figures, the same networks after them (target copies between them included). On the CPU the same
// arithmetic runs, so they agree exactly.
TEST(DqnLargeBatch, UpdateNIsUpdatesInARow) {
  const auto c = small_config();
  Dqn one(c, 4, 3, 5), group(c, 4, 3, 5);
  std::vector<DqnStats> want;
  for (int k = 0; k < 11; ++k) want.push_back(one.update(random_batch(64, 700 + k)));
  int k = 0;
  auto next = [&] { return random_batch(64, 700 + k++); };
  std::vector<DqnStats> got = group.update_n(8, next);
  const auto more = group.update_n(3, next);
  got.insert(got.end(), more.begin(), more.end());
  ASSERT_EQ(got.size(), want.size());
  EXPECT_EQ(group.updates(), 11);
  for (size_t i = 0; i < want.size(); ++i) {
    EXPECT_EQ(got[i].loss, want[i].loss) << i;
    EXPECT_EQ(got[i].q_mean, want[i].q_mean) << i;
    EXPECT_EQ(got[i].target_mean, want[i].target_mean) << i;
  }
  EXPECT_TRUE(same(group.online_parameters(), one.online_parameters()));
  EXPECT_TRUE(same(group.target_parameters(), one.target_parameters()));
  EXPECT_TRUE(group.update_n(0, next).empty());
}

// Updates from a replay kept where the networks train draw each batch as DeviceReplay::sample does
// (a uniform draw from torch's generator): the same figures and networks as update() on the host
// rows at those indices, multi-step rows bootstrapping alike (the copy folds their horizons into
// `terminated`, the host keeps a column of its own), up to float rounding of gamma^h.
TEST(DqnLargeBatch, UpdatesFromADeviceReplayDrawTheirRowsFirst) {
  const auto c = small_config();
  Dqn from_replay(c, 4, 3, 5), on_rows(c, 4, 3, 5);
  ReplayBuffer host(500, 4, 1);
  DeviceReplay dev(500, 4, 1, torch::kCPU, c.gamma());
  fill_replays(host, dev, 300, 17);
  torch::manual_seed(23);
  const auto got = from_replay.update_n_from(8, 64, dev);
  ASSERT_EQ(got.size(), 8u);
  torch::manual_seed(23);
  const SampledBatch stored = host.stored();
  for (int k = 0; k < 8; ++k) {
    const auto idx = (torch::rand({64}, torch::TensorOptions().dtype(torch::kDouble)) * 300).to(torch::kLong);
    const SampledBatch rows{stored.obs.index_select(0, idx),      stored.actions.index_select(0, idx),
                            stored.rewards.index_select(0, idx),  stored.terminated.index_select(0, idx),
                            stored.next_obs.index_select(0, idx), stored.horizon.index_select(0, idx)};
    const DqnStats want = on_rows.update(rows);
    EXPECT_NEAR(got[k].loss, want.loss, 1e-5 * std::max(1.0, std::abs(want.loss))) << k;
    EXPECT_NEAR(got[k].target_mean, want.target_mean, 1e-5 * std::max(1.0, std::abs(want.target_mean))) << k;
  }
  EXPECT_EQ(from_replay.updates(), 8);
  EXPECT_LE(relative_gap(from_replay.online_parameters(), on_rows.online_parameters()), 1e-5);
  EXPECT_LE(relative_gap(from_replay.target_parameters(), on_rows.target_parameters()), 1e-5);
  // Nothing to draw from, or rows on another device than the networks', is refused.
  DeviceReplay empty(500, 4, 1, torch::kCPU, c.gamma());
  EXPECT_THROW(from_replay.update_n_from(1, 64, empty), std::logic_error);
  if (torch::cuda::is_available()) {
    DeviceReplay on_gpu(500, 4, 1, torch::Device(torch::kCUDA, 0), c.gamma());
    fill_replays(host, on_gpu, 10, 19);
    EXPECT_THROW(from_replay.update_n_from(1, 64, on_gpu), std::invalid_argument);
  }
}

// A checkpoint written between calls of the large-batch path: a Dqn that loads it goes on as the
// one that wrote it (networks, Adam's state and step counts, the target-copy clock), draw for draw.
TEST(DqnLargeBatch, SaveAndLoadBetweenCallsGoOnAsOne) {
  const auto dir = std::filesystem::temp_directory_path() / ("dqn_large_ckpt_" + std::to_string(::getpid()));
  auto c = small_config();
  c.set_matmul_dtype("bfloat16");
  ReplayBuffer host(500, 4, 1);
  DeviceReplay dev(500, 4, 1, torch::kCPU, c.gamma());
  fill_replays(host, dev, 400, 29);
  Dqn a(c, 4, 3, 5);
  a.update_n_from(8, 128, dev);
  a.update_n_from(2, 128, dev);  // 10 updates: the next target copy is 2 updates away
  a.save(dir.string());
  Dqn b(c, 4, 3, 77);
  b.load(dir.string());
  EXPECT_EQ(b.updates(), 10);
  EXPECT_TRUE(same(b.online_parameters(), a.online_parameters()));
  EXPECT_TRUE(same(b.target_parameters(), a.target_parameters()));
  torch::manual_seed(41);
  const auto x = a.update_n_from(8, 128, dev);
  torch::manual_seed(41);
  const auto y = b.update_n_from(8, 128, dev);
  for (size_t k = 0; k < x.size(); ++k) EXPECT_EQ(x[k].loss, y[k].loss) << k;
  EXPECT_TRUE(same(b.online_parameters(), a.online_parameters()));
  EXPECT_TRUE(same(b.target_parameters(), a.target_parameters()));
  farm::remove_tree(dir);
}

// A two-step chain with one-hot states, learnt from large minibatches drawn from a DeviceReplay
// (the path a GPU learner takes, here on the CPU) with bfloat16 products. From s0, action 1 leads
// to s1 with no reward and action 0 ends the episode with none; in s1 action 0 ends it with reward
// 1 and action 1 with none. Only the bootstrapped target gets Q(s0, 1) = gamma.
TEST(DqnLargeBatch, LearnsAChainWithBfloat16ProductsFromADeviceReplay) {
  config::DqnConfig c;
  c.add_hidden(32);
  c.set_gamma(0.9);
  c.set_learning_rate(3e-3);
  c.set_target_update_updates(25);
  c.set_matmul_dtype("bfloat16");
  Dqn dqn(c, 2, 2, 3);
  const int rows = 400;
  std::vector<float> obs(rows * 2, 0.f), next_obs(rows * 2, 0.f), actions(rows), rewards(rows, 0.f);
  std::vector<uint8_t> terminated(rows, 1);
  for (int i = 0; i < rows; ++i) {
    const int s = i % 2, a = (i / 2) % 2;
    obs[i * 2 + s] = 1.f;
    actions[i] = float(a);
    if (s == 0 && a == 1) {
      next_obs[i * 2 + 1] = 1.f;
      terminated[i] = 0;
    }
    if (s == 1 && a == 0) rewards[i] = 1.f;
  }
  DeviceReplay dev(1000, 2, 1, torch::kCPU, c.gamma());
  dev.add_n(rows, obs.data(), actions.data(), rewards.data(), terminated.data(), next_obs.data());
  torch::manual_seed(5);
  for (int call = 0; call < 50; ++call) dqn.update_n_from(8, 1024, dev);
  const auto q = dqn.q_values(torch::eye(2));
  EXPECT_NEAR(q[1][0].item<float>(), 1.0, 0.05);
  EXPECT_NEAR(q[1][1].item<float>(), 0.0, 0.05);
  EXPECT_NEAR(q[0][1].item<float>(), 0.9, 0.05);
  EXPECT_NEAR(q[0][0].item<float>(), 0.0, 0.05);
}

// dqn.lr_reference_batch: the square-root rule against the batch the rate was tuned at, on top of
// the step scale's sqrt(s); off (0) it is sqrt(s) alone.
TEST(DqnLargeBatch, TheLearningRateFollowsTheBatchBySquareRoot) {
  EXPECT_DOUBLE_EQ(batch_lr_factor(4096, 1, 0), 1.0);
  EXPECT_DOUBLE_EQ(batch_lr_factor(4096, 4, 0), 2.0);
  EXPECT_DOUBLE_EQ(batch_lr_factor(4096, 1, 1024), 2.0);
  EXPECT_DOUBLE_EQ(batch_lr_factor(1024, 4, 1024), 2.0);
  EXPECT_DOUBLE_EQ(batch_lr_factor(256, 1, 1024), 0.5);
  EXPECT_EQ(batch_lr_phrase(32, 32), "");
  EXPECT_EQ(batch_lr_phrase(4096, 0), "");
  EXPECT_NE(batch_lr_phrase(4096, 1024).find("x2 for its batch of 4096"), std::string::npos)
      << batch_lr_phrase(4096, 1024);
  config::DqnConfig c;  // defaults: no scaling, float32, minibatches on the GPU where it trains
  EXPECT_EQ(c.lr_reference_batch(), 0);
  EXPECT_EQ(c.matmul_dtype(), "float32");
  EXPECT_TRUE(c.replay_on_device());
  for (auto bad : {+[](config::DqnConfig& d) { d.set_matmul_dtype("float16"); },
                   +[](config::DqnConfig& d) { d.set_lr_reference_batch(-1); }}) {
    config::DqnConfig d;
    bad(d);
    EXPECT_THROW(check_config(d), std::invalid_argument);
  }
}

// The large-batch recipe through the interface the learner runs (registry, insert, update of a
// group of 8): on the CPU the minibatches come from the host replay, the group's figures are
// numbered update by update, and the chain of the test above is learnt with bfloat16 products and
// the rate scaled for a batch of 1,024 from one tuned at 32; the start line says so.
TEST(DqnLargeBatch, TheAlgorithmLearnsTheChainInGroupsOfUpdates) {
  config::ExperimentConfig cfg;
  cfg.set_experiment_id("dqn_large_batch");
  cfg.set_algorithm("dqn");
  cfg.set_seed(7);
  auto& d = *cfg.mutable_dqn();
  d.add_hidden(32);
  d.set_gamma(0.9);
  d.set_batch_size(1024);
  d.set_buffer_size(2000);
  d.set_learning_starts(0);
  d.set_learning_rate(5e-4);
  d.set_lr_reference_batch(32);
  d.set_target_update_updates(25);
  d.set_matmul_dtype("bfloat16");
  robots::TaskSpec spec;
  spec.name = "chain";
  spec.obs_dim = 2;
  spec.act_dim = 1;
  spec.num_actions = 2;
  spec.max_episode_steps = 2;
  auto algo = make_algorithm(cfg, spec);
  const std::string line = algo->describe();
  EXPECT_NE(line.find("bfloat16 products"), std::string::npos) << line;
  EXPECT_NE(line.find("for its batch of 1024 (rate tuned at 32)"), std::string::npos) << line;
  Transitions t;
  const int rows = 1200;  // a minibatch's worth
  for (int i = 0; i < rows; ++i) {
    const int s = i % 2, a = (i / 2) % 2;
    const bool onward = s == 0 && a == 1;
    for (int k = 0; k < 2; ++k) {
      t.obs.push_back(k == s ? 1.f : 0.f);
      t.next_obs.push_back(onward && k == 1 ? 1.f : 0.f);
    }
    t.actions.push_back(float(a));
    t.rewards.push_back(s == 1 && a == 0 ? 1.f : 0.f);
    t.terminated.push_back(onward ? 0 : 1);
  }
  t.n = rows;
  std::vector<uint8_t> truncated(rows, 0);
  Batch b;
  b.num_steps = 1;
  b.num_envs = rows;
  b.truncated = truncated.data();
  b.rows = &t;
  algo->insert(b);
  ASSERT_GT(algo->ready(), 0);
  for (int call = 0; call < 50; ++call) {
    const auto figures = algo->update(8, uint64_t(call + 1));
    ASSERT_EQ(figures.size(), 8u);
    for (size_t k = 0; k < figures.size(); ++k) EXPECT_EQ(figures[k].update, int64_t(call * 8 + k + 1));
  }
  EXPECT_EQ(algo->updates(), 400);
  PolicyParams p = algo->policy(1000);
  p.epsilon = 0.f;
  Policy policy(p);
  const std::vector<float> states{1.f, 0.f, 0.f, 1.f};
  std::vector<float> greedy(2);
  std::mt19937_64 rng(1);
  policy.act(states.data(), 2, rng, true, greedy.data(), nullptr);
  EXPECT_EQ(greedy[0], 1.f) << "s0: on to s1";
  EXPECT_EQ(greedy[1], 0.f) << "s1: the rewarded action";
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

// Where a GPU and a CUDA LibTorch are there: a graph that draws its own batches from a replay on
// the GPU (dqn.replay_on_device), in groups as the learner calls it, computes what the eager update
// computes drawing the same rows (the same generator, the same offsets), in float32 and with
// bfloat16 products, at a batch on each side of the large-batch path's threshold (padding).
TEST(DqnCuda, GraphDrawsItsBatchesAsTheEagerUpdateDoes) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  for (const char* dtype : {"float32", "bfloat16"}) {
    for (const int batch : {64, 2048}) {
      SCOPED_TRACE(std::string(dtype) + ", batch " + std::to_string(batch));
      auto c = cuda_dqn_config(true);
      c.set_cuda_tf32(false);
      c.set_matmul_dtype(dtype);
      auto e = c;
      e.set_cuda_graph(false);
      Dqn graph(c, 4, 3, 5), eager(e, 4, 3, 5);
      if (!graph.uses_cuda_graph()) GTEST_SKIP() << "built against a LibTorch without CUDA";
      ReplayBuffer host(8000, 4, 1);
      DeviceReplay dev(8000, 4, 1, torch::Device(torch::kCUDA, 0), c.gamma());
      fill_replays(host, dev, 5000, 31);
      std::vector<DqnStats> got;
      torch::manual_seed(41);
      for (int n : {6, 1, 17, 8}) {
        const auto part = graph.update_n_from(n, batch, dev);
        EXPECT_EQ(part.size(), size_t(n));
        got.insert(got.end(), part.begin(), part.end());
      }
      torch::manual_seed(41);
      const auto want = eager.update_n_from(32, batch, dev);
      ASSERT_EQ(got.size(), want.size());
      const double tol = std::string(dtype) == "float32" ? 1e-4 : 1e-2;
      for (size_t i = 0; i < want.size(); ++i)
        EXPECT_NEAR(got[i].loss, want[i].loss, tol * std::max(1.0, std::abs(want[i].loss))) << "update " << i;
      EXPECT_EQ(graph.updates(), 32);
      EXPECT_LE(relative_gap(graph.online_parameters(), eager.online_parameters()), tol);
      EXPECT_LE(relative_gap(graph.target_parameters(), eager.target_parameters()), tol);
    }
  }
}
