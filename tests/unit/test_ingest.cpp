// Batch validation and sequence accounting: a bad batch is refused with its reason and counted;
// every sequence number is accounted as received, lost, duplicate or invalid.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>

#include "config.h"
#include "ingest.h"
#include "ingest_accounts.h"

using farm::FinishedEpisode;
using farm::Ingest;
using farm::Transitions;

namespace {

constexpr int kObs = 2, kAct = 1;

// T=3 steps x N=2 envs; env 1 ends an episode at t=1 (truncated).
farm::msg::TransitionBatch make_batch(uint64_t seq, const std::string& exp = "exp") {
  farm::msg::TransitionBatch b;
  b.experiment_id(exp);
  b.worker_id("w1");
  b.worker_session(7);
  b.sequence_number(seq);
  b.policy_version(3);
  const int T = 3, N = 2;
  b.num_steps(T);
  b.num_envs(N);
  b.obs_dim(kObs);
  b.act_dim(kAct);
  std::vector<float> obs;
  for (int t = 0; t < T; ++t)
    for (int n = 0; n < N; ++n) {
      obs.push_back(10.f * t + n);
      obs.push_back(-(10.f * t + n));
    }
  b.observations(obs);
  b.actions({0.1f, -0.2f, 0.3f, -0.4f, 0.5f, -0.6f});
  b.rewards({1, 2, 3, 4, 5, 6});
  b.terminated({0, 0, 0, 0, 0, 0});
  b.truncated({0, 0, 0, 1, 0, 0});
  b.log_probs({0, 0, 0, 0, 0, 0});
  b.next_observations({30.f, -30.f, 31.f, -31.f});
  b.final_index({3});  // t=1, n=1
  b.final_observations({99.f, -99.f});
  farm::msg::EpisodeSummary e;
  e.env(1);
  e.episode_return(-123.f);
  e.length(200);
  b.episodes({e});
  return b;
}

struct Fixture : ::testing::Test {
  Ingest ingest{"exp", kObs, kAct, 0};
  Transitions out;
  std::vector<FinishedEpisode> eps;
  std::string take(const farm::msg::TransitionBatch& b) { return ingest.accept(b, 5, 0.0, out, eps); }
  // The batch of sequence number seq of session `session`, one second after the one before.
  double now = 0;
  std::string at(uint64_t session, uint64_t seq) {
    auto b = make_batch(seq);
    b.worker_session(session);
    return ingest.accept(b, 5, now += 1, out, eps);
  }
};

}  // namespace

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
TEST_F(Fixture, RefusedFirstBatchOpensNoAccount) {
  auto b = make_batch(0);
  b.rewards({1, 2, 3});
  EXPECT_NE(take(b).find("rewards has 3 values"), std::string::npos);
  EXPECT_TRUE(ingest.workers().empty());
  EXPECT_EQ(ingest.counters().invalid, 1u);
}

// One forged batch claiming a sequence number near 2^64 on a live stream, or opening a stream
// there: refused as invalid, O(1), and no account moves (the measured attack set lost to 2^63).
TEST_F(Fixture, AbsurdSequenceJumpIsRefusedWithoutMovingTheAccount) {
  EXPECT_EQ(take(make_batch(0)), "");
  EXPECT_EQ(take(make_batch(1)), "");
  for (uint64_t seq : {uint64_t(1) << 63, UINT64_MAX, uint64_t(3) + Ingest::kMaxSequenceJump}) {
    const std::string why = take(make_batch(seq));
    EXPECT_NE(why.find("jumps more than"), std::string::npos) << seq << ": " << why;
  }
  auto fresh = make_batch(UINT64_MAX);
  fresh.worker_session(99);
  EXPECT_NE(take(fresh).find("opens a stream"), std::string::npos);
  const auto& w = ingest.workers().at({"w1", 7});
  EXPECT_EQ(w.next_sequence, 2u);
  EXPECT_EQ(w.lost, 0u);
  EXPECT_EQ(w.invalid, 0u);
  EXPECT_EQ(ingest.counters().lost, 0u);
  EXPECT_EQ(ingest.counters().invalid, 4u);
  EXPECT_EQ(ingest.workers().size(), 1u);
  // The stream goes on as if nothing had come; a gap up to the bound is still plain loss.
  EXPECT_EQ(take(make_batch(2)), "");
  EXPECT_EQ(take(make_batch(3 + Ingest::kMaxSequenceJump)), "");
  EXPECT_EQ(ingest.workers().at({"w1", 7}).lost, Ingest::kMaxSequenceJump);
  EXPECT_EQ(ingest.counters().ok, 4u);
}

