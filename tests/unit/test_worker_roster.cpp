// The learner's worker roster: the join line says what is known of a worker's size, and the size
// once the worker has built its environments; silence marks a worker dead, a heartbeat brings it back.
// On its own thread over a real DDS bus (two participants in this process), the roster hears a
// worker and marks it dead while the learner's loop does nothing (a long fit).
#include <gtest/gtest.h>

#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <fastrtps/xmlparser/XMLProfileManager.h>

#include "config.h"
#include "events.h"
#include "meter.h"
#include "roster_thread.h"
#include "worker_roster.h"

namespace {

farm::msg::WorkerStatus status(uint32_t envs, const std::string& state) {
  farm::msg::WorkerStatus s;
  s.worker_id("local-2");
  s.worker_session(42);
  s.host("vm");
  s.envs(envs);
  s.threads(1);
  s.state(state);
  return s;
}

struct Lines {
  std::vector<std::string> lines;
  farm::WorkerRoster::Log log() {
    return [this](const std::string& m) { lines.push_back(m); };
  }
};

using StatusWriter = farm::dds::Writer<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType>;

// A heartbeat of worker w1, session 1, running in experiment "exp".
farm::msg::WorkerStatus running_w1() {
  farm::msg::WorkerStatus s;
  s.experiment_id("exp");
  s.worker_id("w1");
  s.worker_session(1);
  s.host("h");
  s.envs(4);
  s.threads(1);
  s.state("running");
  return s;
}

// Beats every 0.1 s until the roster has the worker live (10 s at most); true once it has.
bool beat_until_live(const farm::RosterThread& thread, StatusWriter& out, farm::msg::WorkerStatus& s) {
  const double t0 = farm::now_seconds();
  while (thread.live_count() == 0 && farm::now_seconds() - t0 < 10) {
    out.write(s);
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  return thread.live_count() == 1;
}

// The roster's changes of w1 (joined, dead, back), in order, from an events file.
std::vector<std::string> w1_changes(const std::string& events_path) {
  std::ifstream in(events_path);
  std::vector<std::string> changes;
  for (std::string line; std::getline(in, line);) {
    const auto e = nlohmann::json::parse(line, nullptr, false);
    if (e.is_object() && e.value("worker_id", "") == "w1") changes.push_back(e.value("change", ""));
  }
  return changes;
}

}  // namespace

TEST(WorkerRoster, JoinBeforeTheSpecSaysSoThenTheSize) {
  Lines l;
  farm::WorkerRoster roster(10.0, l.log());
  roster.heard(status(0, "waiting_for_learner"), 1.0);
  ASSERT_EQ(l.lines.size(), 1u);
  EXPECT_EQ(l.lines[0], "worker local-2 on vm joined (session 42, waiting for the spec)");
  EXPECT_EQ(l.lines[0].find("0 envs"), std::string::npos);
  roster.heard(status(0, "waiting_for_weights"), 2.0);
  EXPECT_EQ(l.lines.size(), 1u) << "no line while the size is still unknown";
  roster.heard(status(8, "running"), 3.0);
  ASSERT_EQ(l.lines.size(), 2u);
  EXPECT_EQ(l.lines[1], "worker local-2 on vm runs 8 envs on 1 threads");
  roster.heard(status(8, "running"), 4.0);
  EXPECT_EQ(l.lines.size(), 2u) << "the size is said once";
}

TEST(WorkerRoster, JoinWithEnvironmentsBuiltGivesTheSize) {
  Lines l;
  farm::WorkerRoster roster(10.0, l.log());
  roster.heard(status(16, "running"), 1.0);
  ASSERT_EQ(l.lines.size(), 1u);
  EXPECT_EQ(l.lines[0], "worker local-2 on vm joined (session 42, 16 envs on 1 threads)");
}

TEST(WorkerRoster, SilentWorkerIsDeadAndComesBack) {
  Lines l;
  farm::WorkerRoster roster(5.0, l.log());
  roster.heard(status(4, "running"), 1.0);
  EXPECT_EQ(roster.live_count(2.0), 1);
  roster.check(7.0);
  EXPECT_EQ(roster.live_count(7.0), 0);
  ASSERT_EQ(l.lines.size(), 2u);
  EXPECT_NE(l.lines[1].find("marked dead"), std::string::npos) << l.lines[1];
  roster.heard(status(4, "running"), 9.0);
  EXPECT_EQ(roster.live_count(9.0), 1);
  ASSERT_EQ(l.lines.size(), 3u);
  EXPECT_NE(l.lines[2].find("is back after 8.0 s"), std::string::npos) << l.lines[2];
}

// Another experiment's workers on the same domain are not this learner's: no join or dead lines,
// not live, not heard; one line says such heartbeats are ignored. A worker that has no experiment
// yet (it waits for a spec) is not counted either.
TEST(WorkerRoster, OnlyWorkersOfItsExperimentCount) {
  Lines l;
  farm::WorkerRoster roster(5.0, l.log(), "exp_a");
  farm::msg::WorkerStatus foreign = status(8, "running");
  foreign.experiment_id("exp_b");
  EXPECT_FALSE(roster.heard(foreign, 1.0));
  EXPECT_FALSE(roster.heard(foreign, 2.0));
  farm::msg::WorkerStatus unbound = status(0, "waiting_for_learner");
  EXPECT_FALSE(roster.heard(unbound, 2.0));
  ASSERT_EQ(l.lines.size(), 1u) << "the other experiment is noted once";
  EXPECT_EQ(l.lines[0],
            "heartbeats of another experiment, 'exp_b' (worker local-2), are ignored: only workers of "
            "'exp_a' count");
  EXPECT_EQ(roster.live_count(2.0), 0);
  EXPECT_TRUE(roster.views().empty());
  roster.check(20.0);
  EXPECT_EQ(l.lines.size(), 1u) << "no dead-worker line for a worker that was never ours";

  farm::msg::WorkerStatus own = status(4, "running");
  own.experiment_id("exp_a");
  EXPECT_TRUE(roster.heard(own, 21.0));
  EXPECT_EQ(roster.live_count(21.0), 1);
  ASSERT_EQ(l.lines.size(), 2u);
  EXPECT_EQ(l.lines[1], "worker local-2 on vm joined (session 42, 4 envs on 1 threads)");
}

// A worker that cannot run the learner's spec (an older build that lacks a config field, a task it
// does not know) has joined no experiment, so its heartbeats are not the learner's; its error is
// still what the learner's user must see, once per worker and error (a restart does not repeat it). Errors about
// another experiment's spec are that learner's to report.
TEST(WorkerRoster, AWorkerThatCannotRunTheSpecIsReportedOnce) {
  Lines l;
  farm::WorkerRoster roster(5.0, l.log(), "exp_a");
  farm::msg::WorkerStatus rejected = status(0, "error");
  rejected.last_error(
      "cannot run experiment 'exp_a': ExperimentSpec(exp_a):26:27: Message type \"farm.config.SacConfig\" has no "
      "field named \"x\".");
  EXPECT_FALSE(roster.heard(rejected, 1.0));
  EXPECT_FALSE(roster.heard(rejected, 2.0));
  ASSERT_EQ(l.lines.size(), 1u);
  EXPECT_EQ(l.lines[0], "worker local-2 on vm cannot join: " + rejected.last_error());
  EXPECT_EQ(roster.live_count(2.0), 0) << "it runs nothing, so it is not counted";
  farm::msg::WorkerStatus restarted = rejected;
  restarted.worker_session(43);
  EXPECT_FALSE(roster.heard(restarted, 2.5));
  EXPECT_EQ(l.lines.size(), 1u) << "the same worker restarted with the same error";
  // A worker of an older build words its error without the prefix; the spec's name is in it.
  farm::msg::WorkerStatus old = status(0, "error");
  old.worker_id("old-1");
  old.last_error("ExperimentSpec(exp_a):3:1: Message type \"farm.config.ExperimentConfig\" has no field named \"y\".");
  EXPECT_FALSE(roster.heard(old, 3.0));
  ASSERT_EQ(l.lines.size(), 2u);
  EXPECT_EQ(l.lines[1], "worker old-1 on vm cannot join: " + old.last_error());
  // Another learner's spec on the same domain: not ours to report.
  farm::msg::WorkerStatus other = status(0, "error");
  other.worker_id("b-1");
  other.last_error("cannot run experiment 'exp_b': unknown task");
  EXPECT_FALSE(roster.heard(other, 4.0));
  EXPECT_EQ(l.lines.size(), 2u);
  // A hostile or broken heartbeat cannot flood the log: the error is cut, the workers noted bounded.
  farm::msg::WorkerStatus longer = status(0, "error");
  longer.worker_id("long-1");
  longer.last_error("cannot run experiment 'exp_a': " + std::string(100000, 'z'));
  EXPECT_FALSE(roster.heard(longer, 5.0));
  ASSERT_EQ(l.lines.size(), 3u);
  EXPECT_LT(l.lines[2].size(), 700u);
  farm::msg::WorkerStatus forged = status(0, "error");
  forged.worker_id("nl-1");
  forged.last_error("cannot run experiment 'exp_a': x\n[learner] forged line");
  EXPECT_FALSE(roster.heard(forged, 5.5));
  ASSERT_EQ(l.lines.size(), 4u);
  // The line feed is written as \x0a (printable.h): no forged line starts in the log.
  EXPECT_EQ(l.lines[3], "worker nl-1 on vm cannot join: cannot run experiment 'exp_a': x\\x0a[learner] forged line");
  for (int i = 0; i < 1000; ++i) {
    farm::msg::WorkerStatus many = rejected;
    many.worker_id("w" + std::to_string(i));
    roster.heard(many, 6.0);
  }
  EXPECT_LT(l.lines.size(), 100u);
}

// A worker (id and session) is bound to the participant of its first heartbeat: another
// participant's heartbeats under them are not taken.
TEST(WorkerRoster, HeartbeatsOfAnotherParticipantUnderAWorkersIdAreRefused) {
  Lines l;
  farm::WorkerRoster roster(10.0, l.log());
  EXPECT_TRUE(roster.heard(status(4, "running"), 1.0, "P1"));
  auto forged = status(4, "error");
  forged.last_error("stop me");
  EXPECT_FALSE(roster.heard(forged, 2.0, "P2"));
  EXPECT_EQ(roster.refused(), 1u);
  EXPECT_EQ(roster.views().begin()->second.last.state(), "running");
  EXPECT_TRUE(roster.heard(status(4, "running"), 3.0, "P1"));
}

// A heartbeat claiming more environments than a worker can run is not heard: before, 2^32 - 1 envs
// became -1 in PPO's per-worker quota.
TEST(WorkerRoster, ASizeNoWorkerRunsIsRefused) {
  Lines l;
  farm::WorkerRoster roster(10.0, l.log());
  EXPECT_FALSE(roster.heard(status(UINT32_MAX, "running"), 1.0, "P1"));
  EXPECT_FALSE(roster.heard(status(farm::kMaxEnvsPerWorker + 1, "running"), 1.0, "P1"));
  auto threads = status(4, "running");
  threads.threads(UINT32_MAX);
  EXPECT_FALSE(roster.heard(threads, 1.0, "P1"));
  EXPECT_EQ(roster.refused(), 3u);
  EXPECT_TRUE(roster.views().empty());
  EXPECT_TRUE(roster.heard(status(farm::kMaxEnvsPerWorker, "running"), 2.0, "P1"));
}

// Invented sessions of one id by the thousand: the roster keeps kMaxSessionsPerWorker of that id,
// never pushing out the long-running one, cuts their texts, and writes at most kLogBurst lines per
// window, then says how many it held back.
TEST(WorkerRoster, InventedSessionsAreBoundedAndTheirLinesLimited) {
  Lines l;
  farm::WorkerRoster roster(10.0, l.log());
  EXPECT_TRUE(roster.heard(status(4, "running"), 1.0, "real"));
  for (uint64_t k = 0; k < 5000; ++k) {
    auto s = status(4, "running");
    s.worker_session(1000 + k);
    s.host(std::string(60000, 'h'));
    roster.heard(s, 2.0 + k * 1e-4, "forger");
  }
  EXPECT_EQ(roster.views().size(), farm::WorkerRoster::kMaxSessionsPerWorker);
  EXPECT_EQ(roster.views().count("local-2#42"), 1u) << "the worker heard first stays";
  for (const auto& [k, v] : roster.views()) EXPECT_LE(v.last.host().size(), farm::WorkerRoster::kMaxHostBytes);
  EXPECT_EQ(l.lines.size(), size_t(farm::WorkerRoster::kLogBurst));
  roster.heard(status(4, "running"), 20.0, "real");
  auto late = status(4, "running");
  late.worker_session(7);
  roster.heard(late, 20.5, "other");
  ASSERT_GE(l.lines.size(), size_t(farm::WorkerRoster::kLogBurst) + 2);
  EXPECT_NE(l.lines[farm::WorkerRoster::kLogBurst].find("roster line(s) held back"), std::string::npos)
      << l.lines[farm::WorkerRoster::kLogBurst];
}

TEST(RosterThread, HearsAndMarksDeadWhileTheLoopIsBusy) {
  const std::string events_path =
      (std::filesystem::temp_directory_path() / ("farm_roster_" + std::to_string(getpid()) + ".jsonl")).string();
  farm::dds::BusOptions o;
  o.domain = 120 + int(getpid() % 80);
  farm::dds::Bus learner_bus(o, "test learner"), worker_bus(o, "test worker");
  farm::EventLog events;
  events.open(events_path);
  std::vector<std::string> lines;
  std::mutex lines_mu;
  auto log = [&](const std::string& l) {
    std::lock_guard<std::mutex> lk(lines_mu);
    lines.push_back(l);
  };
  farm::WorkerRoster roster(1.0, log, "exp");
  roster.on_event([&](const nlohmann::json& e) { events.write("worker", e); });
  farm::RosterThread thread(learner_bus, std::move(roster), log, events);
  thread.start();
  StatusWriter out(worker_bus, farm::dds::kWorkerStatusTopic, "status_writer");
  farm::msg::WorkerStatus s = running_w1();
  // Live, then 1 s more of beats.
  ASSERT_TRUE(beat_until_live(thread, out, s));
  for (int i = 0; i < 10; ++i) {
    out.write(s);
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  const auto live = thread.find("w1#1");
  ASSERT_TRUE(live.has_value());
  EXPECT_TRUE(live->live);
  EXPECT_EQ(live->view.last.envs(), 4u);
  EXPECT_GT(thread.first_heard(), 0);
  // The worker goes silent and this thread, the learner's loop, calls nothing for 2.5 s: the
  // roster's own thread marks it dead within the 1 s timeout.
  std::this_thread::sleep_for(std::chrono::milliseconds(2500));
  EXPECT_EQ(thread.live_count(), 0);
  EXPECT_EQ(w1_changes(events_path), (std::vector<std::string>{"joined", "dead"}));
  std::remove(events_path.c_str());
}

// A flood of heartbeats from one participant, thousands a second, pushes no other worker's heartbeat
// out of the reader's history (KEEP_LAST 16): the real worker, beating every 0.2 s against a 1 s
// timeout, is never marked dead while the flood runs, and the flood is refused past its share. The
// three participants talk through their transports as separate processes do: Fast DDS 2.9's
// delivery within a process deadlocks (its writer liveliness against discovery) under such a flood.
TEST(RosterThread, AFloodFromOneParticipantPushesNoOtherWorkersHeartbeatOut) {
  const auto library = eprosima::fastrtps::xmlparser::XMLProfileManager::library_settings();
  auto apart = library;
  apart.intraprocess_delivery = eprosima::fastrtps::INTRAPROCESS_OFF;
  eprosima::fastrtps::xmlparser::XMLProfileManager::library_settings(apart);
  const std::string events_path =
      (std::filesystem::temp_directory_path() / ("farm_roster_flood_" + std::to_string(getpid()) + ".jsonl")).string();
  farm::dds::BusOptions o;
  o.domain = 40 + int(getpid() % 80);
  farm::dds::Bus learner_bus(o, "test learner"), worker_bus(o, "test worker"), flood_bus(o, "test flood");
  farm::EventLog events;
  events.open(events_path);
  auto log = [](const std::string&) {};
  farm::WorkerRoster roster(1.0, log, "exp");
  roster.on_event([&](const nlohmann::json& e) { events.write("worker", e); });
  farm::RosterThread thread(learner_bus, std::move(roster), log, events);
  thread.start();
  StatusWriter out(worker_bus, farm::dds::kWorkerStatusTopic, "status_writer");
  StatusWriter flood_out(flood_bus, farm::dds::kWorkerStatusTopic, "status_writer");
  farm::msg::WorkerStatus s = running_w1();
  ASSERT_TRUE(beat_until_live(thread, out, s));
  std::atomic<bool> flooding{true};
  uint64_t flooded = 0;
  std::thread flood([&] {
    farm::msg::WorkerStatus f = s;
    f.worker_id("flood");
    // About 20,000 a second: what the receiving side keeps up with on two busy cores, so that
    // nothing is dropped before the reader (a transport's queue is shared by every writer too).
    for (uint64_t k = 0; flooding.load(); ++k) {
      f.worker_session(1000 + k % 2000);
      flooded += flood_out.write(f);
      if (k % 20 == 19) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  });
  const double t1 = farm::now_seconds();
  while (farm::now_seconds() - t1 < 4) {
    out.write(s);
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  flooding = false;
  flood.join();
  EXPECT_EQ(w1_changes(events_path), (std::vector<std::string>{"joined"}));
  EXPECT_GT(flooded, 20000u);
  EXPECT_GT(thread.refused_for_rate(), 1000u) << flooded << " written";
  std::remove(events_path.c_str());
  eprosima::fastrtps::xmlparser::XMLProfileManager::library_settings(library);
}
