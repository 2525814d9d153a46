// Batch validation: a bad batch is refused with its reason and counted; n-step folding; the
// bounds on a batch's size; episode summaries held to the batch and the task.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>

#include "config.h"
#include "ingest.h"
#include "ingest_accounts.h"
#include "ingest_test_util.h"

using namespace ingest_test;

TEST_F(Fixture, ValidBatchBecomesTransitionsWithTrueNextObservations) {
  ASSERT_EQ(take(make_batch(0)), "");
  ASSERT_EQ(out.n, 6);
  // Row i = t*N+n. Row 0 (t0,n0) -> obs of t1,n0 = (10,-10).
  EXPECT_FLOAT_EQ(out.next_obs[0 * kObs], 10.f);
  // Row 3 (t1,n1) ended an episode: its next obs is the true final observation, not the reset one.
  EXPECT_FLOAT_EQ(out.next_obs[3 * kObs], 99.f);
  EXPECT_FLOAT_EQ(out.next_obs[3 * kObs + 1], -99.f);
  // Rows of the last step bootstrap from next_observations.
  EXPECT_FLOAT_EQ(out.next_obs[4 * kObs], 30.f);
  EXPECT_FLOAT_EQ(out.next_obs[5 * kObs], 31.f);
  EXPECT_EQ(out.terminated[3], 0);  // truncation is not termination
  ASSERT_EQ(eps.size(), 1u);
  EXPECT_FLOAT_EQ(eps[0].episode_return, -123.f);
  EXPECT_EQ(ingest.counters().ok, 1u);
  EXPECT_EQ(ingest.counters().env_steps, 6u);
  EXPECT_DOUBLE_EQ(ingest.counters().lag_sum, 2.0);
}

TEST_F(Fixture, WrongShapeIsRefusedAndCounted) {
  auto b = make_batch(0);
  b.rewards({1, 2, 3});
  std::string why = take(b);
  EXPECT_NE(why.find("rewards has 3 values, expected 6"), std::string::npos) << why;
  EXPECT_EQ(ingest.counters().invalid, 1u);
  EXPECT_EQ(out.n, 0);
}

// An end of stream has no steps, so no product of steps and environments bounds its number of
// environments: before, 2^32 - 1 passed and came to the algorithms and Python as -1.
TEST_F(Fixture, AnEndOfStreamClaimingMoreEnvironmentsThanAWorkerRunsIsRefused) {
  farm::msg::TransitionBatch b = make_batch(0);
  b.num_steps(0);
  b.num_envs(UINT32_MAX);
  b.end_of_stream(true);
  for (auto* v :
       {&b.observations(), &b.actions(), &b.rewards(), &b.log_probs(), &b.next_observations(), &b.final_observations()})
    v->clear();
  b.terminated({});
  b.truncated({});
  b.final_index({});
  b.episodes({});
  EXPECT_EQ(take(b), "4294967295 environments, more than a worker runs (4096)");
  b.num_envs(4);
  EXPECT_EQ(take(b), "");
  EXPECT_EQ(ingest.counters().invalid, 1u);
}

TEST_F(Fixture, WrongDimsAreRefused) {
  auto b = make_batch(0);
  b.obs_dim(3);
  EXPECT_NE(take(b).find("expected obs 2"), std::string::npos);
  EXPECT_EQ(ingest.counters().invalid, 1u);
}

TEST_F(Fixture, NaNIsRefusedAndTrainingDataStaysClean) {
  EXPECT_EQ(take(make_batch(0)), "");
  auto b = make_batch(1);
  auto o = b.observations();
  o[5] = std::nanf("");
  b.observations(o);
  std::string why = take(b);
  EXPECT_NE(why.find("non-finite value in observations at index 5"), std::string::npos) << why;
  EXPECT_EQ(out.n, 6);
  // The next good batch is taken, and the bad one is counted invalid, not lost.
  EXPECT_EQ(take(make_batch(2)), "");
  EXPECT_EQ(ingest.counters().invalid, 1u);
  EXPECT_EQ(ingest.counters().lost, 0u);
  EXPECT_EQ(ingest.counters().ok, 2u);
  EXPECT_EQ(ingest.workers().at({"w1", 7}).invalid, 1u);
}