// Invented sessions by the thousand: open accounts stay at the bound, each new stream past it
// retires the open one with the fewest accepted batches (an invented one-batch stream, never the
// real worker's), and a real stream that opens after the flood is taken.
TEST_F(Fixture, InventedSessionsAreBoundedAndLockNoWorkerOut) {
  EXPECT_EQ(take(make_batch(0)), "");
  EXPECT_EQ(take(make_batch(1)), "");
  for (uint64_t k = 0; k < Ingest::kMaxAccounts + 500; ++k) {
    auto b = make_batch(0);
    b.worker_id("x" + std::to_string(k));
    b.worker_session(1000 + k);
    EXPECT_EQ(take(b), "");
  }
  EXPECT_EQ(ingest.workers().size(), Ingest::kMaxAccounts);
  EXPECT_EQ(ingest.retired(), 501u);
  EXPECT_EQ(take(make_batch(2)), "");
  EXPECT_EQ(ingest.workers().at({"w1", 7}).received, 3u);
  auto late = make_batch(0);  // a real worker that joins after the flood
  late.worker_id("w9");
  EXPECT_EQ(take(late), "");
  EXPECT_EQ(ingest.workers().count({"w9", 7}), 1u);
  EXPECT_EQ(ingest.counters().invalid, 0u);
}

// One worker id holds at most kMaxSessionsPerWorker streams: a new session past it retires that
// id's least recently seen one, and a retired stream that comes back continues its own account
// (no loss counted for the batches it sent before).
TEST_F(Fixture, SessionsPerWorkerAreBoundedAndARetiredStreamContinues) {
  for (uint64_t s = 1; s <= Ingest::kMaxSessionsPerWorker; ++s) EXPECT_EQ(at(s, 0), "");
  EXPECT_EQ(at(1, 1), "");  // session 1 is now the most recently seen; 2 the least
  EXPECT_EQ(at(99, 0), "");
  EXPECT_EQ(ingest.workers().size(), Ingest::kMaxSessionsPerWorker);
  EXPECT_EQ(ingest.workers().count({"w1", 2}), 0u);
  EXPECT_EQ(ingest.retired(), 1u);
  EXPECT_EQ(at(2, 1), "");  // back: its account goes on from sequence 1
  EXPECT_EQ(ingest.workers().at({"w1", 2}).received, 2u);
  EXPECT_EQ(ingest.counters().lost, 0u);
}

// A retired stream that comes back is held to the same bound on its sequence as an open one: a
// forged number near 2^64 under a retired session is refused, restores nothing and books no loss.
TEST_F(Fixture, AbsurdSequenceJumpOnARetiredStreamIsRefused) {
  for (uint64_t s = 1; s <= Ingest::kMaxSessionsPerWorker + 1; ++s) EXPECT_EQ(at(s, 0), "");
  ASSERT_EQ(ingest.retired(), 1u);
  ASSERT_EQ(ingest.workers().count({"w1", 1}), 0u);
  for (uint64_t seq : {uint64_t(1) << 63, UINT64_MAX, uint64_t(2) + Ingest::kMaxSequenceJump}) {
    const std::string why = at(1, seq);
    EXPECT_NE(why.find("jumps more than"), std::string::npos) << seq << ": " << why;
  }
  EXPECT_EQ(ingest.workers().count({"w1", 1}), 0u) << "a refused batch restored the retired stream";
  EXPECT_EQ(ingest.retired_accounts().size(), 1u);
  EXPECT_EQ(ingest.counters().lost, 0u);
  EXPECT_EQ(ingest.counters().invalid, 3u);
  // Its real next batch still brings it back, and a gap within the bound is plain loss.
  EXPECT_EQ(at(1, 1 + Ingest::kMaxSequenceJump), "");
  EXPECT_EQ(ingest.workers().at({"w1", 1}).lost, Ingest::kMaxSequenceJump);
  EXPECT_EQ(ingest.workers().at({"w1", 1}).received, 2u);
}

