#include "compute.h"
#include "device_replay.h"
#include "divergence.h"
#include "paths.h"  // remove_tree: std::filesystem::remove_all crashes the GPU build
#include "sac.h"
#include "sac_test_util.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

namespace farm {
namespace {

using namespace sac_test;

TEST(SacMath, CriticTargetHandComputed) {
  const auto r = torch::tensor({1.f, 1.f});
  const auto done = torch::tensor({0.f, 1.f});
  const auto q1 = torch::tensor({2.f, 2.f}), q2 = torch::tensor({3.f, 3.f});
  const auto logp = torch::tensor({-1.f, -1.f});
  const auto y = sac_critic_target(r, done, q1, q2, logp, 0.5, 0.9);
  // 1 + 0.9 * (min(2, 3) - 0.5 * -1) = 3.25; a terminated transition does not bootstrap.
  EXPECT_NEAR(y[0].item<float>(), 3.25f, 1e-6f);
  EXPECT_NEAR(y[1].item<float>(), 1.f, 1e-6f);
  // The smaller critic is the one used, whichever it is.
  const auto y2 = sac_critic_target(r, done, q2 * 0 + 4.f, q1, logp, 0.5, 0.9);
  EXPECT_NEAR(y2[0].item<float>(), 3.25f, 1e-6f);
}

TEST(SacMath, TemperatureLossValueAndGradientSign) {
  auto log_alpha = torch::full({1}, 0.3, torch::requires_grad());
  // Entropy 0.5 above a target of -1: alpha must go down, so the gradient is positive.
  auto logp = torch::tensor({-0.25f, -0.75f}, torch::requires_grad());
  auto loss = sac_temperature_loss(log_alpha, logp, -1.0);
  EXPECT_NEAR(loss.item<float>(), -0.3f * (-0.5f - 1.f), 1e-6f);
  loss.backward();
  EXPECT_NEAR(log_alpha.grad().item<float>(), 1.5f, 1e-6f);
  EXPECT_FALSE(logp.grad().defined()) << "the policy must get no gradient from the alpha loss";

  // Entropy -2 below the target: alpha must go up.
  log_alpha.mutable_grad().reset();
  sac_temperature_loss(log_alpha, torch::tensor({2.f}), -1.0).backward();
  EXPECT_NEAR(log_alpha.grad().item<float>(), -1.f, 1e-6f);
}

TEST(SacMath, SquashedGaussianLogProbMatchesDirectFormula) {
  torch::manual_seed(3);
  const auto mean = torch::randn({5, 3}), log_std = torch::rand({5, 3}) * 2 - 1.5;
  const auto pre = mean + log_std.exp() * torch::randn({5, 3});
  const auto got = squashed_gaussian_log_prob(mean, log_std, pre);
  ASSERT_EQ(got.sizes(), (std::vector<int64_t>{5}));
  for (int i = 0; i < 5; ++i) {
    double want = 0;
    for (int j = 0; j < 3; ++j) {
      const double m = mean[i][j].item<double>(), s = std::exp(log_std[i][j].item<double>());
      const double x = pre[i][j].item<double>(), a = std::tanh(x);
      want += -0.5 * ((x - m) / s) * ((x - m) / s) - std::log(s) - 0.5 * std::log(2 * M_PI);
      want -= std::log(1 - a * a + 1e-6);
    }
    EXPECT_NEAR(got[i].item<double>(), want, 1e-4) << i;
  }
}

TEST(Sac, ConfigDefaultsAreUsed) {
  config::SacConfig cfg;
  Sac sac(cfg, 3, 2, 1);
  EXPECT_EQ(sac.hidden(), (std::vector<int>{256, 256}));
  EXPECT_DOUBLE_EQ(sac.target_entropy(), -2.0);
  EXPECT_NEAR(sac.alpha(), cfg.initial_alpha(), 1e-6);
  cfg.set_target_entropy(-0.5);
  cfg.set_initial_alpha(0.2);
  Sac other(cfg, 3, 2, 1);
  EXPECT_DOUBLE_EQ(other.target_entropy(), -0.5);
  EXPECT_NEAR(other.alpha(), 0.2, 1e-6);
}

// device "auto" trains where a GPU is seen, else on the CPU; TF32 follows sac.cuda_tf32 on CUDA.
TEST(Sac, AutoDeviceTakesTheGpuWhereThereIsOne) {
  EXPECT_EQ(learner_device("auto", "sac.device").is_cuda(), torch::cuda::is_available());
  EXPECT_THROW(learner_device("gpu", "sac.device"), std::invalid_argument);
  config::SacConfig cfg;
  cfg.set_device("auto");
  cfg.set_cuda_tf32(false);
  Sac sac(cfg, 3, 1, 1);
  if (torch::cuda::is_available()) EXPECT_FALSE(at::globalContext().allowTF32CuBLAS());
}

// sac.actor_on_previous_critic: the actor steps against the critics as they were before this
// update's critic step. From the same start on the same batch: its actor is the actor of an
// update whose critics do not move (critic_lr 0), its critics are those of the default order, and
// its actor is not the default order's (whose actor saw the critics after their step).
TEST(Sac, ActorOnPreviousCriticStepsAgainstTheCriticsBeforeTheirStep) {
  auto after_cfg = small_config();
  auto beside_cfg = after_cfg;
  beside_cfg.set_actor_on_previous_critic(true);
  auto still_cfg = after_cfg;
  still_cfg.set_critic_lr(0.0);
  Sac after(after_cfg, 3, 2, 5), beside(beside_cfg, 3, 2, 5), still(still_cfg, 3, 2, 5);
  const auto critic0 = copies(still.critic_parameters());
  // random_batch seeds the generators, so the three draw the same policy noise.
  after.update(random_batch(64, 3, 2, 900));
  beside.update(random_batch(64, 3, 2, 900));
  still.update(random_batch(64, 3, 2, 900));
  EXPECT_TRUE(all_equal(still.critic_parameters(), critic0));
  EXPECT_TRUE(all_equal(beside.actor_parameters(), still.actor_parameters()));
  EXPECT_TRUE(all_equal(beside.critic_parameters(), after.critic_parameters()));
  EXPECT_FALSE(all_equal(beside.actor_parameters(), after.actor_parameters()));
  EXPECT_FALSE(all_equal(beside.critic_parameters(), critic0));
}

TEST(Sac, TargetsStartEqualAndMoveByTau) {
  const auto cfg = small_config();
  Sac sac(cfg, 3, 1, 7);
  const auto online0 = copies(sac.critic_parameters());
  const auto target0 = copies(sac.target_critic_parameters());
  ASSERT_EQ(online0.size(), target0.size());
  for (size_t i = 0; i < online0.size(); ++i) EXPECT_TRUE(torch::equal(online0[i], target0[i]));

  // Make target and online differ, so the polyak step is visible.
  for (int k = 0; k < 3; ++k) sac.update(random_batch(64, 3, 1, 100 + k));
  const auto target_before = copies(sac.target_critic_parameters());
  sac.update(random_batch(64, 3, 1, 200));
  const auto online_after = sac.critic_parameters();
  const auto target_after = sac.target_critic_parameters();
  const double tau = cfg.tau();
  double moved = 0;
  for (size_t i = 0; i < target_after.size(); ++i) {
    const auto want = (1 - tau) * target_before[i] + tau * online_after[i];
    EXPECT_TRUE(torch::allclose(target_after[i], want, 1e-5, 1e-7)) << "param " << i;
    moved += (target_after[i] - target_before[i]).abs().sum().item<double>();
  }
  EXPECT_GT(moved, 0.0);
  EXPECT_EQ(sac.updates(), 4);
}

TEST(Sac, CriticLossDecreasesOnFixedData) {
  auto cfg = small_config();
  cfg.set_gamma(0.5);  // a short horizon so the fixed point is reached within the test
  Sac sac(cfg, 3, 1, 11);
  const auto data = random_batch(128, 3, 1, 12);
  // Rewards a smooth function of the state, so there is something to fit.
  SampledBatch b = data;
  b.rewards = torch::sin(data.obs.select(1, 0)) + 0.5 * data.actions.select(1, 0);
  std::vector<double> losses;
  for (int i = 0; i < 400; ++i) losses.push_back(sac.update(b).critic_loss);
  auto mean_of = [&](int from, int to) {
    double s = 0;
    for (int i = from; i < to; ++i) s += losses[i];
    return s / (to - from);
  };
  const double first = mean_of(0, 20), last = mean_of(380, 400);
  EXPECT_TRUE(std::isfinite(last));
  EXPECT_LT(last, 0.5 * first) << "first " << first << ", last " << last;
}

// A one-step contextual bandit (every transition terminal, so Q is the reward): the actor must
// move its mean toward the best action, which checks the sign of every loss end to end.
TEST(Sac, ActorLearnsContextualBandit) {
  auto cfg = small_config();
  cfg.set_actor_lr(1e-3);
  cfg.set_critic_lr(1e-3);
  Sac sac(cfg, 1, 1, 31);
  auto best = [](const torch::Tensor& obs) { return 0.6 * obs.select(1, 0); };
  torch::manual_seed(32);
  const auto probe = torch::rand({64, 1}) * 2 - 1;
  auto error = [&] { return (sac.deterministic_action(probe).select(1, 0) - best(probe)).abs().mean().item<double>(); };
  const double before = error();
  for (int i = 0; i < 3000; ++i) {
    SampledBatch b;
    b.obs = torch::rand({128, 1}) * 2 - 1;
    b.actions = torch::rand({128, 1}) * 2 - 1;
    b.rewards = -(b.actions.select(1, 0) - best(b.obs)).square();
    b.terminated = torch::ones({128});
    b.next_obs = b.obs;
    sac.update(b);
  }
  const double after = error();
  EXPECT_LT(after, 0.1) << "before " << before;
  EXPECT_LT(after, 0.5 * before);
}

TEST(Sac, StatsAreFinite) {
  Sac sac(small_config(), 3, 1, 5);
  const auto st = sac.update(random_batch(32, 3, 1, 6));
  for (double v : {st.critic_loss, st.actor_loss, st.alpha, st.alpha_loss, st.entropy, st.q_mean})
    EXPECT_TRUE(std::isfinite(v));
  EXPECT_NEAR(st.alpha, 1.0, 1e-6) << "the alpha reported is the one the update used";
  // One Adam step moves log_alpha by about the learning rate.
  EXPECT_NEAR(std::log(sac.alpha()), 0.0, 1.5 * small_config().alpha_lr());
  EXPECT_NE(sac.alpha(), 1.0);
}

TEST(Sac, DivergedUpdateIsCaughtNamingTheFigures) {
  // Rewards near the float limit overflow the critic loss: the guard the learner runs after every
  // update must refuse it, naming the algorithm, the update and the loss; a sane update passes.
  Sac sac(small_config(), 3, 1, 5);
  auto st = sac.update(random_batch(32, 3, 1, 6));
  EXPECT_NO_THROW(require_finite_update("sac", sac.updates(), {{"critic loss", st.critic_loss}, {"alpha", st.alpha}}));
  auto b = random_batch(32, 3, 1, 7);
  b.rewards.fill_(3e38f);
  st = sac.update(b);
  ASSERT_FALSE(std::isfinite(st.critic_loss));
  try {
    require_finite_update("sac", sac.updates(), {{"critic loss", st.critic_loss}, {"alpha", st.alpha}});
    ADD_FAILURE() << "a non-finite critic loss passed";
  } catch (const std::runtime_error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("sac training diverged at update 2"), std::string::npos) << m;
    EXPECT_NE(m.find("critic loss inf"), std::string::npos) << m;
  }
}

TEST(Sac, SaveLoadRoundTrip) {
  const auto cfg = small_config();
  Sac a(cfg, 3, 2, 21);
  for (int k = 0; k < 5; ++k) a.update(random_batch(32, 3, 2, 300 + k));
  const std::string dir = temp_dir("sac_roundtrip");
  a.save(dir);

  Sac b(cfg, 3, 2, 99);
  b.load(dir);
  EXPECT_EQ(b.updates(), a.updates());
  EXPECT_NEAR(b.alpha(), a.alpha(), 0);
  torch::manual_seed(4);
  const auto obs = torch::randn({16, 3});
  EXPECT_TRUE(torch::equal(a.deterministic_action(obs), b.deterministic_action(obs)));
  const auto at = a.target_critic_parameters(), bt = b.target_critic_parameters();
  for (size_t i = 0; i < at.size(); ++i) EXPECT_TRUE(torch::equal(at[i], bt[i]));

  // Optimizer state came back too: the same next update gives the same networks.
  const auto batch = random_batch(32, 3, 2, 400);
  torch::manual_seed(8);
  a.update(batch);
  torch::manual_seed(8);
  b.update(batch);
  const auto ap = a.actor_parameters(), bp = b.actor_parameters();
  for (size_t i = 0; i < ap.size(); ++i) EXPECT_TRUE(torch::equal(ap[i], bp[i])) << i;
  const auto ac = a.critic_parameters(), bc = b.critic_parameters();
  for (size_t i = 0; i < ac.size(); ++i) EXPECT_TRUE(torch::equal(ac[i], bc[i])) << i;
  EXPECT_NEAR(a.alpha(), b.alpha(), 0);
  farm::remove_tree(dir);
}

// sac.n_step: a row spanning h steps bootstraps with gamma^h. From the same start on the same
// rows: rows of horizon 3 step as the one-step rows whose `terminated` is 1 - gamma^2 (worked out
// here, so gamma * (1 - terminated) = gamma^3), and not as the same rows taken as one step each.
TEST(Sac, MultiStepRowsBootstrapWithGammaToTheirHorizon) {
  const auto cfg = small_config();
  Sac three(cfg, 3, 2, 5), folded(cfg, 3, 2, 5), one(cfg, 3, 2, 5);
  SampledBatch b = random_batch(64, 3, 2, 900);
  b.horizon = torch::full({64}, 3.f);
  three.update(b);
  SampledBatch by_hand = random_batch(64, 3, 2, 900);
  const double g = cfg.gamma();
  by_hand.terminated = 1.f - float(g * g) * (1.f - by_hand.terminated);
  folded.update(by_hand);
  SampledBatch as_one = random_batch(64, 3, 2, 900);
  as_one.horizon = torch::ones({64});
  one.update(as_one);
  EXPECT_LT(relative_difference(three.critic_parameters(), folded.critic_parameters()), 1e-6);
  EXPECT_GT(relative_difference(three.critic_parameters(), one.critic_parameters()), 1e-6);
  // Horizon 1 everywhere is the one-step update exactly.
  Sac plain(cfg, 3, 2, 5);
  plain.update(random_batch(64, 3, 2, 900));
  EXPECT_TRUE(all_equal(plain.critic_parameters(), one.critic_parameters()));
  EXPECT_TRUE(all_equal(plain.actor_parameters(), one.actor_parameters()));
}

// update_n(n, next) is n calls of update(next()): same batches in the same order, same figures,
// same parameters after them. On the CPU the same arithmetic runs, so they agree exactly.
TEST(Sac, UpdateNIsUpdatesInARow) {
  auto cfg = small_config();
  Sac one(cfg, 3, 2, 5), group(cfg, 3, 2, 5);
  std::vector<SacStats> want;
  for (int k = 0; k < 12; ++k) want.push_back(one.update(random_batch(64, 3, 2, 700 + k)));
  int k = 0;
  auto next = [&] { return random_batch(64, 3, 2, 700 + k++); };
  std::vector<SacStats> got = group.update_n(5, next);
  const auto more = group.update_n(7, next);
  got.insert(got.end(), more.begin(), more.end());
  ASSERT_EQ(got.size(), want.size());
  EXPECT_EQ(group.updates(), 12);
  for (size_t i = 0; i < want.size(); ++i) expect_stats_near(got[i], want[i], 0.0, int(i));
  EXPECT_EQ(relative_difference(group.actor_parameters(), one.actor_parameters()), 0.0);
  EXPECT_EQ(relative_difference(group.critic_parameters(), one.critic_parameters()), 0.0);
}

// Updates from a replay kept where the networks train draw each batch as DeviceReplay::sample does
// (a uniform draw from torch's generator, then the policy's noise): the same figures and weights as
// update() on the host rows at those indices, multi-step rows bootstrapping alike (the copy keeps
// their horizons folded into `terminated`, the host a column of its own).
TEST(Sac, UpdatesFromADeviceReplayDrawTheirRowsFirst) {
  const auto cfg = small_config();
  Sac from_replay(cfg, 3, 2, 5), on_rows(cfg, 3, 2, 5);
  ReplayBuffer host(500, 3, 2);
  DeviceReplay dev(500, 3, 2, torch::kCPU, 0.99);
  fill_replays(host, dev, 300, 17);
  torch::manual_seed(23);
  const auto got = from_replay.update_n_from(5, 64, dev);
  torch::manual_seed(23);
  for (int k = 0; k < 5; ++k) {
    const auto u = torch::rand({64}, torch::TensorOptions().dtype(torch::kDouble));
    const SacStats want = on_rows.update(rows_at(host, (u * 300).to(torch::kLong)));
    expect_stats_near(got[k], want, 1e-6, k);
  }
  EXPECT_EQ(from_replay.updates(), 5);
  if (torch::cuda::is_available()) {  // networks on the CPU cannot draw from rows on a GPU
    DeviceReplay on_gpu(500, 3, 2, torch::Device(torch::kCUDA, 0), 0.99);
    fill_replays(host, on_gpu, 10, 19);
    EXPECT_THROW(from_replay.update_n_from(1, 64, on_gpu), std::invalid_argument);
  }
  EXPECT_LE(relative_difference(from_replay.actor_parameters(), on_rows.actor_parameters()), 1e-6);
  EXPECT_LE(relative_difference(from_replay.critic_parameters(), on_rows.critic_parameters()), 1e-6);
}

TEST(Sac, CriticHiddenSizesItsOwnLayers) {
  auto cfg = small_config();  // actor 32-32
  cfg.add_critic_hidden(24);
  cfg.add_critic_hidden(8);
  Sac sac(cfg, 3, 2, 1);
  const auto actor = sac.actor_parameters(), critic = sac.critic_parameters();
  EXPECT_EQ(actor.front().size(0), 32);
  // Twin critics, weights stored [2, in, out]: (obs + act) 5 -> 24 -> 8 -> 1.
  std::vector<std::vector<int64_t>> weights;
  for (const auto& p : critic)
    if (p.size(1) > 1) weights.push_back(p.sizes().vec());
  EXPECT_EQ(weights, (std::vector<std::vector<int64_t>>{{2, 5, 24}, {2, 24, 8}, {2, 8, 1}}));
  EXPECT_EQ(sac.export_policy(0).layout.sizes, (std::vector<int>{3, 32, 32, 4}));
  const auto stats = sac.update(random_batch(64, 3, 2, 3));
  EXPECT_TRUE(std::isfinite(stats.critic_loss));
}

TEST(Sac, LoadRejectsOtherShapesNamingFile) {
  const std::string dir = temp_dir("sac_mismatch");
  Sac(small_config(), 3, 1, 1).save(dir);
  auto expect_error = [&](Sac& other) {
    try {
      other.load(dir);
      ADD_FAILURE() << "no error";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(dir + "/sac.pt"), std::string::npos) << e.what();
    }
  };
  config::SacConfig wider;
  wider.add_hidden(64);
  wider.add_hidden(32);
  auto other_critic = small_config();
  other_critic.add_critic_hidden(16);
  Sac other_hidden(wider, 3, 1, 1), other_obs(small_config(), 4, 1, 1), other_q(other_critic, 3, 1, 1);
  auto tanh = small_config();
  tanh.set_activation(small_config().activation() == "tanh" ? "relu" : "tanh");
  Sac other_activation(tanh, 3, 1, 1);
  expect_error(other_hidden);
  expect_error(other_obs);
  expect_error(other_q);
  expect_error(other_activation);  // before, the weights of one activation ran under the other
  Sac missing(small_config(), 3, 1, 1);
  farm::remove_tree(dir);
  expect_error(missing);
}

