// The learner's ingest thread over a real DDS bus (two participants in this process): with a
// consumer far slower than the sender, every batch is accepted and handed over once, in order,
// with nothing lost, while the bounded queue makes the thread stop taking (the reliable history
// then holds the writer back). And the event log: one JSON object a line, CSV rows under their
// column names.
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <mutex>
#include <set>
#include <thread>

#include "events.h"
#include "ingest_thread.h"
#include "meter.h"

namespace {

constexpr int kObs = 2, kAct = 1;
constexpr uint64_t kVersion = 7;  // the run's policy version when the thread starts

farm::msg::TransitionBatch batch(uint64_t seq) {
  farm::msg::TransitionBatch b;
  b.experiment_id("exp");
  b.worker_id("w1");
  b.worker_session(7);
  b.sequence_number(seq);
  b.policy_version(kVersion);  // a resumed run's: the thread must know it from its start
  b.num_steps(1);
  b.num_envs(2);
  b.obs_dim(kObs);
  b.act_dim(kAct);
  b.observations({float(seq), 0.f, 1.f, 1.f});
  b.actions({0.1f, -0.2f});
  b.rewards({float(seq), 1.f});
  b.terminated({0, 0});
  b.truncated({0, 0});
  b.log_probs({0, 0});
  b.next_observations({2.f, 2.f, 3.f, 3.f});
  return b;
}

int test_domain() { return 120 + int(getpid() % 80); }

// The worker's side, in a process of its own as on a farm (Fast DDS's intra-process shortcut would
// not resend what a full reader history refused): n batches, each written again until the writer
// takes it (a full reader history holds the writer back). Exit code 0 once all are written.
// The batches are worker `id`'s; with bad_dims their dims are not the experiment's (each refused).
int send_batches(int domain, uint64_t n, const std::string& id = "w1", bool bad_dims = false) {
  farm::dds::BusOptions o;
  o.domain = domain;
  farm::dds::Bus bus(o, "test " + id);
  farm::dds::Writer<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType> out(bus, farm::dds::kBatchTopic,
                                                                                          "batch_writer");
  for (int i = 0; i < 400 && out.matched() == 0; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(25));
  if (out.matched() == 0) return 2;
  for (uint64_t s = 0; s < n; ++s) {
    auto b = batch(s);
    b.worker_id(id);
    if (bad_dims) b.obs_dim(kObs + 1);
    const double t_end = farm::now_seconds() + 60;
    while (!out.write(b))
      if (farm::now_seconds() > t_end) return 3;
  }
  out.wait_for_acks(30);
  return 0;
}

TEST(IngestThread, SlowConsumerLosesNothingAndTheQueueHoldsTheThreadBack) {
  const int domain = test_domain();
  // More than the queue and the reader's history (256) together: the writer must be held back.
  const uint64_t n = 400;
  std::fflush(nullptr);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) _exit(send_batches(domain, n));
  farm::dds::BusOptions o;
  o.domain = domain;
  farm::dds::Bus learner_bus(o, "test learner");
  farm::EventLog events;
  const size_t capacity = 1000;  // bytes: a few batches of 2 rows
  std::vector<std::string> lines;
  std::mutex lines_mu;
  farm::IngestThread intake(
      learner_bus, farm::Ingest("exp", kObs, kAct, 0), uint32_t(farm::Ingest::max_batch_bytes(kObs, kAct, 0, 1)),
      capacity,
      [&](const std::string& m) {
        std::lock_guard<std::mutex> lk(lines_mu);
        lines.push_back(m);
      },
      events);
  intake.start(kVersion);

