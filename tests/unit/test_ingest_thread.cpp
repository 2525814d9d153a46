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
#include <mutex>
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