TEST(Sac, ExportPolicyLayout) {
  auto cfg = small_config();
  cfg.set_log_std_min(-5);
  cfg.set_log_std_max(1);
  Sac sac(cfg, 3, 2, 1);
  const PolicyParams p = sac.export_policy(42);
  EXPECT_EQ(p.version, 42u);
  EXPECT_EQ(p.head, PolicyHead::kSquashedGaussian);
  EXPECT_EQ(p.layout.sizes, (std::vector<int>{3, 32, 32, 4}));
  EXPECT_EQ(p.layout.activation, Activation::kRelu);
  EXPECT_TRUE(p.obs_mean.empty());
  EXPECT_TRUE(p.obs_std.empty());
  EXPECT_FLOAT_EQ(p.log_std_min, -5.f);
  EXPECT_FLOAT_EQ(p.log_std_max, 1.f);
  const size_t want = (3 * 32 + 32) + (32 * 32 + 32) + (32 * 4 + 4);
  EXPECT_EQ(p.params.size(), want);
  EXPECT_EQ(p.layout.num_params(), want);
  // Flat order: first layer's weight row-major, then its bias.
  const auto params = sac.actor_parameters();
  const auto w0 = params[0].contiguous();
  ASSERT_EQ(w0.sizes(), (std::vector<int64_t>{32, 3}));
  EXPECT_EQ(p.params[1], w0[0][1].item<float>());
  EXPECT_EQ(p.params[3], w0[1][0].item<float>());
  EXPECT_EQ(p.params[3 * 32], params[1][0].item<float>());
}