// Streams invented by the thousand, each opening 2^20 numbers on, remember at most
// kMaxMissingTotal gap numbers between them, however many are open or retired, and a checkpoint
// holds no more. Before, each kept kMaxMissing: 33.5 million numbers (256 MiB) over the open and
// retired accounts, all written into every checkpoint.
TEST_F(Fixture, GapNumbersRememberedOverAllStreamsAreBounded) {
  const auto remembered = [this] {
    size_t n = 0;
    for (const auto& [_, w] : ingest.workers()) n += w.missing.size();
    for (const auto& [_, w] : ingest.retired_accounts()) n += w.missing.size();
    return n;
  };
  for (uint64_t k = 0; k < Ingest::kMaxAccounts + Ingest::kMaxRetired + 100; ++k) {
    auto b = make_batch(Ingest::kMaxSequenceJump);
    b.worker_id("x" + std::to_string(k));
    ASSERT_EQ(take(b), "");
  }
  EXPECT_EQ(ingest.retired_accounts().size(), Ingest::kMaxRetired);
  EXPECT_EQ(remembered(), ingest.missing_total());
  EXPECT_LE(remembered(), Ingest::kMaxMissingTotal);
  // A late batch whose number is remembered is still taken back from lost.
  const auto with_gap = std::find_if(ingest.workers().begin(), ingest.workers().end(),
                                     [](const auto& kv) { return !kv.second.missing.empty(); });
  ASSERT_NE(with_gap, ingest.workers().end());
  const auto first = with_gap->second;
  auto late = make_batch(first.missing.front());
  late.worker_id(first.worker_id);
  EXPECT_EQ(take(late), "");
  EXPECT_EQ(ingest.workers().at({first.worker_id, 7}).lost, first.lost - 1);
  EXPECT_EQ(remembered(), ingest.missing_total());

  farm::config::CheckpointManifest m;
  farm::accounts_to_manifest(ingest, m);
  size_t written = 0;
  for (const auto& r : m.workers()) written += size_t(r.missing_size());
  EXPECT_LE(written, Ingest::kMaxMissingTotal);
  Ingest resumed{"exp", kObs, kAct, 0};
  farm::accounts_from_manifest(m, resumed, 0.0);
  EXPECT_EQ(resumed.missing_total(), written);
}

// Accounts idle for the expiry are retired, counted; one seen since stays.
TEST_F(Fixture, IdleAccountsExpire) {
  auto b = make_batch(0);
  EXPECT_EQ(ingest.accept(b, 5, 10.0, out, eps), "");
  b.worker_id("w2");
  EXPECT_EQ(ingest.accept(b, 5, 100.0, out, eps), "");
  EXPECT_EQ(ingest.expire(500.0, 450.0), 1u);
  EXPECT_EQ(ingest.workers().size(), 1u);
  EXPECT_EQ(ingest.workers().count({"w2", 7}), 1u);
  EXPECT_EQ(ingest.retired(), 1u);
}

// A checkpoint holds the open streams and the retired ones: after a resume (a new process, whose
// clock may read anything), no open stream is retired as idle for the time the learner was away,
// a retired stream that comes back continues its own count, and a late batch of a gap is taken.
TEST_F(Fixture, CheckpointedAccountsResumeOpenAndRetiredStreams) {
  auto w1 = [](uint64_t seq) { return make_batch(seq); };
  auto w2 = [](uint64_t seq) {
    auto b = make_batch(seq);
    b.worker_id("w2");
    return b;
  };
  EXPECT_EQ(ingest.accept(w1(0), 5, 10.0, out, eps), "");
  EXPECT_EQ(ingest.accept(w1(1), 5, 11.0, out, eps), "");
  EXPECT_EQ(ingest.accept(w1(3), 5, 12.0, out, eps), "");  // 2 missing: lost, for now
  EXPECT_EQ(ingest.accept(w2(0), 5, 650.0, out, eps), "");
  EXPECT_EQ(ingest.expire(700.0, 600.0), 1u);  // w1, idle since 12 s
  ASSERT_EQ(ingest.retired_accounts().size(), 1u);
  farm::config::CheckpointManifest m;
  farm::accounts_to_manifest(ingest, m);

  Ingest resumed{"exp", kObs, kAct, 0};
  const double now = 1e6;
  farm::accounts_from_manifest(m, resumed, now);
  EXPECT_EQ(resumed.counters().ok, ingest.counters().ok);
  EXPECT_EQ(resumed.counters().lost, 1u);
  EXPECT_EQ(resumed.expire(now + 1, 600.0), 0u) << "an open stream retired for the learner's time away";
  EXPECT_EQ(resumed.workers().count({"w2", 7}), 1u);
  EXPECT_EQ(resumed.accept(w1(2), 5, now + 2, out, eps), "");  // late, not lost after all
  EXPECT_EQ(resumed.accept(w1(4), 5, now + 3, out, eps), "");
  EXPECT_EQ(resumed.accept(w2(1), 5, now + 4, out, eps), "");
  EXPECT_EQ(resumed.counters().lost, 0u);
  EXPECT_EQ(resumed.workers().at({"w1", 7}).received, 5u);
  EXPECT_EQ(resumed.workers().at({"w2", 7}).received, 2u);
}

