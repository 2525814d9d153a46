// Sequence accounting: every sequence number is accounted as received, lost, duplicate or
// invalid; sessions and gaps are bounded; a stream takes batches only from its writer and resumes
// from a checkpoint.
#include <gtest/gtest.h>

#include <algorithm>

#include "config.h"
#include "ingest.h"
#include "ingest_accounts.h"
#include "ingest_test_util.h"

using namespace ingest_test;

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