// The actor's parameters in the workers' flat order (ExportPolicyLayout): per layer, weight then bias.
std::vector<float> actor_flat(const Sac& sac) {
  std::vector<torch::Tensor> parts;
  for (const auto& t : sac.actor_parameters()) parts.push_back(t.detach().contiguous().reshape({-1}));
  const auto flat = torch::cat(parts);
  return {flat.data_ptr<float>(), flat.data_ptr<float>() + flat.numel()};
}

void expect_params_near(const std::vector<float>& got, const std::vector<float>& want, const char* what) {
  ASSERT_EQ(got.size(), want.size()) << what;
  for (size_t i = 0; i < got.size(); ++i) ASSERT_NEAR(got[i], want[i], 1e-6) << what << ", parameter " << i;
}

// sac.policy_average_tau: the published policy is the actor until the first update, the actor
// after it, then average + tau * (actor - average) after each update; a checkpoint brings the
// average back, and a config without the average publishes the actor again.
TEST(Sac, PublishedPolicyIsAPolyakAverageOfTheActor) {
  auto cfg = small_config();
  cfg.set_policy_average_tau(0.25);
  Sac a(cfg, 3, 2, 17);
  expect_params_near(a.export_policy(0).params, actor_flat(a), "before any update");
  a.update(random_batch(32, 3, 2, 501));
  const auto first = actor_flat(a);
  expect_params_near(a.export_policy(0).params, first, "after the first update");
  a.update(random_batch(32, 3, 2, 502));
  const auto second = actor_flat(a);
  std::vector<float> want(first.size());
  for (size_t i = 0; i < want.size(); ++i) want[i] = first[i] + 0.25f * (second[i] - first[i]);
  expect_params_near(a.export_policy(0).params, want, "after the second update");
  double moved = 0;
  for (size_t i = 0; i < want.size(); ++i) moved += std::abs(second[i] - first[i]);
  EXPECT_GT(moved, 0) << "the second update did not move the actor: the test shows nothing";

  const std::string dir = temp_dir("sac_policy_average");
  a.save(dir);
  Sac b(cfg, 3, 2, 99);
  b.load(dir);
  expect_params_near(b.export_policy(0).params, want, "loaded");
  Sac c(small_config(), 3, 2, 99);
  c.load(dir);
  expect_params_near(c.export_policy(0).params, second, "loaded without policy_average_tau");
  farm::remove_tree(dir);
}