// A stream takes batches only from the participant that opened it: another participant writing
// under its id and session (both readable off the bus) is refused without moving the account.
TEST_F(Fixture, StreamTakesBatchesOnlyFromItsWriter) {
  EXPECT_EQ(ingest.accept(make_batch(0), 5, 0.0, out, eps, nullptr, "P1"), "");
  const std::string why = ingest.accept(make_batch(5), 5, 0.0, out, eps, nullptr, "P2");
  EXPECT_NE(why.find("from another participant"), std::string::npos) << why;
  EXPECT_EQ(ingest.workers().at({"w1", 7}).next_sequence, 1u);
  EXPECT_EQ(ingest.workers().at({"w1", 7}).lost, 0u);
  EXPECT_EQ(ingest.accept(make_batch(1), 5, 0.0, out, eps, nullptr, "P1"), "");
  EXPECT_EQ(ingest.counters().invalid, 1u);
}

// A thief that reads a new worker's session off its heartbeat and writes the first batch under it
// does not open the stream: the participant of the heartbeat does. A session whose heartbeat was
// not heard opens from its writer, as before.
TEST_F(Fixture, AStreamOpensOnlyFromTheParticipantThatAnnouncedIt) {
  ingest.set_announcer([](const std::string& id, uint64_t session) {
    return id == "w1" && session == 7 ? std::string("WORKER") : std::string();
  });
  const std::string why = ingest.accept(make_batch(0), 5, 0.0, out, eps, nullptr, "THIEF");
  EXPECT_NE(why.find("whose heartbeats announced it"), std::string::npos) << why;
  EXPECT_EQ(ingest.workers().count({"w1", 7}), 0u);
  EXPECT_EQ(ingest.counters().invalid, 1u);
  EXPECT_EQ(ingest.accept(make_batch(0), 5, 0.0, out, eps, nullptr, "WORKER"), "");
  EXPECT_EQ(ingest.accept(make_batch(1), 5, 0.0, out, eps, nullptr, "WORKER"), "");
  EXPECT_EQ(ingest.workers().at({"w1", 7}).received, 2u);
  auto unheard = make_batch(0);
  unheard.worker_session(8);
  EXPECT_EQ(ingest.accept(unheard, 5, 0.0, out, eps, nullptr, "OTHER"), "");
}

// The binding survives a checkpoint: after a resume, a participant that writes first under an
// open or a retired stream's id and session (a thief that read both off the bus) is refused, and
// the worker that stayed up, on the participant that opened the stream, carries on with it.
TEST_F(Fixture, ResumedStreamsKeepTheirWriter) {
  auto w2 = [](uint64_t seq) {
    auto b = make_batch(seq);
    b.worker_id("w2");
    return b;
  };
  EXPECT_EQ(ingest.accept(make_batch(0), 5, 10.0, out, eps, nullptr, "P1"), "");
  EXPECT_EQ(ingest.accept(w2(0), 5, 650.0, out, eps, nullptr, "P2"), "");
  EXPECT_EQ(ingest.expire(700.0, 600.0), 1u);  // w1's stream retired, w2's open
  farm::config::CheckpointManifest m;
  farm::accounts_to_manifest(ingest, m);

  Ingest resumed{"exp", kObs, kAct, 0};
  farm::accounts_from_manifest(m, resumed, 1e6);
  for (const auto& [batch, owner] : {std::pair{make_batch(1), "P1"}, std::pair{w2(1), "P2"}}) {
    SCOPED_TRACE(batch.worker_id());
    const std::string why = resumed.accept(batch, 5, 1e6 + 1, out, eps, nullptr, "THIEF");
    EXPECT_NE(why.find("from another participant"), std::string::npos) << why;
    EXPECT_EQ(resumed.accept(batch, 5, 1e6 + 2, out, eps, nullptr, owner), "");
  }
  EXPECT_EQ(resumed.counters().lost, 0u);
  EXPECT_EQ(resumed.workers().at({"w1", 7}).received, 2u);
  EXPECT_EQ(resumed.workers().at({"w2", 7}).received, 2u);
}