  std::vector<uint64_t> got;
  size_t most_queued = 0, one_batch = 0;
  const double t_end = farm::now_seconds() + 90;
  while (got.size() < n && farm::now_seconds() < t_end) {
    most_queued = std::max(most_queued, intake.queued_bytes());
    intake.pop(1, [&](farm::AcceptedBatch& a) {
      ASSERT_EQ(a.rows.n, 2);
      one_batch = a.bytes();
      got.push_back(uint64_t(a.rows.rewards[0]));
    });
    if (got.size() < 40) std::this_thread::sleep_for(std::chrono::milliseconds(20));  // a slow consumer at first
    intake.wait(0.05);
  }
  int status = -1;
  waitpid(child, &status, 0);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << "sender status " << status;
  for (const auto& l : lines) ADD_FAILURE() << "ingest said: " << l;
  ASSERT_EQ(got.size(), n);
  for (uint64_t s = 0; s < n; ++s) ASSERT_EQ(got[s], s) << "batch " << s << " out of order or missing";
  const farm::IngestCounters c = intake.counters();
  EXPECT_EQ(c.ok, n);
  EXPECT_EQ(c.lost, 0u);
  EXPECT_EQ(c.invalid, 0u);
  EXPECT_EQ(intake.env_steps(), 2 * n);
  EXPECT_LT(most_queued, capacity + one_batch);
  EXPECT_EQ(intake.queued_bytes(), 0u);
  EXPECT_GT(intake.full_waits(), 0u) << "the queue never filled: the consumer was not slower than the sender";
}

// Refusal lines and events are capped per participant: a participant whose 150 refused batches
// exhaust its own caps leaves another's refusal said (in the log and as an event).
TEST(IngestThread, OneParticipantsRefusalsDoNotSilenceAnothers) {
  const int domain = test_domain() + 1;
  farm::dds::BusOptions o;
  o.domain = domain;
  farm::dds::Bus learner_bus(o, "test learner");
  const std::string path =
      (std::filesystem::temp_directory_path() / ("refusals_" + std::to_string(getpid()) + ".jsonl")).string();
  std::filesystem::remove(path);
  farm::EventLog events;
  events.open(path);
  std::vector<std::string> lines;
  std::mutex lines_mu;
  farm::IngestThread intake(
      learner_bus, farm::Ingest("exp", kObs, kAct, 0), uint32_t(farm::Ingest::max_batch_bytes(kObs, kAct, 0, 1)),
      1 << 20,
      [&](const std::string& m) {
        std::lock_guard<std::mutex> lk(lines_mu);
        lines.push_back(m);
      },
      events);
  intake.start(kVersion);
  // Two participants of this process, one after the other (fewer batches than the reader's history
  // holds, which Fast DDS's intra-process delivery does not resend).
  EXPECT_EQ(send_batches(domain, 150, "noise", true), 0);
  EXPECT_EQ(send_batches(domain, 1, "w1", true), 0);
  const double t_end = farm::now_seconds() + 10;
  while (intake.counters().invalid < 151 && farm::now_seconds() < t_end) intake.wait(0.05);
  EXPECT_EQ(intake.counters().invalid, 151u);
  std::ifstream in(path);
  std::string line;
  int noise = 0, w1 = 0;
  while (std::getline(in, line)) {
    const auto e = nlohmann::json::parse(line);
    if (e.value("event", "") != "refusal") continue;
    noise += e.value("worker_id", "") == "noise";
    w1 += e.value("worker_id", "") == "w1";
  }
  EXPECT_EQ(noise, farm::IngestThread::kMaxRefusalEvents);
  EXPECT_EQ(w1, 1);
  std::lock_guard<std::mutex> lk(lines_mu);
  EXPECT_EQ(lines.size(), size_t(farm::IngestThread::kMaxRefusalLines) + 1);
}

