// End-to-end: the real farm-learner and two real farm-worker processes talk over Fast DDS on
// this machine (shared memory / loopback), train the pendulum with SAC, and account for every
// batch. One worker corrupts one batch with NaN; it must be rejected, counted, and training must
// go on. The workers start before the learner and must say they are waiting for it.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <regex>
#include <string>

#include "process_util.h"

namespace fs = std::filesystem;
using namespace farm::testing;

namespace {

class FarmProcesses : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = set_.dir();
    domain_ = std::to_string(private_domain(0));
  }
  void TearDown() override { set_.cleanup(HasFailure()); }
  Proc& start(const std::vector<std::string>& argv, const std::string& name) { return set_.start(argv, name); }
  long long batches_sent(const std::string& name) const { return set_.batches_sent(name); }

  ProcessSet set_;
  std::string dir_, domain_;
};

// Short pendulum experiment: same hyperparameters as the main job, a tighter clock.
const char* kConfig = R"(experiment_id: "it_pendulum"
seed: 3
task { name: "pendulum" }
sac {
  hidden: 64
  hidden: 64
  actor_lr: 1e-3
  critic_lr: 1e-3
  alpha_lr: 1e-3
  learning_starts: 1000
  publish_every_updates: 25
}
worker { envs_per_worker: 8 steps_per_batch: 25 max_batches_per_version: 2 }
eval { episodes: 10 every_seconds: 5 final_episodes: 20 }
stop { target_eval_return: -250 max_seconds: 300 }
checkpoint_every_seconds: 30
log_every_seconds: 2
)";

TEST_F(FarmProcesses, TrainsOverDdsAndEveryBatchArrivesExactlyOnce) {
  const std::string cfg = dir_ + "/it.txtpb", run = dir_ + "/run";
  write_file(cfg, kConfig);
  // Workers first: they must wait for the learner and say so.
  start({FARM_WORKER_BIN, "--domain", domain_, "--id", "it-a", "--inject-nan-batch", "5", "--log-every", "2"},
        "worker-a");
  start({FARM_WORKER_BIN, "--domain", domain_, "--id", "it-b", "--log-every", "2"}, "worker-b");
  std::this_thread::sleep_for(std::chrono::seconds(3));
  for (auto w : {"worker-a", "worker-b"}) EXPECT_FALSE(set_.worker_events(w, "waiting").empty()) << w;

  Proc& learner = start({FARM_LEARNER_BIN, "--config", cfg, "--run-dir", run, "--domain", domain_}, "learner");
  const int learner_rc = wait_for(learner, 600);
  const std::string learner_log = slurp(dir_ + "/learner.log");
  ASSERT_EQ(learner_rc, 0) << learner_log;
  int worker_rc[2];
  worker_rc[0] = wait_for(set_.procs()[0], 60);
  worker_rc[1] = wait_for(set_.procs()[1], 60);
  EXPECT_EQ(worker_rc[0], 0) << slurp(dir_ + "/worker-a.log");
  EXPECT_EQ(worker_rc[1], 0) << slurp(dir_ + "/worker-b.log");

  // Throughput rows went to the CSV, and each as a progress event under the CSV's column names.
  std::ifstream csv(run + "/learner.csv");
  std::string header, row;
  ASSERT_TRUE(std::getline(csv, header)) << "no learner.csv in " << run;
  EXPECT_NE(header.find("env_steps"), std::string::npos) << header;
  size_t rows = 0;
  while (std::getline(csv, row)) ++rows;
  EXPECT_GT(rows, 0u) << "learner.csv has no rows";
  const auto progress = events(run, "progress");
  ASSERT_EQ(progress.size(), rows);
  EXPECT_GT(progress.back().value("env_steps", 0), 0);
  EXPECT_TRUE(progress.back()["updates_per_s"].is_number()) << progress.back();
  // The ingest thread's counters, as it accepted batches.
  const auto ingest = events(run, "ingest");
  ASSERT_FALSE(ingest.empty());
  EXPECT_GT(ingest.back().value("batches_ok", 0), 0);

  // The NaN batch was refused with a reason naming it.
  const auto refusal = event_with(run, "refusal", "reason", "non-finite value");
  ASSERT_FALSE(refusal.is_null()) << learner_log;
  EXPECT_EQ(refusal.value("worker_id", ""), "it-a") << refusal;
  EXPECT_EQ(refusal.value("sequence_number", -1), 5) << refusal;

  const nlohmann::json summary = summary_event(run);
  ASSERT_FALSE(summary.empty()) << learner_log;
  const BatchCounts c = batch_counts(summary);
  EXPECT_GT(c.ok, 0);
  EXPECT_EQ(c.lost, 0) << summary;
  EXPECT_EQ(c.duplicate, 0) << summary;
  EXPECT_EQ(c.invalid, 1) << summary;

  // Every sequence number each worker says it sent reached the learner exactly once.
  struct Expect {
    const char* id;
    const char* log;
    int invalid;
  };
  for (Expect e : {Expect{"it-a", "worker-a", 1}, Expect{"it-b", "worker-b", 0}}) {
    const long long n = batches_sent(e.log);
    ASSERT_GT(n, 6) << e.id << "\n" << slurp(dir_ + "/" + e.log + ".log");
    const auto streams = streams_of(summary, e.id);
    ASSERT_EQ(streams.size(), 1u) << e.id << "\n" << summary;
    const nlohmann::json& got = streams[0];
    EXPECT_TRUE(got.value("closed", false)) << got;
    EXPECT_EQ(got.value("received", -1LL) + got.value("invalid", -1LL), n) << got;
    EXPECT_EQ(got.value("last_sequence", -1LL), n - 1) << got;
    EXPECT_EQ(got.value("lost", -1), 0) << got;
    EXPECT_EQ(got.value("duplicate", -1), 0) << got;
    EXPECT_EQ(got.value("invalid", -1), e.invalid) << got;
  }

  // Learning progressed: a random policy scores about -1200 on Pendulum-v1; the target is -250.
  const nlohmann::json final_eval = event_with(run, "evaluation", "label", "final");
  ASSERT_TRUE(final_eval.contains("mean") && final_eval["mean"].is_number()) << slurp(run + "/events.jsonl");
  EXPECT_GT(final_eval["mean"].get<double>(), -400.0) << final_eval;
  EXPECT_TRUE(fs::exists(run + "/checkpoint/manifest.txtpb"));
  // The best evaluation's networks were kept beside the checkpoint.
  EXPECT_EQ(best_policy_problem(run, summary, "sac"), "");
  EXPECT_FALSE(events(run, "best").empty()) << learner_log;
  // Both workers joined, and the run says why it stopped and what it took.
  EXPECT_GE(events(run, "worker").size(), 2u);
  ASSERT_EQ(events(run, "stop").size(), 1u);
  const auto end = events(run, "summary");
  ASSERT_EQ(end.size(), 1u);
  EXPECT_EQ(end[0].value("batches_invalid", -1), 1) << end[0];
  EXPECT_EQ(end[0].value("batches_lost", -1), 0) << end[0];
}

