// PPO's small parts: GAE, the KL-adaptive rate, the fit scheduler and the dataset shape of seed
// 000 §3.1, the running observation normalizer, and the PPO learner itself (its log-probabilities against the workers',
// its exported network against the LibTorch actor for each activation, and a short fit that must move the policy toward
// the better action).
#include <gtest/gtest.h>
#include <torch/cuda.h>
#include <unistd.h>

#include "config.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <numeric>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "fit_scheduler.h"
#include "gae.h"
#include "mlp.h"
#include "obs_normalizer.h"
#include "paths.h"  // remove_tree: std::filesystem::remove_all crashes the GPU build
#include "ppo.h"
#include "ppo_algorithm.h"

using namespace farm;

TEST(Gae, HandComputedSequenceBootstrapsOnTruncationNotOnTermination) {
  // gamma 0.9, lambda 0.5. Step 1 is truncated (time limit): it bootstraps on the value of its
  // true final observation (10) and cuts the advantage chain. Step 3 terminates: no future at
  // all, its next value (7) must be ignored. Step 4 ends the segment: bootstrap on 4.
  const float r[] = {1, 2, 3, 4, 5};
  const float v[] = {0.5f, 1, 1.5f, 2, 2.5f};
  const float nv[] = {1, 10, 2, 7, 4};
  const uint8_t term[] = {0, 0, 0, 1, 0};
  const uint8_t trunc[] = {0, 1, 0, 0, 0};
  float adv[5], ret[5];
  compute_gae(r, v, nv, term, trunc, 5, 0.9, 0.5, adv, ret);
  // delta: 1.4, 10, 3.3, 2, 6.1; A_t = delta_t + 0.45 * A_{t+1} within an episode.
  const float want_adv[] = {1.4f + 0.45f * 10.f, 10.f, 3.3f + 0.45f * 2.f, 2.f, 6.1f};
  for (int t = 0; t < 5; ++t) {
    EXPECT_NEAR(adv[t], want_adv[t], 1e-5) << "t=" << t;
    EXPECT_NEAR(ret[t], want_adv[t] + v[t], 1e-5) << "t=" << t;
  }
}

TEST(Gae, LambdaOneGivesDiscountedReturnsLambdaZeroGivesTdErrors) {
  const float r[] = {1, 1, 1};
  const float v[] = {0, 0, 0};
  const float nv[] = {0, 0, 2};
  const uint8_t no[] = {0, 0, 0};
  float adv[3], ret[3];
  compute_gae(r, v, nv, no, no, 3, 0.5, 1.0, adv, ret);
  EXPECT_NEAR(ret[0], 1 + 0.5 + 0.25 + 0.125 * 2, 1e-6);
  compute_gae(r, v, nv, no, no, 3, 0.5, 0.0, adv, ret);
  EXPECT_NEAR(adv[0], 1.0, 1e-6);
  EXPECT_NEAR(adv[2], 2.0, 1e-6);
}

TEST(VTrace, WithTheCurrentPolicysOwnStepsItIsGae) {
  const float r[] = {1, 2, 3, 4, 5};
  const float v[] = {0.5f, 1, 1.5f, 2, 2.5f};
  const float nv[] = {1, 10, 2, 7, 4};
  const uint8_t term[] = {0, 0, 0, 1, 0};
  const uint8_t trunc[] = {0, 1, 0, 0, 0};
  const float zero[5] = {0, 0, 0, 0, 0};
  float adv[5], ret[5], gadv[5], gret[5];
  compute_vtrace(r, v, nv, term, trunc, zero, 5, 0.9, 0.5, 1.0, 1.0, adv, ret);
  compute_gae(r, v, nv, term, trunc, 5, 0.9, 0.5, gadv, gret);
  for (int t = 0; t < 5; ++t) {
    EXPECT_FLOAT_EQ(adv[t], gadv[t]) << "t=" << t;
    EXPECT_FLOAT_EQ(ret[t], gret[t]) << "t=" << t;
  }
}