// The hold's rules on a clock of its own: a session is released when announced or when its time
// is up, its batches in the order held; one participant's bound and the total's refuse room
// without touching the item; a release settles the counts.
TEST(FirstBatchHold, ReleasesOnAnnouncementOrTimeInOrderWithinBounds) {
  using Hold = farm::FirstBatchHold<int, std::string>;
  Hold hold(Hold::Limits{3.0, 2, 100});
  std::vector<std::pair<int, std::string>> out;
  const auto take = [&](int key, std::string& item) { out.emplace_back(key, item); };
  std::string a = "t0", b = "w0", c = "t1", d = "x0", e = "t2", f = "big";
  EXPECT_TRUE(hold.hold(1, "thief", 10, 0.0, a));
  EXPECT_TRUE(hold.hold(1, "worker", 10, 0.5, b));
  EXPECT_TRUE(hold.hold(1, "thief", 10, 0.6, c));
  EXPECT_TRUE(hold.hold(2, "other", 10, 1.0, d));
  EXPECT_FALSE(hold.hold(2, "thief", 10, 1.1, e));  // the thief has its 2 held
  EXPECT_EQ(e, "t2");                               // refused room: the item is the caller's still
  EXPECT_FALSE(hold.hold(3, "new", 61, 1.2, f));    // 40 + 61 bytes > 100
  EXPECT_EQ(hold.batches(), 4u);
  EXPECT_EQ(hold.bytes(), 40u);
  std::set<int> announced;
  EXPECT_EQ(hold.release(
                2.0, [&](int k) { return announced.count(k) > 0; }, take),
            0u);
  announced.insert(1);
  EXPECT_EQ(hold.release(
                2.1, [&](int k) { return announced.count(k) > 0; }, take),
            3u);
  const std::vector<std::pair<int, std::string>> first{{1, "t0"}, {1, "w0"}, {1, "t1"}};
  EXPECT_EQ(out, first);
  EXPECT_TRUE(hold.hold(5, "thief", 10, 2.2, e));  // its room came back with the release
  EXPECT_EQ(hold.release(
                3.9, [](int) { return false; }, take),
            0u);
  EXPECT_EQ(hold.release(
                4.0, [](int) { return false; }, take),
            1u);  // key 2: held at 1.0, 3 s up
  EXPECT_EQ(out.back(), std::make_pair(2, std::string("x0")));
  EXPECT_EQ(hold.release(5, take), 1u);  // at once, out of room
  EXPECT_TRUE(hold.empty());
  EXPECT_EQ(hold.bytes(), 0u);
}