TEST_F(FarmProcesses, MisspelledConfigFieldIsNamedAndNothingIsLost) {
  const std::string cfg = dir_ + "/typo.txtpb", run = dir_ + "/run";
  std::string text = kConfig;
  text.replace(text.find("learning_starts"), std::string("learning_starts").size(), "learning_start");
  write_file(cfg, text);
  fs::create_directories(run);
  write_file(run + "/learner.csv", "earlier results\n");

  Proc& learner = start({FARM_LEARNER_BIN, "--config", cfg, "--run-dir", run, "--domain", domain_}, "learner");
  const int rc = wait_for(learner, 60);
  const std::string out = slurp(dir_ + "/learner.log");
  EXPECT_NE(rc, 0) << out;
  EXPECT_NE(out.find("typo.txtpb:10:"), std::string::npos) << out;
  EXPECT_NE(out.find("learning_start"), std::string::npos) << out;
  // The earlier run is untouched.
  EXPECT_EQ(slurp(run + "/learner.csv"), "earlier results\n");
}

TEST_F(FarmProcesses, ResumeCarriesOnFromTheCheckpoint) {
  const std::string cfg = dir_ + "/it.txtpb", run = dir_ + "/run";
  std::string text = kConfig;
  // A run that stops on its update budget, then a resumed run with a larger budget.
  text.replace(text.find("stop {"), std::string("stop {").size(), "stop { max_updates: 1500");
  text.replace(text.find("target_eval_return: -250"), std::string("target_eval_return: -250").size(),
               "target_eval_return: 1000");
  write_file(cfg, text);
  start({FARM_WORKER_BIN, "--domain", domain_, "--id", "it-r"}, "worker");
  Proc& first = start({FARM_LEARNER_BIN, "--config", cfg, "--run-dir", run, "--domain", domain_}, "learner-1");
  ASSERT_EQ(wait_for(first, 300), 0) << slurp(dir_ + "/learner-1.log");
  const double updates_1 = summary_event(run).value("updates", -1.0);
  EXPECT_GE(updates_1, 1500);

  std::string more = text;
  more.replace(more.find("max_updates: 1500"), std::string("max_updates: 1500").size(), "max_updates: 2500");
  write_file(cfg, more);
  start({FARM_WORKER_BIN, "--domain", domain_, "--id", "it-r2"}, "worker-2");
  Proc& second =
      start({FARM_LEARNER_BIN, "--config", cfg, "--run-dir", run, "--domain", domain_, "--resume"}, "learner-2");
  ASSERT_EQ(wait_for(second, 300), 0) << slurp(dir_ + "/learner-2.log");
  const auto starts = events(run, "start");  // one file for the run, resumed or not
  ASSERT_EQ(starts.size(), 2u) << slurp(dir_ + "/learner-2.log");
  EXPECT_FALSE(starts[0].value("resumed", true));
  EXPECT_TRUE(starts[1].value("resumed", false));
  const double updates_2 = summary_event(run).value("updates", -1.0);
  EXPECT_GE(updates_2, 2500);
  EXPECT_LT(updates_2 - updates_1, 1500) << "the resumed run started from scratch";
}