TEST(VTrace, HandComputedTruncatedImportanceWeights) {
  // gamma 0.5, lambda 1, rho_bar 1, c_bar 1. Step 0: ratio 2, truncated to 1 (rho and c); step
  // 1: ratio 0.5 weighs its TD error and the trace back to step 0; step 2 ends the segment and
  // bootstraps on its next value 4 with ratio 1.
  const float r[] = {1, 1, 1};
  const float v[] = {0, 0, 0};
  const float nv[] = {0, 0, 4};
  const uint8_t no[] = {0, 0, 0};
  const float log_ratio[] = {std::log(2.f), std::log(0.5f), 0.f};
  float adv[3], ret[3];
  compute_vtrace(r, v, nv, no, no, log_ratio, 3, 0.5, 1.0, 1.0, 1.0, adv, ret);
  const double a2 = 1 + 0.5 * 4;               // delta_2 = 3
  const double a1 = 0.5 * 1 + 0.5 * 0.5 * a2;  // rho_1 = c_1 = 0.5
  const double a0 = 1 + 0.5 * 1 * a1;          // rho_0 = c_0 = min(1, 2)
  EXPECT_NEAR(adv[2], a2, 1e-6);
  EXPECT_NEAR(adv[1], a1, 1e-6);
  EXPECT_NEAR(adv[0], a0, 1e-6);
  EXPECT_NEAR(ret[0], a0, 1e-6);  // values 0: the targets are the advantages
  // A higher rho_bar lets step 0's weight of 2 through; c_bar 1 still truncates its trace.
  compute_vtrace(r, v, nv, no, no, log_ratio, 3, 0.5, 1.0, 4.0, 1.0, adv, ret);
  EXPECT_NEAR(adv[0], 2 * 1 + 0.5 * 1 * a1, 1e-6);
}

TEST(KlAdaptiveRate, LowersAboveTheBandRaisesBelowKeepsInside) {
  config::PpoConfig c;  // desired_kl 0.01, band 2, factor 1.5, rate in [1e-5, 1e-2]
  EXPECT_NEAR(adapt_learning_rate(1e-3, 0.05, c), 1e-3 / 1.5, 1e-12);
  EXPECT_NEAR(adapt_learning_rate(1e-3, 0.001, c), 1e-3 * 1.5, 1e-12);
  EXPECT_EQ(adapt_learning_rate(1e-3, 0.01, c), 1e-3);
  EXPECT_EQ(adapt_learning_rate(1e-3, 0.0199, c), 1e-3);
  EXPECT_EQ(adapt_learning_rate(1e-3, 0.0051, c), 1e-3);
  EXPECT_EQ(adapt_learning_rate(1.2e-5, 1.0, c), 1e-5);  // floor
  EXPECT_EQ(adapt_learning_rate(9e-3, 0.0, c), 1e-2);    // ceiling
  EXPECT_EQ(adapt_learning_rate(1e-3, NAN, c), 1e-3);    // no measurement, no change
}

namespace {

struct SimResult {
  std::vector<FitScheduler::Fit> fits;
  int64_t max_held = 0;  // most steps held at once for one fit (carry included)
  int64_t steps = 0, episodes = 0;
};

// A vectorized core in miniature: num_envs envs whose episodes last `horizon` steps; each step
// the mask says how many run (envs 0..active-1); fits are taken when due.
SimResult simulate(const FitPlan& plan, int num_envs, int horizon, int max_steps = 100000) {
  FitScheduler s(plan);
  std::vector<int> t(num_envs, 0);
  SimResult out;
  for (int k = 0; k < max_steps && !s.run_done(); ++k) {
    const int64_t active = s.active_envs(num_envs);
    if (active == 0) break;
    int64_t ended = 0;
    for (int i = 0; i < active; ++i)
      if (++t[i] == horizon) {
        t[i] = 0;
        ++ended;
      }
    s.on_data(active, ended);
    out.max_held = std::max(out.max_held, s.fit_steps());
    while (s.fit_due()) out.fits.push_back(s.take_fit());
  }
  out.steps = s.run_steps();
  out.episodes = s.run_episodes();
  return out;
}

}  // namespace

TEST(FitScheduler, StepsPerFitCarriesTheSurplusOver) {
  FitPlan p;
  p.steps_per_fit = 100;
  FitScheduler s(p);
  for (int k = 0; k < 7; ++k) s.on_data(16, 0);  // 112 steps
  ASSERT_TRUE(s.fit_due());
  auto f = s.take_fit();
  EXPECT_EQ(f.steps_used, 100);
  EXPECT_EQ(f.steps_carried, 12);
  EXPECT_FALSE(s.fit_due());
  EXPECT_EQ(s.steps_wanted(), 88);
  for (int k = 0; k < 6; ++k) s.on_data(16, 0);  // 12 + 96 = 108
  f = s.take_fit();
  EXPECT_EQ(f.steps_used, 100);
  EXPECT_EQ(f.steps_carried, 8);
  EXPECT_EQ(s.active_envs(16), 16);  // by steps, every env runs
}