// A thief writes the first batches of w1's session 7 before the learner hears the heartbeat that
// announces it (the learner's reader matched the worker's heartbeat writer after its first beat):
// they are held, with the worker's own, until the announcement, then the thief's are refused and
// the stream opens from the worker. A session never announced opens from its writer once its time
// is up.
TEST(IngestThread, AFirstBatchWaitsForItsSessionsAnnouncement) {
  const int domain = test_domain() + 2;
  farm::dds::BusOptions o;
  o.domain = domain;
  farm::dds::Bus learner_bus(o, "test learner"), thief_bus(o, "test thief"), worker_bus(o, "test worker");
  const std::string worker_key = farm::dds::participant_key(worker_bus.participant()->guid());
  std::mutex mu;
  std::string announcer;  // the participant of w1#7's first heartbeat, "" while none was heard
  farm::Ingest ingest("exp", kObs, kAct, 0);
  ingest.set_announcer([&](const std::string& id, uint64_t session) {
    std::lock_guard<std::mutex> lk(mu);
    return id == "w1" && session == 7 ? announcer : std::string();
  });
  farm::EventLog events;
  farm::IngestThread intake(
      learner_bus, std::move(ingest), uint32_t(farm::Ingest::max_batch_bytes(kObs, kAct, 0, 1)), 1 << 20,
      [](const std::string&) {}, events);
  intake.start(kVersion);
  using BatchWriter = farm::dds::Writer<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType>;
  BatchWriter thief(thief_bus, farm::dds::kBatchTopic, "batch_writer"),
      worker(worker_bus, farm::dds::kBatchTopic, "batch_writer");
  for (int i = 0; i < 400 && (thief.matched() == 0 || worker.matched() == 0); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(25));
  ASSERT_GT(thief.matched() * worker.matched(), 0);
  const auto until = [&](const std::function<bool()>& done, double seconds) {
    const double t_end = farm::now_seconds() + seconds;
    while (!done() && farm::now_seconds() < t_end) std::this_thread::sleep_for(std::chrono::milliseconds(5));
    return done();
  };

  const double t0 = farm::now_seconds();
  auto unheard = batch(0);
  unheard.worker_session(8);
  ASSERT_TRUE(thief.write(unheard));
  for (uint64_t s = 0; s < 2; ++s) {
    auto b = batch(s);
    ASSERT_TRUE(thief.write(b));
  }
  ASSERT_TRUE(until([&] { return intake.held() == 3; }, 2)) << "held " << intake.held();
  for (uint64_t s = 0; s < 3; ++s) {
    auto b = batch(s);
    ASSERT_TRUE(worker.write(b));
  }
  ASSERT_TRUE(until([&] { return intake.held() == 6; }, 2)) << "held " << intake.held();
  EXPECT_EQ(intake.counters().ok + intake.counters().invalid, 0u);
  {
    std::lock_guard<std::mutex> lk(mu);
    announcer = worker_key;
  }
  ASSERT_TRUE(until([&] { return intake.counters().ok == 3; }, 2)) << "accepted " << intake.counters().ok;
  EXPECT_EQ(intake.counters().invalid, 2u);
  EXPECT_LT(farm::now_seconds() - t0, 3.0) << "session 8's time ran out first: the test shows nothing";
  intake.with_ingest([&](farm::Ingest& in) {
    const farm::WorkerAccount& w = in.workers().at({"w1", 7});
    EXPECT_EQ(w.received, 3u);
    EXPECT_EQ(w.lost, 0u);
    EXPECT_EQ(w.writer, worker_key);
  });
  ASSERT_TRUE(until([&] { return intake.counters().ok == 4; }, 5)) << "session 8 was never decided";
  EXPECT_GE(farm::now_seconds() - t0, 2.9);
  EXPECT_EQ(intake.held(), 0u);
}

TEST(EventLog, OneObjectALineWithItsOwnElapsedKept) {
  const std::string path =
      (std::filesystem::temp_directory_path() / ("events_" + std::to_string(getpid()) + ".jsonl")).string();
  std::filesystem::remove(path);
  {
    farm::EventLog e;
    e.open(path);
    e.set_start(farm::now_seconds() - 5.0);
    e.write(
        "progress",
        {{"elapsed_s", 12.5}, {"env_steps", 4096}, {"updates_per_s", 87.5}, {"mean_return", nullptr}, {"note", "abc"}});
    e.write("worker", {{"worker_id", std::string("w\x1b\xff")}});
  }
  std::ifstream in(path);
  std::string line;
  ASSERT_TRUE(std::getline(in, line));
  const auto a = nlohmann::json::parse(line);
  EXPECT_EQ(a["event"], "progress");
  EXPECT_DOUBLE_EQ(a["elapsed_s"].get<double>(), 12.5);  // the row's own, not the clock's
  EXPECT_TRUE(a["env_steps"].is_number_integer());
  EXPECT_EQ(a["env_steps"].get<int64_t>(), 4096);
  EXPECT_DOUBLE_EQ(a["updates_per_s"].get<double>(), 87.5);
  EXPECT_TRUE(a["mean_return"].is_null());
  EXPECT_EQ(a["note"], "abc");
  ASSERT_TRUE(std::getline(in, line));
  const auto b = nlohmann::json::parse(line);  // invalid UTF-8 from the network does not break a line
  EXPECT_EQ(b["event"], "worker");
  EXPECT_GE(b["elapsed_s"].get<double>(), 5.0);
  EXPECT_FALSE(std::getline(in, line));
  std::filesystem::remove(path);
}

}  // namespace