TEST_F(Fixture, InfiniteRewardAndOutOfRangeActionAreRefused) {
  auto b = make_batch(0);
  auto r = b.rewards();
  r[2] = INFINITY;
  b.rewards(r);
  EXPECT_NE(take(b).find("rewards"), std::string::npos);
  auto c = make_batch(1);
  auto a = c.actions();
  a[0] = 3.f;
  c.actions(a);
  EXPECT_NE(take(c).find("outside [-1, 1]"), std::string::npos);
  EXPECT_EQ(ingest.counters().invalid, 2u);
}

TEST_F(Fixture, WrongExperimentIsRefused) {
  std::string why = take(make_batch(0, "other"));
  EXPECT_NE(why.find("'other' is not 'exp'"), std::string::npos) << why;
  EXPECT_EQ(ingest.counters().foreign, 1u);
  EXPECT_EQ(ingest.counters().invalid, 0u) << "another run's batches are not faults of this one";
  EXPECT_TRUE(ingest.workers().empty());
}

TEST_F(Fixture, PolicyVersionFromTheFutureIsRefusedAndItsNumberUsed) {
  EXPECT_EQ(take(make_batch(0)), "");
  auto b = make_batch(1);
  b.policy_version(6);  // the learner's latest is 5
  std::string why = take(b);
  EXPECT_NE(why.find("policy version 6 is newer than the learner's latest (5)"), std::string::npos) << why;
  EXPECT_EQ(ingest.counters().invalid, 1u);
  EXPECT_EQ(take(make_batch(2)), "");
  EXPECT_EQ(ingest.counters().lost, 0u);
}

// Finite but absurd numbers from the network are refused before they train: an observation or
// reward beyond any task's magnitude (squared in a loss it would overflow float32 and end the run),
// and a reward beyond the task's own bound on one step where the task declares one.
TEST_F(Fixture, AbsurdObservationsAndRewardsAreRefused) {
  auto obs = make_batch(0);
  auto o = obs.observations();
  o[3] = 3e38f;
  obs.observations(o);
  EXPECT_NE(take(obs).find("observations at index 3 is 3e+38, beyond +-1e+09"), std::string::npos) << take(obs);
  auto fin = make_batch(0);
  fin.final_observations({99.f, -2e9f});
  EXPECT_NE(take(fin).find("final_observations at index 1"), std::string::npos);
  auto huge = make_batch(0);
  huge.rewards({1, 2, 3e30f, 4, 5, 6});
  EXPECT_NE(take(huge).find("rewards at index 2"), std::string::npos);
  EXPECT_EQ(ingest.counters().ok, 0u);
  EXPECT_TRUE(out.rewards.empty());
  // With the task's bound of 5 a step, the batch's reward of 6 is refused, and 5 is taken.
  ingest.set_reward_bound(5);
  const std::string why = take(make_batch(0));
  EXPECT_NE(why.find("rewards at index 5 is 6, beyond +-5, the task's bound"), std::string::npos) << why;
  auto within = make_batch(0);
  within.rewards({1, 2, 3, 4, 5, -5});
  EXPECT_EQ(take(within), "");
  EXPECT_EQ(ingest.counters().ok, 1u);
}

