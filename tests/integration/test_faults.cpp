// Faults survived over real processes: a worker killed with SIGKILL mid-training, and the learner
// killed with SIGKILL and restarted with --resume while the workers stay up.
#include <gtest/gtest.h>

#include <filesystem>
#include <regex>
#include <string>

#include "process_util.h"

namespace fs = std::filesystem;
using namespace farm::testing;

namespace {

std::string config(const std::string& id, const std::string& stop) {
  return "experiment_id: \"" + id + R"("
seed: 11
task { name: "pendulum" }
sac { hidden: 64 hidden: 64 actor_lr: 1e-3 critic_lr: 1e-3 alpha_lr: 1e-3
      learning_starts: 1000 publish_every_updates: 25 }
worker { envs_per_worker: 8 steps_per_batch: 25 max_batches_per_version: 2 }
eval { episodes: 5 every_seconds: 10 final_episodes: 10 }
checkpoint_every_seconds: 3
log_every_seconds: 1
stop { )" +
         stop + " }\n";
}

// The `updates` column of the last row of learner.csv.
long long last_updates(const std::string& csv_path) {
  std::string text = slurp(csv_path);
  std::istringstream in(text);
  std::string header, line, last;
  std::getline(in, header);
  while (std::getline(in, line))
    if (!line.empty()) last = line;
  if (last.empty()) return -1;
  auto split = [](const std::string& s) {
    std::vector<std::string> v;
    std::stringstream ss(s);
    std::string x;
    while (std::getline(ss, x, ',')) v.push_back(x);
    return v;
  };
  auto h = split(header), r = split(last);
  for (size_t i = 0; i < h.size() && i < r.size(); ++i)
    if (h[i] == "updates") return std::stoll(r[i]);
  return -1;
}

TEST(Faults, KilledWorkerIsMarkedDeadTrainingGoesOnAndARestartRejoins) {
  ProcessSet set;
  const std::string d = set.dir(), domain = std::to_string(private_domain(41)), run = d + "/run";
  write_file(d + "/cfg.txtpb", config("it_worker_fault", "max_seconds: 35"));
  Proc& learner =
      set.start({FARM_LEARNER_BIN, "--config", d + "/cfg.txtpb", "--run-dir", run, "--domain", domain}, "learner");
  set.start({FARM_WORKER_BIN, "--domain", domain, "--id", "it-a"}, "worker-a");
  Proc& b = set.start({FARM_WORKER_BIN, "--domain", domain, "--id", "it-b"}, "worker-b");
  ASSERT_TRUE(wait_for_join(run, "it-b", 30)) << set.log("learner");
  // it-b is producing: its status line counts batches sent. Not its state word: on a busy machine a
  // worker that outpaces the learner is "throttled" at every status line while it sends.
  ASSERT_TRUE(wait_until(
      [&] {
        const auto p = set.worker_events("worker-b", "progress");
        return !p.empty() && p.back().value("batches_sent", 0) > 0;
      },
      30))
      << set.log("worker-b");
  std::this_thread::sleep_for(std::chrono::seconds(3));

  kill(b.pid, SIGKILL);
  wait_for(b, 5);
  const long long updates_at_kill = last_updates(run + "/learner.csv");
  // Marked dead within a few seconds (heartbeat every 1 s, timeout 4 s, log check every loop).
  EXPECT_TRUE(joined(run, "it-b") && wait_until([&] { return marked_dead(run, "it-b"); }, 8))
      << slurp(run + "/events.jsonl");
  std::this_thread::sleep_for(std::chrono::seconds(3));
  EXPECT_GT(last_updates(run + "/learner.csv"), updates_at_kill + 300) << "training stopped after a worker died";

  // The same worker id restarted: a new session, accepted from sequence 0.
  Proc& b2 = set.start({FARM_WORKER_BIN, "--domain", domain, "--id", "it-b"}, "worker-b2");
  ASSERT_EQ(wait_for(learner, 120), 0) << set.log("learner");
  EXPECT_EQ(wait_for(b2, 30), 0) << set.log("worker-b2");
  EXPECT_EQ(wait_for(set.procs()[1], 30), 0) << set.log("worker-a");

  const nlohmann::json summary = summary_event(run);
  EXPECT_TRUE(no_batch_lost_or_refused(summary)) << summary << slurp(run + "/events.jsonl");
  // Two sessions of it-b: the killed one (stream left open) and the restarted one.
  const auto sessions = streams_of(summary, "it-b");
  ASSERT_EQ(sessions.size(), 2u) << summary;
  int open = 0, closed_with_data = 0;
  for (const auto& s : sessions) {
    EXPECT_EQ(s.value("lost", -1) + s.value("duplicate", -1) + s.value("invalid", -1), 0) << s;
    open += !s.value("closed", true);
    closed_with_data += s.value("closed", false) && s.value("received", 0) > 10;
  }
  EXPECT_EQ(open, 1) << summary;
  EXPECT_EQ(closed_with_data, 1) << summary;
  EXPECT_TRUE(joined(d + "/run", "it-b")) << slurp(d + "/run/events.jsonl");
  set.cleanup(::testing::Test::HasFailure());
}

TEST(Faults, KilledLearnerResumesAndTheWorkersThatStayedUpCarryOn) {
  ProcessSet set;
  const std::string d = set.dir(), domain = std::to_string(private_domain(53)), run = d + "/run";
  std::string cfg = config("it_learner_fault", "max_updates: 9000");
  cfg.replace(cfg.find("every_seconds: 10"), 17, "every_seconds: 2");  // one answered before the kill
  write_file(d + "/cfg.txtpb", cfg);
  const std::vector<std::string> learner_argv = {FARM_LEARNER_BIN, "--config", d + "/cfg.txtpb", "--run-dir", run,
                                                 "--domain",       domain};
  Proc& first = set.start(learner_argv, "learner-1");
  set.start({FARM_WORKER_BIN, "--domain", domain, "--id", "it-a"}, "worker-a");
  set.start({FARM_WORKER_BIN, "--domain", domain, "--id", "it-b"}, "worker-b");
  ASSERT_TRUE(wait_for_events(run, "checkpoint", 1, 60)) << set.log("learner-1");
  EXPECT_EQ(events(run, "checkpoint")[0].value("ok", false), true) << slurp(run + "/events.jsonl");
  // An evaluation answered before the kill, so that the resumed run has counts to carry on.
  ASSERT_TRUE(wait_for_events(run, "evaluation", 1, 60)) << set.log("learner-1");
  std::this_thread::sleep_for(std::chrono::seconds(4));  // a second checkpoint, then more work that it lacks
  kill(first.pid, SIGKILL);
  wait_for(first, 5);
  ASSERT_TRUE(fs::exists(run + "/checkpoint/manifest.txtpb"));
  const std::string manifest = slurp(run + "/checkpoint/manifest.txtpb");
  std::smatch m;
  ASSERT_TRUE(std::regex_search(manifest, m, std::regex(R"(batches_ok: (\d+))"))) << manifest;
  const long long ok_at_checkpoint = std::stoll(m[1]);
  ASSERT_TRUE(std::regex_search(manifest, m, std::regex(R"(updates: (\d+))"))) << manifest;
  const long long updates_at_checkpoint = std::stoll(m[1]);
  ASSERT_LT(updates_at_checkpoint, 9000) << "the first learner finished before it was killed";
  // The evaluations asked before the kill count in the resumed run's summary, as its batches do.
  ASSERT_TRUE(std::regex_search(manifest, m, std::regex(R"(evals_asked: (\d+))"))) << manifest;
  const long long asked_at_checkpoint = std::stoll(m[1]);
  ASSERT_TRUE(std::regex_search(manifest, m, std::regex(R"(evals_answered: (\d+))"))) << manifest;
  const long long answered_at_checkpoint = std::stoll(m[1]);

  std::this_thread::sleep_for(std::chrono::seconds(2));
  Proc& second = set.start(
      [&] {
        auto a = learner_argv;
        a.push_back("--resume");
        return a;
      }(),
      "learner-2");
  ASSERT_EQ(wait_for(second, 180), 0) << set.log("learner-2");
  EXPECT_EQ(wait_for(set.procs()[1], 30), 0) << set.log("worker-a");
  EXPECT_EQ(wait_for(set.procs()[2], 30), 0) << set.log("worker-b");
  const auto starts = events(run, "start");
  ASSERT_EQ(starts.size(), 2u) << slurp(run + "/events.jsonl");
  EXPECT_FALSE(starts[0].value("resumed", true));
  EXPECT_TRUE(starts[1].value("resumed", false));
  for (const char* w : {"worker-a", "worker-b"})
    EXPECT_FALSE(set.worker_events(w, "learner_restarted").empty()) << set.log(w);

  const nlohmann::json summary = summary_event(run);
  const BatchCounts c = batch_counts(summary);
  EXPECT_GT(c.ok, ok_at_checkpoint + 50) << "no new batches accepted after the resume\n" << summary;
  EXPECT_EQ(c.duplicate, 0) << summary;
  EXPECT_EQ(c.invalid, 0) << summary;
  // One session per worker: they never restarted, the resumed learner carried their accounting on.
  for (const char* id : {"it-a", "it-b"}) {
    const auto streams = streams_of(summary, id);
    ASSERT_EQ(streams.size(), 1u) << id << "\n" << summary;
    EXPECT_EQ(streams[0].value("duplicate", -1) + streams[0].value("invalid", -1), 0) << streams[0];
    EXPECT_TRUE(streams[0].value("closed", false)) << streams[0];
  }
  // The resumed learner counts on from its checkpoint: the parts answered then, and each answer
  // it took itself (an `answer` event after its start).
  long long answered_after_resume = 0, started = 0;
  for (const auto& e : events(run)) {
    if (e.value("event", "") == "start") ++started;
    if (started == 2 && e.value("event", "") == "answer") ++answered_after_resume;
  }
  EXPECT_GT(answered_at_checkpoint, 0) << manifest;
  EXPECT_EQ(summary.value("evals_answered", -1LL), answered_at_checkpoint + answered_after_resume) << summary;
  EXPECT_GT(summary.value("evals_asked", -1LL), asked_at_checkpoint) << summary;
  EXPECT_GE(summary.value("updates", -1LL), 9000) << summary;
  set.cleanup(::testing::Test::HasFailure());
}

}  // namespace