TEST(FitScheduler, StepsPerFitNeverHoldsMoreThanTheCorrectedDatasetShape) {
  for (int envs : {1, 3, 16, 64}) {
    for (int64_t spf : {10, 100, 1000}) {
      FitPlan p;
      p.steps_per_fit = spf;
      p.steps_per_run = 20 * spf;
      SimResult r = simulate(p, envs, 7);
      const DatasetShape d = dataset_shape(p, envs, 7);
      EXPECT_EQ(d.cols, envs);
      EXPECT_EQ(d.rows, (spf + envs - 1) / envs + 1);
      EXPECT_LE(r.max_held, d.rows * d.cols) << envs << " envs, " << spf << " steps per fit";
      EXPECT_EQ(r.steps, p.steps_per_run) << "the run made steps it does not use";
      int64_t used = 0;
      for (auto& f : r.fits) used += f.steps_used;
      EXPECT_EQ(used, p.steps_per_run);
    }
  }
}

TEST(FitScheduler, EpisodesPerFitBelowTheEnvCountRunsOnlyThatManyEnvs) {
  FitPlan p;
  p.episodes_per_fit = 3;
  p.episodes_per_run = 6;
  FitScheduler s(p);
  EXPECT_EQ(s.active_envs(8), 3);  // the mask: 3 of 8 envs
  SimResult r = simulate(p, 8, 10);
  ASSERT_EQ(r.fits.size(), 2u);
  for (auto& f : r.fits) {
    EXPECT_EQ(f.steps_used, 30);  // 3 episodes of 10 steps, nothing more
    EXPECT_EQ(f.steps_carried, 0);
    EXPECT_EQ(f.episodes, 3);
  }
  const DatasetShape d = dataset_shape(p, 8, 10);
  EXPECT_EQ(d.rows, 10);
  EXPECT_EQ(d.cols, 3);
  EXPECT_EQ(r.max_held, d.rows * d.cols);
}

TEST(FitScheduler, StepsPerFitWithEpisodesPerRun) {
  FitPlan p;
  p.steps_per_fit = 50;
  p.episodes_per_run = 5;
  SimResult r = simulate(p, 4, 20);
  // 4 envs run 20 steps (4 episodes), then the mask keeps 1 env for the fifth episode.
  EXPECT_EQ(r.episodes, 5);
  EXPECT_EQ(r.steps, 100);
  int64_t used = 0;
  for (auto& f : r.fits) used += f.steps_used;
  EXPECT_EQ(used, 100);
  ASSERT_GE(r.fits.size(), 2u);
  EXPECT_EQ(r.fits[0].steps_used, 50);
  EXPECT_EQ(r.fits[0].steps_carried, 2);  // 13 steps x 4 envs = 52
}

TEST(FitScheduler, EpisodesPerFitWithStepsPerRun) {
  FitPlan p;
  p.episodes_per_fit = 4;
  p.steps_per_run = 50;
  SimResult r = simulate(p, 4, 10);
  EXPECT_EQ(r.steps, 50);  // 40 in the first fit, then 4 + 4 + 2: never past the run's length
  ASSERT_EQ(r.fits.size(), 2u);
  EXPECT_EQ(r.fits[0].steps_used, 40);
  EXPECT_EQ(r.fits[0].episodes, 4);
  EXPECT_EQ(r.fits[1].steps_used, 10);  // the run's last, partial fit
}

TEST(FitScheduler, DatasetShapeIsTheCorrectedFormulaNotTheFaultyOne) {
  FitPlan p;
  p.steps_per_fit = 98304;  // MushroomRL paper appendix
  auto d = dataset_shape(p, 4096, 1000);
  EXPECT_EQ(d.rows, 98304 / 4096 + 1);  // (ceil(N_steps / N_envs) + 1, N_envs)
  EXPECT_EQ(d.cols, 4096);
  EXPECT_LT(d.rows * d.cols, int64_t(98304) * 4096);  // the faulty (N_steps, N_envs)
  p.steps_per_fit = 100;
  EXPECT_EQ(dataset_shape(p, 16, 1).rows, 8);  // ceil(100 / 16) + 1
  FitPlan e;
  e.episodes_per_fit = 20;
  d = dataset_shape(e, 8, 50);  // (ceil(N_ep / N_envs) * horizon, min(N_envs, N_ep))
  EXPECT_EQ(d.rows, 150);
  EXPECT_EQ(d.cols, 8);
}