// Ctrl-C on a busy learner, then --resume: the batches the learner's reader had already taken
// when it stopped go into its checkpoint, so every worker's account ends with lost 0 and what it
// says it sent (workers that never wait on their own: a budget of 1,000 batches per version).
TEST_F(FarmProcesses, CleanStopAndResumeLoseNothing) {
  const std::string cfg = dir_ + "/it.txtpb", run = dir_ + "/run";
  std::string text = kConfig;
  text.replace(text.find("max_batches_per_version: 2"), std::string("max_batches_per_version: 2").size(),
               "max_batches_per_version: 1000");
  text.replace(text.find("publish_every_updates: 25"), std::string("publish_every_updates: 25").size(),
               "publish_every_updates: 5");
  text.replace(text.find("target_eval_return: -250 max_seconds: 300"),
               std::string("target_eval_return: -250 max_seconds: 300").size(), "max_seconds: 24");
  write_file(cfg, text);
  Proc& first = start({FARM_LEARNER_BIN, "--config", cfg, "--run-dir", run, "--domain", domain_}, "learner-1");
  Proc& wa = start({FARM_WORKER_BIN, "--domain", domain_, "--id", "it-sa"}, "worker-a");
  Proc& wb = start({FARM_WORKER_BIN, "--domain", domain_, "--id", "it-sb"}, "worker-b");
  auto updates = [&] {
    const auto p = events(run, "progress");
    return p.empty() ? 0 : p.back().value("updates", 0);
  };
  ASSERT_TRUE(wait_until([&] { return updates() >= 1000; }, 120)) << slurp(dir_ + "/learner-1.log");
  kill(first.pid, SIGINT);
  ASSERT_EQ(wait_for(first, 60), 130) << slurp(dir_ + "/learner-1.log");
  Proc& second =
      start({FARM_LEARNER_BIN, "--config", cfg, "--run-dir", run, "--domain", domain_, "--resume"}, "learner-2");
  ASSERT_EQ(wait_for(second, 120), 0) << slurp(dir_ + "/learner-2.log");
  EXPECT_EQ(wait_for(wa, 60), 0) << slurp(dir_ + "/worker-a.log");
  EXPECT_EQ(wait_for(wb, 60), 0) << slurp(dir_ + "/worker-b.log");
  const nlohmann::json summary = summary_event(run);
  for (const char* id : {"it-sa", "it-sb"}) {
    const std::string name = "worker-" + std::string(id).substr(4);
    const long long sent = batches_sent(name);
    ASSERT_GE(sent, 0) << slurp(dir_ + "/" + name + ".log");
    EXPECT_EQ(closed_whole_stream(summary, id), sent) << id << "\n"
                                                      << summary << "\n"
                                                      << slurp(dir_ + "/learner-1.log");
  }
}

}  // namespace
