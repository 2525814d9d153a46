#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <random>
#include <stdexcept>
#include <vector>

#include "mlp.h"
#include "rollout.h"
#include "task.h"
#include "vec_env.h"

namespace farm {
namespace {

std::shared_ptr<const robots::Task> pendulum(int max_episode_steps = 200) {
  config::TaskConfig cfg;
  cfg.mutable_pendulum()->set_max_episode_steps(max_episode_steps);
  return robots::make_task(cfg);
}

PolicyParams random_policy(uint64_t seed, uint64_t version = 1, Activation activation = Activation::kRelu) {
  PolicyParams p;
  p.version = version;
  p.layout = {{3, 64, 37, 2}, activation};
  p.params.resize(p.layout.num_params());
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> n(0.f, 0.2f);
  for (auto& v : p.params) v = n(rng);
  return p;
}

std::vector<float> row(const float* p, int n) { return std::vector<float>(p, p + n); }

TEST(VecEnv, AutoResetRecordsFinalObservation) {
  const int N = 3, L = 5;
  VecEnv env(pendulum(L), N, 123);
  VecEnv longer(pendulum(L + 1), N, 123);  // same seeds, no episode end at step L
  env.reset_all();
  longer.reset_all();
  for (int i = 0; i < N; ++i) EXPECT_EQ(row(env.obs(i), 3), row(longer.obs(i), 3));

  std::vector<float> actions = {0.5f, -1.f, 0.f}, rewards(N), rewards_l(N);
  std::vector<uint8_t> term(N), trunc(N), term_l(N), trunc_l(N);
  std::vector<double> returns(N, 0.0);
  EpisodeEnds ends, ends_l;
  for (int t = 1; t <= L; ++t) {
    env.step_range(0, N, actions.data(), rewards.data(), term.data(), trunc.data(), ends);
    longer.step_range(0, N, actions.data(), rewards_l.data(), term_l.data(), trunc_l.data(), ends_l);
    for (int i = 0; i < N; ++i) {
      returns[i] += rewards[i];
      EXPECT_EQ(rewards[i], rewards_l[i]);
      EXPECT_EQ(term[i], 0);
      EXPECT_EQ(trunc[i], t == L ? 1 : 0) << "t " << t;
      EXPECT_EQ(trunc_l[i], 0);
    }
    EXPECT_EQ(ends.size(), t == L ? N : 0);
  }
  EXPECT_EQ(ends_l.size(), 0);

  // Reset seeds come from each env's own stream: the next episode starts where a second
  // reset of an identically seeded env starts.
  VecEnv fresh(pendulum(L), N, 123);
  fresh.reset_all();
  fresh.reset_all();
  for (int i = 0; i < N; ++i) {
    EXPECT_EQ(ends.env(i), i);
    EXPECT_EQ(row(ends.final_obs(i), 3), row(longer.obs(i), 3)) << "env " << i;
    EXPECT_EQ(row(env.obs(i), 3), row(fresh.obs(i), 3)) << "env " << i;
    EXPECT_NE(row(env.obs(i), 3), row(longer.obs(i), 3));
    const EpisodeRecord& r = ends.record(i);
    EXPECT_EQ(r.env, i);
    EXPECT_EQ(r.length, L);
    EXPECT_FALSE(r.terminated);
    EXPECT_NEAR(r.episode_return, returns[i], 1e-4);
    ASSERT_EQ(r.metrics.size(), 1u);
    EXPECT_GE(r.metrics[0], 0.f);
    EXPECT_LE(r.metrics[0], 1.f);
    EXPECT_EQ(env.state(i).step, 0);
  }
}

TEST(VecEnv, DifferentEnvsAndSeedsDiffer) {
  VecEnv a(pendulum(), 4, 1), b(pendulum(), 4, 2);
  a.reset_all();
  b.reset_all();
  EXPECT_NE(row(a.obs(0), 3), row(a.obs(1), 3));
  EXPECT_NE(row(a.obs(0), 3), row(b.obs(0), 3));
  EXPECT_NE(mix_seed(1, 0), mix_seed(1, 1));
  EXPECT_NE(mix_seed(1, 0), mix_seed(2, 0));
}

void expect_same_batch(const RolloutBatch& a, const RolloutBatch& b) {
  EXPECT_EQ(a.obs, b.obs);
  EXPECT_EQ(a.actions, b.actions);
  EXPECT_EQ(a.rewards, b.rewards);
  EXPECT_EQ(a.terminated, b.terminated);
  EXPECT_EQ(a.truncated, b.truncated);
  EXPECT_EQ(a.log_probs, b.log_probs);
  EXPECT_EQ(a.next_obs, b.next_obs);
  EXPECT_EQ(a.final_index, b.final_index);
  EXPECT_EQ(a.final_obs, b.final_obs);
  ASSERT_EQ(a.episodes.size(), b.episodes.size());
  for (size_t i = 0; i < a.episodes.size(); ++i) {
    EXPECT_EQ(a.episodes[i].env, b.episodes[i].env);
    EXPECT_EQ(a.episodes[i].episode_return, b.episodes[i].episode_return);
    EXPECT_EQ(a.episodes[i].length, b.episodes[i].length);
    EXPECT_EQ(a.episodes[i].metrics, b.episodes[i].metrics);
  }
}

TEST(Rollout, SameSeedSameBatchesWhateverTheThreadCount) {
  const int N = 7, T = 23;
  auto task = pendulum(10);
  for (Activation act : {Activation::kRelu, Activation::kTanh}) {
    SCOPED_TRACE("activation " + std::to_string(int(act)));
    Rollout one(task, N, 1, 99), three(task, N, 3, 99), other_seed(task, N, 3, 100);
    EXPECT_EQ(three.num_threads(), 3);
    const PolicyParams p = random_policy(5, 1, act);
    one.set_policy(p);
    three.set_policy(p);
    other_seed.set_policy(p);
    RolloutBatch a, b, c;
    for (int k = 0; k < 3; ++k) {  // episodes continue across batches
      one.collect(T, a);
      three.collect(T, b);
      other_seed.collect(T, c);
      SCOPED_TRACE("batch " + std::to_string(k));
      expect_same_batch(a, b);
      EXPECT_NE(a.obs, c.obs);
    }
    EXPECT_FALSE(a.final_index.empty());
  }
}

TEST(Rollout, BatchShapesAndEpisodeBookkeeping) {
  const int N = 5, T = 32, L = 10;
  Rollout rollout(pendulum(L), N, 2, 7);
  EXPECT_THROW(
      {
        RolloutBatch tmp;
        rollout.collect(T, tmp);
      },
      std::logic_error);
  rollout.set_policy(random_policy(3, 42));
  EXPECT_EQ(rollout.policy_version(), 42u);
  EXPECT_EQ(rollout.num_envs(), N);
  EXPECT_EQ(rollout.spec().name, "pendulum");

  RolloutBatch out;
  rollout.collect(T, out);
  EXPECT_EQ(out.T, T);
  EXPECT_EQ(out.N, N);
  EXPECT_EQ(out.obs_dim, 3);
  EXPECT_EQ(out.act_dim, 1);
  EXPECT_EQ(out.policy_version, 42u);
  EXPECT_EQ(out.obs.size(), size_t(T * N * 3));
  EXPECT_EQ(out.actions.size(), size_t(T * N));
  EXPECT_EQ(out.rewards.size(), size_t(T * N));
  EXPECT_EQ(out.log_probs.size(), size_t(T * N));
  EXPECT_EQ(out.next_obs.size(), size_t(N * 3));
  EXPECT_EQ(rollout.env_steps(), uint64_t(T * N));

  // All envs start together, so episodes end at t = 9, 19, 29.
  ASSERT_EQ(out.final_index.size(), size_t(3 * N));
  ASSERT_EQ(out.episodes.size(), out.final_index.size());
  ASSERT_EQ(out.final_obs.size(), out.final_index.size() * 3);
  int64_t steps_in_episodes = 0;
  for (size_t i = 0; i < out.final_index.size(); ++i) {
    if (i > 0) {
      EXPECT_LT(out.final_index[i - 1], out.final_index[i]);
    }
    const int t = int(out.final_index[i]) / N, n = int(out.final_index[i]) % N;
    const EpisodeRecord& e = out.episodes[i];
    EXPECT_EQ(e.env, n);
    EXPECT_EQ(e.length, L);
    EXPECT_EQ((t + 1) % L, 0);
    EXPECT_EQ(out.truncated[t * N + n], 1);
    double ret = 0;
    for (int s = t - L + 1; s <= t; ++s) ret += out.rewards[s * N + n];
    EXPECT_NEAR(e.episode_return, ret, 1e-3);
    steps_in_episodes += e.length;
    // The final observation is the step's result, not the next episode's first observation.
    if (t + 1 < T) {
      EXPECT_NE(row(&out.final_obs[i * 3], 3), row(&out.obs[((t + 1) * N + n) * 3], 3));
    }
  }
  EXPECT_EQ(steps_in_episodes, int64_t(3 * L * N));
  int ends_flagged = 0;
  for (size_t k = 0; k < out.truncated.size(); ++k) {
    ends_flagged += out.truncated[k] + out.terminated[k];
    EXPECT_EQ(out.terminated[k], 0);
  }
  EXPECT_EQ(ends_flagged, int(out.final_index.size()));

  for (int k = 0; k < T * N; ++k) {
    ASSERT_GE(out.actions[k], -1.f);
    ASSERT_LE(out.actions[k], 1.f);
    ASSERT_TRUE(std::isfinite(out.log_probs[k]));
  }
  // obs[t][n] are unit-circle observations the envs actually visited.
  for (int k = 0; k < T * N; ++k) {
    EXPECT_NEAR(out.obs[k * 3] * out.obs[k * 3] + out.obs[k * 3 + 1] * out.obs[k * 3 + 1], 1.f, 1e-5);
  }

  // next_obs is the env state after the last step, and the next batch starts from it.
  for (int n = 0; n < N; ++n) {
    EXPECT_EQ(row(&out.next_obs[n * 3], 3), row(rollout.env().obs(n), 3));
  }
  const std::vector<float> next = out.next_obs;
  rollout.collect(T, out);
  EXPECT_EQ(std::vector<float>(out.obs.begin(), out.obs.begin() + N * 3), next);
  EXPECT_EQ(rollout.env_steps(), uint64_t(2 * T * N));
}

// worker.exploration_scale_min/max: each env's factor lies in the range, stays through its
// episode, and is drawn anew when the episode ends; the envs differ; 1 and 1 set none.
TEST(Rollout, EachEnvDrawsItsNoiseScaleAtEachEpisodesStart) {
  const int N = 6, L = 10;
  Rollout rollout(pendulum(L), N, 2, 7);
  rollout.set_policy(random_policy(3));
  EXPECT_THROW(rollout.set_exploration_scales(0.0, 1.0), std::invalid_argument);
  EXPECT_THROW(rollout.set_exploration_scales(2.0, 1.0), std::invalid_argument);
  rollout.set_exploration_scales(1.0, 1.0);
  EXPECT_EQ(rollout.exploration_scale(0), 1.f);
  rollout.set_exploration_scales(0.4, 1.6);
  std::vector<float> first(N);
  for (int n = 0; n < N; ++n) {
    first[n] = rollout.exploration_scale(n);
    EXPECT_GE(first[n], 0.4f);
    EXPECT_LE(first[n], 1.6f);
  }
  EXPECT_NE(first[0], first[1]);
  RolloutBatch out;
  rollout.collect(L - 1, out);  // every episode one step short of its end
  for (int n = 0; n < N; ++n) EXPECT_EQ(rollout.exploration_scale(n), first[n]) << "env " << n;
  rollout.collect(1, out);  // the episodes end: new factors
  int redrawn = 0;
  for (int n = 0; n < N; ++n) {
    EXPECT_GE(rollout.exploration_scale(n), 0.4f);
    EXPECT_LE(rollout.exploration_scale(n), 1.6f);
    redrawn += rollout.exploration_scale(n) != first[n];
  }
  EXPECT_EQ(redrawn, N);
}

TEST(Rollout, RejectsMismatchedPolicy) {
  Rollout rollout(pendulum(), 2, 1, 1);
  PolicyParams p;
  p.layout = {{4, 8, 2}, Activation::kRelu};
  p.params.assign(p.layout.num_params(), 0.f);
  EXPECT_THROW(rollout.set_policy(p), std::invalid_argument);
  EXPECT_THROW(Rollout(pendulum(), 0, 1, 1), std::invalid_argument);
  EXPECT_THROW(Rollout(pendulum(), 2, 0, 1), std::invalid_argument);
}

TEST(EvaluatePolicy, RunsFullDeterministicEpisodes) {
  auto task = pendulum(50);
  const PolicyParams p = random_policy(8);
  const auto records = evaluate_policy(task, p, 6, 31);
  ASSERT_EQ(records.size(), 6u);
  for (int i = 0; i < 6; ++i) {
    EXPECT_EQ(records[i].env, i);
    EXPECT_EQ(records[i].length, 50);
    EXPECT_LT(records[i].episode_return, 0.f);
  }
  const auto again = evaluate_policy(task, p, 6, 31);
  for (int i = 0; i < 6; ++i) EXPECT_EQ(records[i].episode_return, again[i].episode_return);

  // The same episodes, stepped by hand with the mode of the policy.
  VecEnv env(task, 6, 31);
  env.reset_all();
  Policy policy(p);
  std::mt19937_64 rng(0);
  std::vector<float> a(6), r(6);
  std::vector<uint8_t> te(6), tr(6);
  std::vector<double> ret(6, 0.0);
  EpisodeEnds ends;
  for (int t = 0; t < 50; ++t) {
    policy.act(env.obs(), 6, rng, true, a.data(), nullptr);
    env.step_range(0, 6, a.data(), r.data(), te.data(), tr.data(), ends);
    for (int i = 0; i < 6; ++i) ret[i] += r[i];
  }
  for (int i = 0; i < 6; ++i) EXPECT_NEAR(records[i].episode_return, ret[i], 1e-3);
  EXPECT_TRUE(evaluate_policy(task, p, 0, 1).empty());
}

TEST(EvaluatePolicy, SpreadsEpisodesOverTheTasksConditions) {
  // mCLARI's evaluation conditions are its terrains: episode k of an evaluation whose first episode
  // is number `first` starts on terrain (first + k) mod 6, whatever the seed; training resets draw.
  config::TaskConfig cfg;
  cfg.set_name("mclari");
  auto* m = cfg.mutable_mclari();
  m->set_fixed_frequency(1);
  m->set_fixed_group(11);
  m->set_max_episode_steps(1);
  std::shared_ptr<const robots::Task> task = robots::make_task(cfg);
  ASSERT_EQ(task->eval_conditions(), 6);
  PolicyParams p;
  p.layout = {{4, 8, 4}, Activation::kTanh};  // mean and log-std of 2 actions
  p.params.assign(p.layout.num_params(), 0.f);
  const int terrain = 3;  // metric "terrain"
  ASSERT_EQ(task->spec().metric_names[terrain], "terrain");
  for (uint32_t first : {0u, 4u, 11u}) {
    const auto records = evaluate_policy(task, p, 4, 17 + first, nullptr, first);
    ASSERT_EQ(records.size(), 4u);
    for (int k = 0; k < 4; ++k)
      EXPECT_EQ(int(records[k].metrics[terrain]), int((first + k) % 6)) << "first " << first << ", episode " << k;
  }
}

TEST(EvaluatePolicy, APartRunsTheEpisodesOfTheWholeEvaluation) {
  // An evaluation split into parts (the learner's eval.min_episodes_per_worker: one part per
  // worker, each with the evaluation's seed and its first episode's number) runs the episodes it
  // would run whole: 2 workers and 15 are evaluated on the same starts (maps, for Kaya).
  auto pend = pendulum(20);
  const auto whole = evaluate_policy(pend, random_policy(8), 7, 31, nullptr, 0);
  ASSERT_EQ(whole.size(), 7u);
  std::vector<EpisodeRecord> parts;
  for (auto [first, n] : {std::pair{0u, 3}, std::pair{3u, 2}, std::pair{5u, 2}}) {
    const auto part = evaluate_policy(pend, random_policy(8), n, 31, nullptr, first);
    parts.insert(parts.end(), part.begin(), part.end());
  }
  ASSERT_EQ(parts.size(), whole.size());
  for (size_t k = 0; k < whole.size(); ++k) EXPECT_EQ(parts[k].episode_return, whole[k].episode_return) << k;
  // Not the first episodes again, and another seed's are others.
  EXPECT_NE(parts[3].episode_return, whole[0].episode_return);
  EXPECT_NE(evaluate_policy(pend, random_policy(8), 1, 32, nullptr, 0)[0].episode_return, whole[0].episode_return);
  // VecEnv likewise: env 0 of the envs from index 3 is env 3 of the set.
  VecEnv all(pendulum(), 5, 9), from3(pendulum(), 2, 9, 3);
  all.reset_all();
  from3.reset_all();
  EXPECT_EQ(row(from3.obs(0), 3), row(all.obs(3), 3));
  EXPECT_EQ(row(from3.obs(1), 3), row(all.obs(4), 3));
}

}  // namespace
}  // namespace farm