TEST(FitScheduler, BadPlansAreRefusedWithTheFieldNamed) {
  FitPlan both;
  both.steps_per_fit = 10;
  both.episodes_per_fit = 2;
  try {
    FitScheduler s(both);
    FAIL() << "accepted both triggers";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("episodes_per_fit"), std::string::npos) << e.what();
  }
  EXPECT_THROW(FitScheduler(FitPlan{}), std::invalid_argument);
}

TEST(ObsNormalizer, RunningMomentsMatchTheWholeDataAndShipSafeStd) {
  std::mt19937_64 rng(5);
  std::normal_distribution<float> a(3.f, 2.f), b(-1.f, 0.5f);
  std::vector<float> obs;
  for (int i = 0; i < 3000; ++i) {
    obs.push_back(a(rng));
    obs.push_back(b(rng));
    obs.push_back(7.f);  // constant entry
  }
  ObsNormalizer whole(3), parts(3);
  whole.update(obs.data(), 3000);
  parts.update(obs.data(), 1);
  parts.update(obs.data() + 3, 999);
  parts.update(obs.data() + 3000, 2000);
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(parts.mean()[i], whole.mean()[i], 1e-4);
    EXPECT_NEAR(parts.std()[i], whole.std()[i], 1e-4);
  }
  EXPECT_NEAR(whole.mean()[0], 3.0, 0.15);
  EXPECT_NEAR(whole.std()[0], 2.0, 0.1);
  EXPECT_NEAR(whole.std()[1], 0.5, 0.03);
  EXPECT_GT(whole.std()[2], 0.f);             // floored, not 0
  EXPECT_EQ(ObsNormalizer(2).std()[0], 1.f);  // nothing seen: identity
}

namespace {
// Saves a fresh Ppo of config c into dir (a folder under root), loads it into another of a
// different seed and expects the same exported policy; removes root.
void expect_save_load_round_trip(const config::PpoConfig& c, const std::filesystem::path& root,
                                 const std::filesystem::path& dir) {
  Ppo a(c, 3, 2, 5), b(c, 3, 2, 9);
  a.save(dir.string());
  b.load(dir.string());
  const PolicyParams pa = a.export_policy(0), pb = b.export_policy(0);
  EXPECT_EQ(pb.params, pa.params);
  EXPECT_EQ(pb.log_std, pa.log_std);
  farm::remove_tree(root.string());
}
}  // namespace

// Only where a GPU and a CUDA LibTorch are there: a checkpoint is read back onto the GPU (a GPU
// run's --resume). Its tensors land on the device; what is read on the host (the normalizer's
// moments) is copied back first, not read from GPU memory (which crashed the load).
TEST(PpoCuda, CheckpointLoadsBackOntoTheGpu) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  config::PpoConfig c;
  c.set_device("cuda");
  const auto dir = std::filesystem::temp_directory_path() / ("ppo_cuda_" + std::to_string(::getpid()));
  expect_save_load_round_trip(c, dir, dir);
}

// Ppo::save makes the folder it is given, as Sac::save and Dqn::save do.
TEST(Ppo, SaveMakesItsFolderAndLoadsBack) {
  const auto root = std::filesystem::temp_directory_path() / ("ppo_save_" + std::to_string(::getpid()));
  const auto dir = root / "not" / "yet";
  ASSERT_FALSE(std::filesystem::exists(dir));
  expect_save_load_round_trip(config::PpoConfig(), root, dir);
}

// A checkpoint of other networks is refused, naming the file: before, Module::load took the saved
// shapes as they were (the policy exported half-sized, every worker refusing it) and another
// activation ran the weights through the wrong function.
TEST(Ppo, LoadRefusesNetworksOfAnotherShapeOrActivation) {
  const auto dir = std::filesystem::temp_directory_path() / ("ppo_other_" + std::to_string(::getpid()));
  config::PpoConfig c;
  c.clear_hidden();
  c.add_hidden(16);
  c.add_hidden(16);
  Ppo(c, 3, 2, 5).save(dir.string());
  auto refused = [&](const config::PpoConfig& other, const std::string& why) {
    Ppo b(other, 3, 2, 9);
    try {
      b.load(dir.string());
      ADD_FAILURE() << "loaded: " << why;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find((dir / "ppo.pt").string()), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(why), std::string::npos) << e.what();
    }
  };
  auto wider = c;
  wider.set_hidden(1, 32);
  refused(wider, "actor.l1.weight has shape [16, 16], this config's ppo.hidden makes [32, 16]");
  auto elu = c;
  elu.set_activation("elu");
  refused(elu, "another activation than this config's ppo.activation 'elu'");
  farm::remove_tree(dir.string());
}