// A stream's first batch is checked before an account is opened: a refused one opens none (its
// number, if the stream is real, shows as lost when the next batch arrives).
TEST_F(Fixture, NStepFoldSumsRewardsUntilEpisodeOrBatchEnds) {
  const auto b = make_batch(0);
  ASSERT_EQ(take(b), "");
  farm::fold_n_step(b, out, 0.5, 3);
  ASSERT_EQ(out.n, 6);
  ASSERT_EQ(out.horizon.size(), 6u);
  // Row (t0, e0): 1 + 0.5 * 3 + 0.25 * 5, bootstrapping from the batch's next observation.
  EXPECT_FLOAT_EQ(out.rewards[0], 3.75f);
  EXPECT_FLOAT_EQ(out.horizon[0], 3.f);
  EXPECT_FLOAT_EQ(out.next_obs[0 * kObs], 30.f);
  // Row (t0, e1): env 1's episode is truncated at t1: 2 + 0.5 * 4, from the true final observation.
  EXPECT_FLOAT_EQ(out.rewards[1], 4.f);
  EXPECT_FLOAT_EQ(out.horizon[1], 2.f);
  EXPECT_FLOAT_EQ(out.next_obs[1 * kObs + 1], -99.f);
  EXPECT_EQ(out.terminated[1], 0);
  // Row (t1, e0): the batch ends after t2: 3 + 0.5 * 5.
  EXPECT_FLOAT_EQ(out.rewards[2], 5.5f);
  EXPECT_FLOAT_EQ(out.horizon[2], 2.f);
  EXPECT_FLOAT_EQ(out.next_obs[2 * kObs], 30.f);
  // The rows that end an episode or the batch keep their one-step values.
  const float one_step[] = {4, 5, 6}, next_first[] = {99, 30, 31};
  for (int i = 3; i < 6; ++i) {
    EXPECT_FLOAT_EQ(out.rewards[i], one_step[i - 3]) << "row " << i;
    EXPECT_FLOAT_EQ(out.horizon[i], 1.f) << "row " << i;
    EXPECT_FLOAT_EQ(out.next_obs[i * kObs], next_first[i - 3]) << "row " << i;
  }
}

TEST_F(Fixture, NStepFoldStopsAtTerminationAndKeepsItsFlag) {
  auto b = make_batch(0);
  b.terminated({0, 0, 1, 0, 0, 0});  // env 0 terminates at t1
  b.final_index({2, 3});
  b.final_observations({77.f, -77.f, 99.f, -99.f});
  farm::msg::EpisodeSummary ended = b.episodes()[0];
  ended.env(0);
  ended.terminated(true);
  b.episodes().insert(b.episodes().begin(), ended);
  ASSERT_EQ(take(b), "");
  farm::fold_n_step(b, out, 0.5, 3);
  EXPECT_FLOAT_EQ(out.rewards[0], 2.5f);  // 1 + 0.5 * 3; the reward after the reset (5) is not added
  EXPECT_FLOAT_EQ(out.horizon[0], 2.f);
  EXPECT_EQ(out.terminated[0], 1);
  EXPECT_FLOAT_EQ(out.next_obs[0], 77.f);
  // n_step 2 on a fresh copy: row (t0, e0) reads the observation of t2 itself.
  Transitions two;
  std::vector<FinishedEpisode> e2;
  Ingest other{"exp", kObs, kAct, 0};
  const auto plain = make_batch(0);
  ASSERT_EQ(other.accept(plain, 5, 0.0, two, e2), "");
  farm::fold_n_step(plain, two, 0.5, 2);
  EXPECT_FLOAT_EQ(two.rewards[0], 2.5f);
  EXPECT_FLOAT_EQ(two.horizon[0], 2.f);
  EXPECT_FLOAT_EQ(two.next_obs[0], 20.f);
  EXPECT_FLOAT_EQ(two.next_obs[1], -20.f);
  // n_step 1 changes nothing and reports horizon 1 everywhere.
  Transitions one;
  Ingest third{"exp", kObs, kAct, 0};
  ASSERT_EQ(third.accept(plain, 5, 0.0, one, e2), "");
  const auto before = one.rewards;
  farm::fold_n_step(plain, one, 0.5, 1);
  EXPECT_EQ(one.rewards, before);
  EXPECT_EQ(one.horizon, std::vector<float>(6, 1.f));
}