// DDS Security: a worker's id is its certificate's name. A batch whose worker id differs from the
// authenticated name of the participant that wrote it (a w1 certificate sending as w2), or that
// comes from a participant with no authenticated name, is refused as invalid: nothing trained on,
// no account opened for the id it claims, the writer's own stream untouched.
TEST_F(Fixture, BatchUnderAnotherIdThanItsWritersCertificateIsRefused) {
  const std::string w1 = "w1", w2 = "w2", unknown;
  EXPECT_EQ(ingest.accept(make_batch(0), 5, 0.0, out, eps, &w1), "");
  auto b = make_batch(0);
  b.worker_id("w2");
  b.worker_session(8);
  const std::string why = ingest.accept(b, 5, 0.0, out, eps, &w1);
  EXPECT_NE(why.find("worker id 'w2' is not 'w1'"), std::string::npos) << why;
  b.worker_id("w1");  // the right id, from a participant whose name is w2
  EXPECT_NE(ingest.accept(b, 5, 0.0, out, eps, &w2), "");
  EXPECT_NE(ingest.accept(make_batch(1), 5, 0.0, out, eps, &unknown).find("binds to no granted worker name"),
            std::string::npos);
  EXPECT_EQ(out.n, 6);  // the first batch only
  EXPECT_EQ(ingest.counters().ok, 1u);
  EXPECT_EQ(ingest.counters().invalid, 3u);
  ASSERT_EQ(ingest.workers().size(), 1u);
  const auto& a = ingest.workers().begin()->second;
  EXPECT_EQ(a.worker_id, "w1");
  EXPECT_EQ(a.next_sequence, 1u);
  EXPECT_EQ(a.invalid, 0u);
  // Another experiment's batch stays "other experiments", whoever sent it.
  auto foreign = make_batch(0, "other");
  foreign.worker_id("w2");
  ingest.accept(foreign, 5, 0.0, out, eps, &w1);
  EXPECT_EQ(ingest.counters().foreign, 1u);
  EXPECT_EQ(ingest.counters().invalid, 3u);
  // Without security (no name given) the id is taken as it is.
  EXPECT_EQ(ingest.accept(make_batch(1), 5, 0.0, out, eps), "");
}

TEST_F(Fixture, DoneFlagsMustMatchFinalIndex) {
  auto b = make_batch(0);
  b.truncated({0, 0, 0, 0, 0, 0});
  EXPECT_NE(take(b).find("final_index does not match"), std::string::npos);
}

TEST_F(Fixture, GapsAreCountedLostAndLateArrivalsRecovered) {
  EXPECT_EQ(take(make_batch(0)), "");
  EXPECT_EQ(take(make_batch(3)), "");
  EXPECT_EQ(ingest.counters().lost, 2u);
  EXPECT_EQ(take(make_batch(2)), "");  // late, not lost after all
  EXPECT_EQ(ingest.counters().lost, 1u);
  const auto& w = ingest.workers().at({"w1", 7});
  EXPECT_EQ(w.received, 3u);
  EXPECT_EQ(w.lost, 1u);
  EXPECT_EQ(w.next_sequence, 4u);
}

TEST_F(Fixture, DuplicatesAreRefusedAndCounted) {
  EXPECT_EQ(take(make_batch(0)), "");
  EXPECT_EQ(take(make_batch(1)), "");
  std::string why = take(make_batch(1));
  EXPECT_NE(why.find("duplicate sequence number 1"), std::string::npos) << why;
  EXPECT_EQ(ingest.counters().duplicate, 1u);
  EXPECT_EQ(ingest.counters().ok, 2u);
  EXPECT_EQ(out.n, 12);
}

TEST_F(Fixture, RestartedWorkerHasItsOwnSequenceSpace) {
  EXPECT_EQ(take(make_batch(0)), "");
  auto b = make_batch(0);
  b.worker_session(8);
  EXPECT_EQ(take(b), "");
  EXPECT_EQ(ingest.counters().duplicate, 0u);
  EXPECT_EQ(ingest.workers().size(), 2u);
}

TEST_F(Fixture, EndOfStreamMayBeEmpty) {
  farm::msg::TransitionBatch b;
  b.experiment_id("exp");
  b.worker_id("w1");
  b.worker_session(7);
  b.sequence_number(0);
  b.obs_dim(kObs);
  b.act_dim(kAct);
  b.end_of_stream(true);
  EXPECT_EQ(take(b), "");
  EXPECT_TRUE(ingest.workers().at({"w1", 7}).ended);
  b.end_of_stream(false);
  b.sequence_number(1);
  EXPECT_NE(take(b).find("empty batch"), std::string::npos);
}

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