// The plain variant's rate is this run's config, as SAC's and DQN's are; clip_kl's adapted rate goes
// on, within this config's bounds.
TEST(Ppo, LoadTakesThePlainRateFromTheConfigAndKeepsTheAdaptedOne) {
  const auto dir = std::filesystem::temp_directory_path() / ("ppo_rate_" + std::to_string(::getpid()));
  // The rate of a Ppo of config `resume` after loading one of config `saved`.
  const auto resumed_rate = [&](const config::PpoConfig& saved, const config::PpoConfig& resume) {
    Ppo(saved, 3, 2, 5).save(dir.string());
    Ppo b(resume, 3, 2, 9);
    b.load(dir.string());
    return b.learning_rate();
  };
  config::PpoConfig plain, plain_later;
  plain.set_variant("plain");
  plain.set_learning_rate(1e-3);
  plain_later = plain;
  plain_later.set_learning_rate(5e-4);
  EXPECT_DOUBLE_EQ(resumed_rate(plain, plain_later), 5e-4);

  config::PpoConfig adaptive, adaptive_later;
  adaptive.set_learning_rate(3e-3);
  adaptive_later.set_learning_rate(1e-4);
  EXPECT_DOUBLE_EQ(resumed_rate(adaptive, adaptive_later), 3e-3);
  adaptive_later.set_lr_max(2e-3);
  EXPECT_DOUBLE_EQ(resumed_rate(adaptive, adaptive_later), 2e-3);
  farm::remove_tree(dir.string());
}

TEST(Ppo, LearnerLogProbsMatchTheWorkersIncludingClampedActions) {
  config::PpoConfig c;
  c.set_initial_log_std(0.3);  // wide: many samples land beyond [-1, 1] and are clamped
  Ppo ppo(c, 3, 2, 11);
  PolicyParams p = ppo.export_policy(0);
  ASSERT_EQ(p.head, PolicyHead::kGaussian);
  Policy pol(p);
  std::mt19937_64 rng(3);
  std::normal_distribution<float> g(0.f, 2.f);
  const int rows = 400;
  std::vector<float> obs(rows * 3), act(rows * 2), lp(rows);
  for (auto& x : obs) x = g(rng);
  pol.act(obs.data(), rows, rng, false, act.data(), lp.data());
  int clamped = 0;
  for (float a : act) clamped += (a == 1.f || a == -1.f);
  EXPECT_GT(clamped, 50);
  const auto learner_lp = ppo.log_probs(obs.data(), act.data(), rows);
  for (int r = 0; r < rows; ++r) ASSERT_NEAR(learner_lp[r], lp[r], 2e-4) << "row " << r;
}

TEST(Ppo, FitsTowardTheBetterActionAndReportsItsNumbers) {
  // A one-step bandit: reward -(a - 0.5)^2 whatever the observation. A few fits must move the
  // deterministic action from about 0 toward 0.5.
  for (const char* variant : {"plain", "clip_kl"}) {
    config::PpoConfig c;
    c.set_variant(variant);
    c.set_learning_rate(3e-3);
    c.set_mini_batch_size(256);
    // Narrow enough that clamping at +-1 barely moves the optimum: with a wide Gaussian the
    // clamped mass at -1 costs more than at +1, and the best mean sits well above 0.5.
    c.set_initial_log_std(std::log(0.3));
    Ppo ppo(c, 2, 1, 21);
    std::mt19937_64 rng(9);
    std::normal_distribution<float> g(0.f, 1.f);
    const int n = 1024;
    PpoStats st;
    for (int fit = 0; fit < 15; ++fit) {
      Policy pol(ppo.export_policy(fit));
      PpoSamples s;
      s.n = n;
      s.obs.resize(n * 2);
      for (auto& x : s.obs) x = g(rng);
      s.actions.resize(n);
      s.behaviour_log_prob.resize(n);
      pol.act(s.obs.data(), n, rng, false, s.actions.data(), s.behaviour_log_prob.data());
      s.current.assign(n, 1);
      const auto v = ppo.values(s.obs.data(), n);
      s.advantages.resize(n);
      s.returns.resize(n);
      for (int i = 0; i < n; ++i) {
        const float r = -(s.actions[i] - 0.5f) * (s.actions[i] - 0.5f);
        s.returns[i] = r;
        s.advantages[i] = r - v[i];
      }
      st = ppo.fit(s);
      ppo.normalizer().update(s.obs.data(), n);
    }
    Policy pol(ppo.export_policy(99));
    std::vector<float> o(200 * 2), a(200);
    for (auto& x : o) x = g(rng);
    pol.act(o.data(), 200, rng, true, a.data(), nullptr);
    const double mean_a = std::accumulate(a.begin(), a.end(), 0.0) / 200;
    EXPECT_NEAR(mean_a, 0.5, 0.15) << variant;
    EXPECT_EQ(st.samples, n);
    EXPECT_EQ(st.minibatches, 4 * c.epochs());
    EXPECT_GT(st.kl, 0.0) << variant;
    EXPECT_GE(st.clip_fraction, 0.0);
    EXPECT_LE(st.clip_fraction, 1.0);
    EXPECT_TRUE(std::isfinite(st.value_loss));
    EXPECT_EQ(ppo.fits(), 15);
    if (std::string(variant) == "plain") EXPECT_EQ(st.learning_rate, 3e-3);  // no adaptation
  }
}