// The batch reader's bound (Ingest::max_batch_bytes) lets through the largest batch a worker of the
// experiment can send: every step of kMaxEnvsPerWorker envs ending an episode, with its final
// observation and summary, and long ids. It is not much above it, so it refuses a larger one.
TEST(IngestBound, MaxBatchBytesHoldsTheLargestValidBatchAndNotMuchMore) {
  const unsigned T = 2, N = farm::kMaxEnvsPerWorker, od = 3, ad = 2, metrics = 2;
  const size_t TN = size_t(T) * N;
  farm::msg::TransitionBatch b;
  b.experiment_id(std::string(200, 'e'));
  b.worker_id(std::string(200, 'w'));
  b.num_steps(T);
  b.num_envs(N);
  b.obs_dim(od);
  b.act_dim(ad);
  b.observations(std::vector<float>(TN * od, 0.f));
  b.actions(std::vector<float>(TN * ad, 0.f));
  b.rewards(std::vector<float>(TN, 0.f));
  b.terminated(std::vector<uint8_t>(TN, 1));
  b.truncated(std::vector<uint8_t>(TN, 0));
  b.log_probs(std::vector<float>(TN, 0.f));
  b.next_observations(std::vector<float>(size_t(N) * od, 0.f));
  std::vector<uint32_t> idx(TN);
  for (size_t i = 0; i < TN; ++i) idx[i] = uint32_t(i);
  b.final_index(idx);
  b.final_observations(std::vector<float>(TN * od, 0.f));
  std::vector<farm::msg::EpisodeSummary> eps(TN);
  for (auto& e : eps) e.metrics(std::vector<float>(metrics, 0.f));
  b.episodes(eps);
  const uint64_t size = farm::msg::TransitionBatch::getCdrSerializedSize(b) + 4;  // + encapsulation
  const uint64_t bound = Ingest::max_batch_bytes(od, ad, metrics, T);
  EXPECT_GE(bound, size);
  EXPECT_LE(bound, size + Ingest::kBatchHeaderBytes);
  // More steps per batch, more room; never more transitions than kMaxBatchTransitions.
  EXPECT_GT(Ingest::max_batch_bytes(od, ad, metrics, 4), bound);
  EXPECT_EQ(Ingest::max_batch_bytes(od, ad, metrics, farm::kMaxStepsPerBatch),
            Ingest::max_batch_bytes(od, ad, metrics, farm::kMaxBatchTransitions / farm::kMaxEnvsPerWorker));
}

TEST(IngestBound, SamplesRefusedByTheBusAreCountedInvalidOnce) {
  Ingest in{"exp", 2, 1, 0};
  EXPECT_EQ(in.count_refused_samples(0), 0u);
  EXPECT_EQ(in.count_refused_samples(3), 3u);
  EXPECT_EQ(in.count_refused_samples(3), 0u);
  EXPECT_EQ(in.count_refused_samples(5), 2u);
  EXPECT_EQ(in.counters().invalid, 5u);
  EXPECT_TRUE(in.workers().empty());
}

// A batch's worker id is bounded as a heartbeat's is: every accepted episode and account copies it.
TEST_F(Fixture, OverlongWorkerIdIsRefused) {
  auto b = make_batch(0);
  b.worker_id(std::string(Ingest::kMaxIdBytes, 'w'));
  EXPECT_EQ(take(b), "");
  b.worker_id(std::string(Ingest::kMaxIdBytes + 1, 'w'));
  EXPECT_EQ(take(b), "worker id of 257 bytes (at most 256)");
  EXPECT_EQ(ingest.counters().invalid, 1u);
}