// The sizes of one update's steps on `batch`: the critics' (summed over their parameters) and the
// temperature's (log alpha), with LibTorch's generator at a fixed state so two instances draw the
// same policy noise.
struct StepSizes {
  double critics, temperature;
};
StepSizes step_sizes(Sac& sac, const SampledBatch& batch) {
  const auto before = copies(sac.critic_parameters());
  const double log_alpha = std::log(sac.alpha());
  torch::manual_seed(8);
  sac.update(batch);
  const auto after = sac.critic_parameters();
  double sum = 0;
  for (size_t i = 0; i < after.size(); ++i) sum += (after[i] - before[i]).abs().sum().item<double>();
  return {sum, std::abs(std::log(sac.alpha()) - log_alpha)};
}

// Adam's step is proportional to its learning rate at the same moments, so from the same state the
// scaled instance's critics and temperature move by the scale's multiple (the temperature's falls
// by at most about alpha_lr per update, so a larger step that left it out would hold a run's
// temperature schedule to the seed's count of updates); a loaded checkpoint written at another
// scale does not bring its learning rates along.
TEST(Sac, LearningRateScaleScalesTheStepAndOutlivesLoad) {
  const auto cfg = small_config();
  const auto batch = random_batch(32, 3, 2, 500);
  Sac plain(cfg, 3, 2, 5), scaled(cfg, 3, 2, 5);
  scaled.scale_learning_rates(4.0);
  EXPECT_EQ(scaled.learning_rate_scale(), 4.0);
  const StepSizes at4 = step_sizes(scaled, batch), at1 = step_sizes(plain, batch);
  ASSERT_GT(at1.temperature, 0.0);
  EXPECT_NEAR(at4.critics / at1.critics, 4.0, 1e-3);
  EXPECT_NEAR(at4.temperature / at1.temperature, 4.0, 1e-3);

  for (int k = 0; k < 4; ++k) scaled.update(random_batch(32, 3, 2, 510 + k));
  const std::string dir = temp_dir("sac_lr_scale");
  scaled.save(dir);
  Sac own(cfg, 3, 2, 6), twice(cfg, 3, 2, 6);
  twice.scale_learning_rates(2.0);
  own.load(dir);
  twice.load(dir);
  EXPECT_EQ(own.learning_rate_scale(), 1.0);
  EXPECT_EQ(twice.learning_rate_scale(), 2.0);
  const StepSizes at2 = step_sizes(twice, batch), own1 = step_sizes(own, batch);
  EXPECT_NEAR(at2.critics / own1.critics, 2.0, 1e-3);
  EXPECT_NEAR(at2.temperature / own1.temperature, 2.0, 1e-3);
  farm::remove_tree(dir);

  EXPECT_THROW(plain.scale_learning_rates(0.0), std::invalid_argument);
  EXPECT_THROW(plain.scale_learning_rates(NAN), std::invalid_argument);
}

}  // namespace
}  // namespace farm