TEST(Ppo, KlAdaptiveVariantLowersAnOversizedRate) {
  config::PpoConfig c;
  c.set_learning_rate(5e-2);  // far too large: the KL leaves the band at once
  c.set_lr_max(5e-2);
  c.set_mini_batch_size(64);
  Ppo ppo(c, 1, 1, 4);
  std::mt19937_64 rng(2);
  Policy pol(ppo.export_policy(0));
  PpoSamples s;
  s.n = 512;
  s.obs.assign(512, 0.f);
  s.actions.resize(512);
  s.behaviour_log_prob.resize(512);
  pol.act(s.obs.data(), 512, rng, false, s.actions.data(), s.behaviour_log_prob.data());
  s.current.assign(512, 1);
  s.returns.assign(512, 0.f);
  s.advantages.resize(512);
  for (int i = 0; i < 512; ++i) s.advantages[i] = s.actions[i];
  const PpoStats st = ppo.fit(s);
  EXPECT_LT(st.learning_rate, 5e-2);
  EXPECT_EQ(st.learning_rate, ppo.learning_rate());
}

namespace {

// Steps of an older version whose every ratio against the behaviour is past the clip range in the
// direction its advantage pushes: +1 where the action is above the (zero-observation) mean, with the
// behaviour's log-probability 1 below the current policy's (ratio e), -1 below it, 1 above (1/e).
PpoSamples stale_steps_past_the_clip(const Ppo& ppo, int n, uint8_t current) {
  std::mt19937_64 rng(5);
  Policy pol(ppo.export_policy(0));
  PpoSamples s;
  s.n = n;
  s.obs.assign(n, 0.f);
  s.actions.resize(n);
  std::vector<float> lp(n);
  pol.act(s.obs.data(), n, rng, false, s.actions.data(), lp.data());
  std::vector<float> mean(1);
  pol.act(s.obs.data(), 1, rng, true, mean.data(), nullptr);
  const auto now = ppo.log_probs(s.obs.data(), s.actions.data(), n);
  s.advantages.resize(n);
  s.behaviour_log_prob.resize(n);
  for (int i = 0; i < n; ++i) {
    const bool up = s.actions[i] > mean[0];
    s.advantages[i] = up ? 1.f : -1.f;
    s.behaviour_log_prob[i] = now[i] + (up ? -1.f : 1.f);
  }
  s.current.assign(n, current);
  s.returns.assign(n, 0.f);
  return s;
}

config::PpoConfig surrogate_config(const char* surrogate) {
  config::PpoConfig c;
  c.set_variant("plain");
  c.set_mini_batch_size(128);
  c.set_learning_rate(1e-2);
  c.set_normalize_advantages(false);
  c.set_surrogate(surrogate);
  return c;
}

}  // namespace