// One episode summary for each episode end, of that end's env and flag, with the task's metrics:
// before, a one-step batch could claim any number of finished episodes (PPO counts them toward
// its fits and stop rules) and carry NaN metrics into the learner's figures.
TEST_F(Fixture, EpisodeSummariesMustMatchTheEpisodeEnds) {
  const auto refused = [&](const std::function<void(farm::msg::TransitionBatch&)>& edit, const std::string& why) {
    auto b = make_batch(0);
    edit(b);
    const std::string got = take(b);
    EXPECT_NE(got.find(why), std::string::npos) << "got: " << got << "; expected: " << why;
  };
  refused([](auto& b) { b.episodes().push_back(b.episodes()[0]); }, "2 episode summaries for 1 episode ends");
  refused([](auto& b) { b.episodes().clear(); }, "0 episode summaries for 1 episode ends");
  refused([](auto& b) { b.episodes()[0].env(0); }, "episode summary 0 names env 0, its end (step index 3) is env 1");
  refused([](auto& b) { b.episodes()[0].terminated(true); }, "terminated does not match the flag at step index 3");
  refused([](auto& b) { b.episodes()[0].length(0); }, "episode summary 0 has length 0");
  refused([](auto& b) { b.episodes()[0].metrics({1.f}); }, "episode summary 0 has 1 metrics, the task has 0");
  EXPECT_EQ(out.n, 0);
  EXPECT_TRUE(eps.empty());

  Ingest with_metrics{"exp", kObs, kAct, 2};
  auto b = make_batch(0);
  b.episodes()[0].metrics({0.5f, NAN});
  EXPECT_EQ(with_metrics.accept(b, 5, 0.0, out, eps),
            "episode summary 0: non-finite value in episode metrics at index 1");
  EXPECT_EQ(with_metrics.accept(make_batch(1), 5, 0.0, out, eps), "episode summary 0 has 0 metrics, the task has 2");
  auto good = make_batch(2);
  good.episodes()[0].metrics({0.5f, 2.f});
  EXPECT_EQ(with_metrics.accept(good, 5, 0.0, out, eps), "");
  ASSERT_EQ(eps.size(), 1u);
  EXPECT_EQ(eps[0].metrics, (std::vector<float>{0.5f, 2.f}));
}

// A training episode is held to the task's limits as an evaluated one is: no longer than the time
// limit, no return beyond length x the bound on one step's reward, no metric beyond any task's.
// Before, a summary claiming a return of 1e30 was taken, and the run's mean return (logs,
// learner.csv, the status) became that.
TEST_F(Fixture, EpisodeSummariesAreHeldToTheTasksLimits) {
  ingest.set_max_episode_steps(100);
  EXPECT_EQ(take(make_batch(0)), "episode summary 0 has length 200, beyond the task's time limit of 100 steps");
  ingest.set_max_episode_steps(200);
  ingest.set_reward_bound(6);  // 200 steps: a return of at most 1200
  auto absurd = make_batch(0);
  absurd.episodes()[0].episode_return(1e30f);
  EXPECT_EQ(take(absurd),
            "episode summary 0 returns 1e+30, beyond what 200 steps can give at the task's bound of 6 a step");
  auto over = make_batch(0);
  over.episodes()[0].episode_return(-1201.f);
  EXPECT_NE(take(over).find("beyond what 200 steps can give"), std::string::npos);
  EXPECT_EQ(ingest.counters().ok, 0u);
  EXPECT_TRUE(eps.empty());

  Ingest with_metrics{"exp", kObs, kAct, 1};
  auto far = make_batch(0);
  far.episodes()[0].metrics({-3e20f});
  EXPECT_NE(with_metrics.accept(far, 5, 0.0, out, eps).find("episode summary 0: episode metrics at index 0 is"),
            std::string::npos);

  auto at_bound = make_batch(0);
  at_bound.episodes()[0].episode_return(-1200.f);
  EXPECT_EQ(take(at_bound), "");
  ASSERT_EQ(eps.size(), 1u);
  EXPECT_FLOAT_EQ(eps[0].episode_return, -1200.f);
}