// Stale steps already past the clip range at a fit's start: the behaviour surrogate (APPO) takes
// no gradient from them and the policy stays where it was (KL exactly 0); the proximal one
// (decoupled PPO) starts each ratio at 1 against the fit's own start and learns from them, the
// mean moving the way the advantages point. With steps of the fitted version both are one fit.
TEST(Ppo, ProximalSurrogateLearnsFromStaleStepsTheBehaviourOneClipsAway) {
  const int n = 512;
  Ppo behaviour(surrogate_config("behaviour"), 1, 1, 3), proximal(surrogate_config("proximal"), 1, 1, 3);
  const PpoStats b = behaviour.fit(stale_steps_past_the_clip(behaviour, n, 0));
  const PpoStats p = proximal.fit(stale_steps_past_the_clip(proximal, n, 0));
  EXPECT_EQ(b.kl, 0.0);
  EXPECT_DOUBLE_EQ(b.clip_fraction, 1.0);
  EXPECT_GT(p.kl, 1e-4);
  EXPECT_LT(p.clip_fraction, 1.0);
  std::mt19937_64 rng(1);
  const std::vector<float> zero(1, 0.f);
  float before = 0, after = 0;
  Policy(behaviour.export_policy(1)).act(zero.data(), 1, rng, true, &before, nullptr);
  Policy(proximal.export_policy(1)).act(zero.data(), 1, rng, true, &after, nullptr);
  EXPECT_GT(after, before + 0.01f) << "the advantages push the mean up";

  // One after the other: each learner seeds LibTorch's generator, which the mini-batch order draws on.
  Ppo b2(surrogate_config("behaviour"), 1, 1, 3);
  const PpoStats bc = b2.fit(stale_steps_past_the_clip(b2, n, 1));
  Ppo p2(surrogate_config("proximal"), 1, 1, 3);
  const PpoStats pc = p2.fit(stale_steps_past_the_clip(p2, n, 1));
  EXPECT_EQ(bc.kl, pc.kl);
  EXPECT_EQ(bc.policy_loss, pc.policy_loss);
  EXPECT_GT(bc.kl, 0.0);
}

// One step whose behaviour log-probability is finite but absurd (-1e30, as a hostile batch may
// carry it), its advantage negative: its ratio is clamped before exp, so the fit's loss and the
// networks stay finite (before, the loss was infinite and the run ended as diverged).
TEST(Ppo, AnAbsurdBehaviourLogProbabilityLeavesTheFitFinite) {
  Ppo ppo(surrogate_config("behaviour"), 1, 1, 3);
  PpoSamples s = stale_steps_past_the_clip(ppo, 512, 0);
  s.behaviour_log_prob[7] = -1e30f;
  s.advantages[7] = -1.f;
  const PpoStats st = ppo.fit(s);
  EXPECT_TRUE(std::isfinite(st.policy_loss)) << st.policy_loss;
  EXPECT_TRUE(std::isfinite(st.kl)) << st.kl;
  for (float v : ppo.export_policy(1).params) ASSERT_TRUE(std::isfinite(v));
}

// The warm-up (run on a GPU before a run starts) fits a copy of its own, seeded as the run's
// networks are: the run after it draws the mini-batch orders it would have drawn without it, and
// the copy's fit went through the asynchronous path (steps of three versions, V-trace).
TEST(PpoWarmUp, LeavesTheGeneratorAsItFoundIt) {
  config::PpoConfig c = surrogate_config("proximal");
  c.set_mode("async");
  c.set_max_policy_lag(2);
  c.set_steps_per_fit(24 * 64 * 2);
  c.set_mini_batch_size(768);
  torch::manual_seed(5);
  const auto without = torch::rand({8});
  torch::manual_seed(5);
  const double s = ppo_warm_up(c, 3, 2, 7, "cpu");
  const auto with = torch::rand({8});
  EXPECT_GT(s, 0.0);
  EXPECT_TRUE(torch::equal(without, with)) << "the warm-up's seeding and mini-batch draws leaked into the run";
  c.set_device("no-such-device");
  EXPECT_THROW(ppo_warm_up(c, 3, 2, 7, "no-such-device"), std::invalid_argument);
}

TEST(Ppo, BadConfigIsRefusedWithTheFieldNamed) {
  config::PpoConfig c;
  c.set_variant("fancy");
  try {
    farm::check_config(c);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("ppo.variant"), std::string::npos) << e.what();
  }
  config::PpoConfig d;
  d.set_episodes_per_fit(4);  // with the default steps_per_fit: two triggers
  EXPECT_THROW(farm::check_config(d), std::invalid_argument);
  config::PpoConfig e;
  e.set_surrogate("impala");
  try {
    farm::check_config(e);
    FAIL();
  } catch (const std::invalid_argument& x) {
    EXPECT_NE(std::string(x.what()).find("ppo.surrogate"), std::string::npos) << x.what();
  }
}

namespace {

// The actor's mean as the learner computes it (LibTorch), read from its log-probabilities: with
// every action inside (-1, 1), log p(a) sums -0.5 ((a_j - m_j) / s_j)^2 - log s_j - log sqrt(2 pi)
// over the dims, so two actions that differ only in dim j, +d and -d, give
// m_j = (lp(+d) - lp(-d)) s_j^2 / (2 d). A small s makes that difference large next to the
// log-probabilities' float rounding.
std::vector<double> learner_means(const Ppo& ppo, const std::vector<float>& obs, int rows, int act_dim,
                                  double log_std) {
  const float d = 0.05f;
  std::vector<double> means(size_t(rows) * act_dim);
  for (int j = 0; j < act_dim; ++j) {
    std::vector<float> plus(size_t(rows) * act_dim, 0.f), minus(plus.size(), 0.f);
    for (int r = 0; r < rows; ++r) {
      plus[size_t(r) * act_dim + j] = d;
      minus[size_t(r) * act_dim + j] = -d;
    }
    const auto lp_plus = ppo.log_probs(obs.data(), plus.data(), rows);
    const auto lp_minus = ppo.log_probs(obs.data(), minus.data(), rows);
    for (int r = 0; r < rows; ++r) {
      means[size_t(r) * act_dim + j] =
          (double(lp_plus[r]) - double(lp_minus[r])) * std::exp(2 * log_std) / (2 * double(d));
    }
  }
  return means;
}

}  // namespace

// The policy PPO exports runs, in the workers' EigenMlp, the network the learner trains: for each
// activation (ELU as legged_gym's A1 actor, 48-512-256-128-12), the exported forward pass gives the
// LibTorch actor's mean within 1e-5, and the same weights under either other activation do not.
TEST(Ppo, ExportedPolicyComputesTheActorsMeanForEachActivation) {
  const std::vector<std::pair<std::string, Activation>> activations = {
      {"tanh", Activation::kTanh}, {"relu", Activation::kRelu}, {"elu", Activation::kElu}};
  const int obs_dim = 48, act_dim = 12, rows = 64;
  const double log_std = -4;  // within [log_std_min, log_std_max]: not clamped
  std::mt19937_64 rng(5);
  std::normal_distribution<float> g(0.f, 2.f);
  std::vector<float> obs(size_t(rows) * obs_dim);
  for (auto& x : obs) x = g(rng);
  for (const auto& [name, activation] : activations) {
    SCOPED_TRACE("activation " + name);
    config::PpoConfig c;
    c.set_activation(name);
    for (int h : {512, 256, 128}) c.add_hidden(h);
    c.set_initial_log_std(log_std);
    c.set_normalize_observations(false);  // the network alone
    Ppo ppo(c, obs_dim, act_dim, 17);
    const PolicyParams p = ppo.export_policy(1);
    ASSERT_EQ(p.layout.activation, activation);
    EXPECT_EQ(p.layout.describe(), "48-512-256-128-12 " + name);
    ASSERT_TRUE(p.obs_mean.empty());
    const std::vector<double> want = learner_means(ppo, obs, rows, act_dim, log_std);
    // Worst |EigenMlp - LibTorch| with the exported layout, and with each other activation.
    std::map<Activation, double> worst;
    double spread = 0;
    for (Activation a : {Activation::kTanh, Activation::kRelu, Activation::kElu}) {
      EigenMlp net(MlpLayout{p.layout.sizes, a}, p.params);
      std::vector<float> mean(want.size());
      net.forward(obs.data(), rows, mean.data());
      for (size_t i = 0; i < want.size(); ++i) {
        worst[a] = std::max(worst[a], std::abs(double(mean[i]) - want[i]));
        spread = std::max(spread, std::abs(want[i]));
      }
    }
    std::printf("ppo %s: max |mean| %.3g; max |EigenMlp - LibTorch| tanh %.2e, relu %.2e, elu %.2e\n", name.c_str(),
                spread, worst[Activation::kTanh], worst[Activation::kRelu], worst[Activation::kElu]);
    EXPECT_LE(worst[activation], 1e-5);
    for (const auto& [a, err] : worst) {
      if (a != activation) EXPECT_GT(err, 1e-4) << "activation " << int(a) << " is not told apart";
    }
  }
}
