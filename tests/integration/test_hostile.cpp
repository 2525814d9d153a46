// A hostile participant on the farm's domain: batches claiming sequence numbers near 2^64 and 2^63,
// and invented sessions by the thousand with sequence numbers from the whole 64-bit range. Every one
// is refused and counted invalid, no account is opened or moved for them, the real worker's
// figures are exactly what it sent, and the learner keeps training at its normal update rate
// (printed: updates/s before and during the attack).
// Then oversized samples: well-formed batches of tens of MB, far above what the experiment's workers
// can send, are refused before the learner takes memory for them, counted invalid, and the learner's
// peak RSS stays under the bound documented in docs/record/reliability.md (item "size limits before memory").
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "process_util.h"

using namespace farm::testing;

namespace {

const char* kConfig = R"(experiment_id: "it_hostile"
seed: 5
task { name: "pendulum" }
sac { hidden: 64 hidden: 64 learning_starts: 1000 publish_every_updates: 25 }
worker { envs_per_worker: 8 steps_per_batch: 25 max_batches_per_version: 4 }
eval { episodes: 2 every_seconds: 600 final_episodes: 2 }
checkpoint_every_seconds: 600
stop { max_seconds: 36 }
log_every_seconds: 1
)";

struct Row {
  double elapsed, updates_per_s;
  long long updates;
};

std::vector<Row> read_csv(const std::string& path) {
  std::vector<Row> rows;
  std::istringstream in(slurp(path));
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    std::vector<std::string> f;
    std::stringstream ls(line);
    for (std::string x; std::getline(ls, x, ',');) f.push_back(x);
    if (f.size() < 5) continue;
    rows.push_back({std::stod(f[0]), std::stod(f[4]), std::stoll(f[3])});
  }
  return rows;
}

double mean_rate(const std::vector<Row>& rows, double from, double to) {
  double s = 0;
  int n = 0;
  for (const auto& r : rows)
    if (r.elapsed > from && r.elapsed <= to) s += r.updates_per_s, ++n;
  return n ? s / n : -1;
}

// The process's peak resident set (VmHWM) in MiB, or -1 once it is gone.
double peak_rss_mib(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("VmHWM:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;
  }
  return -1;
}

// Training settled: the learner's CSV shows updates for 6 s, so an attack meets a steady update
// rate; *first_update: when the first row with updates was written (60 s at most).
bool training_settled(const std::string& csv, double* first_update) {
  return poll_log(
      csv,
      [&](const std::string&) {
        const auto rows = read_csv(csv);
        for (const auto& r : rows)
          if (r.updates > 0) {
            *first_update = r.elapsed;
            break;
          }
        return *first_update >= 0 && !rows.empty() && rows.back().elapsed >= *first_update + 6;
      },
      60);
}

// A learner of kConfig, its experiment named `experiment`, and one worker "hw", on a private domain.
struct Farm {
  std::string dir, domain;
  Proc& learner;
  Proc& worker;
};

Farm start_farm(ProcessSet& set, int domain_offset, const std::string& experiment) {
  const std::string d = set.dir(), domain = std::to_string(private_domain(domain_offset));
  std::string cfg = kConfig;
  cfg.replace(cfg.find("it_hostile"), 10, experiment);
  write_file(d + "/cfg.txtpb", cfg);
  Proc& learner = set.start(
      {FARM_LEARNER_BIN, "--config", d + "/cfg.txtpb", "--run-dir", d + "/run", "--domain", domain}, "learner");
  Proc& worker = set.start({FARM_WORKER_BIN, "--domain", domain, "--id", "hw", "--log-every", "2"}, "worker");
  return {d, domain, learner, worker};
}

TEST(Hostile, ForgedSequencesAndInventedSessionsAreRefusedAndTrainingGoesOn) {
  ProcessSet set;
  const Farm farm = start_farm(set, 91, "it_hostile");
  const std::string &d = farm.dir, &domain = farm.domain;
  Proc &learner = farm.learner, &worker = farm.worker;
  const std::string csv = d + "/run/learner.csv";
  double first_update = -1;
  ASSERT_TRUE(training_settled(csv, &first_update)) << set.log("learner");
  const double attack_start = read_csv(csv).back().elapsed;
  Proc& hostile = set.start({FARM_INTRUDER_BIN, "--domain", domain, "--experiment", "it_hostile", "--id", "hostile",
                             "--seconds", "12", "--hostile", "1"},
                            "hostile");
  ASSERT_EQ(wait_for(hostile, 60), 0) << set.log("hostile");
  const double attack_end = read_csv(csv).back().elapsed;
  ASSERT_EQ(wait_for(learner, 120), 0) << set.log("learner");
  ASSERT_EQ(wait_for(worker, 60), 0) << set.log("worker");

  const nlohmann::json attack = set.last_event("hostile", "sent");
  ASSERT_FALSE(attack.empty()) << set.log("hostile");
  const long long sent = attack.value("batches", -1LL);
  EXPECT_GE(sent, 1000) << attack;
  EXPECT_GE(attack.value("batch_readers_matched", -1), 1) << attack;

  const nlohmann::json summary = summary_event(d + "/run");
  const BatchCounts c = batch_counts(summary);
  EXPECT_GT(c.ok, 50) << summary;
  EXPECT_EQ(c.lost, 0) << summary;
  EXPECT_EQ(c.duplicate, 0) << summary;
  EXPECT_EQ(c.invalid, sent) << summary;
  // One account: the real worker's, with exactly what it says it sent.
  const long long worker_sent = set.batches_sent("worker");
  ASSERT_GE(worker_sent, 0) << set.log("worker");
  EXPECT_EQ(closed_whole_stream(summary, "hw"), worker_sent) << summary;
  EXPECT_EQ(summary.value("streams", nlohmann::json::array()).size(), 1u) << summary;

  // Training went on at its rate: updates/s before and during the attack.
  const auto rows = read_csv(csv);
  const double before = mean_rate(rows, first_update + 2, attack_start);
  const double during = mean_rate(rows, attack_start + 1, attack_end);
  std::printf("updates/s before the attack %.0f, during it %.0f (ratio %.2f); %lld hostile batches refused\n", before,
              during, before > 0 ? during / before : 0.0, sent);
  ASSERT_GT(before, 0);
  EXPECT_GE(during, 0.5 * before);
  set.cleanup(::testing::Test::HasFailure());
}

// Bound on the learner's peak RSS in this experiment (pendulum, 8 envs x 25 steps, SAC 64x64) while
// it is fed 27 MB batches: what it needs for honest traffic with room to spare, and below what even
// a few of the oversized samples would take once taken into memory. docs/record/reliability.md, item
// "size limits before memory", gives the reasoning; Ingest::max_batch_bytes the per-sample bound.
constexpr double kOversizeRssBoundMiB = 320;

TEST(Hostile, OversizedBatchesAreRefusedBeforeMemoryAndTrainingGoesOn) {
  ProcessSet set;
  const Farm farm = start_farm(set, 93, "it_oversize");
  const std::string &d = farm.dir, &domain = farm.domain;
  Proc &learner = farm.learner, &worker = farm.worker;
  const std::string csv = d + "/run/learner.csv";
  double first_update = -1;
  ASSERT_TRUE(training_settled(csv, &first_update)) << set.log("learner");
  const double rss_before = peak_rss_mib(learner.pid);
  const double attack_start = read_csv(csv).back().elapsed;
  Proc& intruder = set.start({FARM_INTRUDER_BIN, "--domain", domain, "--experiment", "it_oversize", "--id", "oversize",
                              "--seconds", "12", "--oversize", "1"},
                             "oversize");
  // VmHWM is the peak: followed while the attack lasts and a little after, while batches drain.
  double rss_peak = rss_before;
  const auto follow = [&](double seconds) {
    for (auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
         std::chrono::steady_clock::now() < end;) {
      rss_peak = std::max(rss_peak, peak_rss_mib(learner.pid));
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
  };
  follow(12);
  ASSERT_EQ(wait_for(intruder, 60), 0) << set.log("oversize");
  follow(2);
  const double attack_end = read_csv(csv).back().elapsed;
  ASSERT_EQ(wait_for(learner, 120), 0) << set.log("learner");
  ASSERT_EQ(wait_for(worker, 60), 0) << set.log("worker");

  const nlohmann::json sample = set.last_event("oversize", "serialized");
  ASSERT_FALSE(sample.empty()) << set.log("oversize");
  const double sample_mib = sample.value("bytes", -1.0) / (1 << 20);
  const nlohmann::json attack = set.last_event("oversize", "sent");
  ASSERT_FALSE(attack.empty()) << set.log("oversize");
  const long long sent = attack.value("batches", -1LL);
  EXPECT_GE(sent, 5) << attack;
  EXPECT_GE(attack.value("batch_readers_matched", -1), 1) << attack;

  const nlohmann::json summary = summary_event(d + "/run");
  const BatchCounts c = batch_counts(summary);
  EXPECT_GT(c.ok, 50) << summary;
  EXPECT_EQ(c.lost, 0) << summary;
  EXPECT_EQ(c.duplicate, 0) << summary;
  EXPECT_EQ(c.invalid, sent) << summary << set.log("learner");
  const nlohmann::json refused = event_with(d + "/run", "refusal", "what", "batch sample");
  ASSERT_FALSE(refused.is_null()) << slurp(d + "/run/events.jsonl");
  EXPECT_GE(refused.value("count", 0), 1) << refused.dump();
  const long long worker_sent = set.batches_sent("worker");
  ASSERT_GE(worker_sent, 0) << set.log("worker");
  EXPECT_EQ(closed_whole_stream(summary, "hw"), worker_sent) << summary;
  EXPECT_TRUE(streams_of(summary, "oversize").empty()) << summary;

  const auto rows = read_csv(csv);
  const double before = mean_rate(rows, first_update + 2, attack_start);
  const double during = mean_rate(rows, attack_start + 1, attack_end);
  std::printf(
      "updates/s before the attack %.0f, during it %.0f (ratio %.2f); %lld oversized batches of %.1f MiB sent; "
      "learner peak RSS %.0f MiB before, %.0f MiB after (bound %.0f MiB)\n",
      before, during, before > 0 ? during / before : 0.0, sent, sample_mib, rss_before, rss_peak, kOversizeRssBoundMiB);
  ASSERT_GT(before, 0);
  EXPECT_GE(during, 0.5 * before);
  ASSERT_GT(rss_before, 0);
  EXPECT_LT(rss_peak, kOversizeRssBoundMiB);
  set.cleanup(::testing::Test::HasFailure());
}

// Evaluation requests from a participant that is not the learner, addressed to a training worker
// (farm_intruder --eval-requests: six wrong in one way each, the policy whose layout counts 2^64 + 8
// parameters among them, and one the worker could run): none is run or answered, since only the
// learner it joined asks it for evaluations, and the worker goes on training; the learner's own
// final evaluation is answered. Before, the worker ran the good ones and answered every one.
TEST(Hostile, ForgedEvaluationRequestsAreNotRunAndTheWorkerGoesOn) {
  ProcessSet set;
  const Farm farm = start_farm(set, 95, "it_hostile_eval");
  const std::string &d = farm.dir, &domain = farm.domain;
  Proc &learner = farm.learner, &worker = farm.worker;
  double first_update = -1;
  ASSERT_TRUE(training_settled(d + "/run/learner.csv", &first_update)) << set.log("learner");
  Proc& intruder = set.start({FARM_INTRUDER_BIN, "--domain", domain, "--experiment", "it_hostile_eval", "--id",
                              "forger", "--seconds", "6", "--eval-requests", "hw"},
                             "forger");
  ASSERT_EQ(wait_for(intruder, 60), 0) << set.log("forger");
  ASSERT_EQ(wait_for(learner, 120), 0) << set.log("learner");
  ASSERT_EQ(wait_for(worker, 60), 0) << set.log("worker");

  const nlohmann::json requests = set.last_event("forger", "eval_requests");
  ASSERT_FALSE(requests.empty()) << set.log("forger");
  EXPECT_EQ(requests.value("worker", ""), "hw") << requests;
  EXPECT_GE(requests.value("sent", -1LL), 60) << requests;
  EXPECT_GE(requests.value("readers_matched", -1), 1) << requests;
  EXPECT_EQ(requests.value("answers_received", -1), 0) << requests << set.log("worker").substr(0, 4000);
  const long long sent = set.batches_sent("worker");
  ASSERT_GE(sent, 0) << set.log("worker");

  const nlohmann::json summary = summary_event(d + "/run");
  EXPECT_EQ(closed_whole_stream(summary, "hw"), sent) << summary;
  EXPECT_EQ(summary.value("evals_asked", -1), 1) << summary;
  EXPECT_EQ(summary.value("evals_answered", -1), 1) << summary;
  EXPECT_EQ(summary.value("evals_lost", -1) + summary.value("evals_invalid", -1), 0) << summary;
  const nlohmann::json final_eval = event_with(d + "/run", "evaluation", "label", "final");
  ASSERT_FALSE(final_eval.is_null()) << slurp(d + "/run/events.jsonl");
  EXPECT_GT(final_eval.value("episodes", 0), 0) << final_eval.dump();
  EXPECT_TRUE(final_eval["mean"].is_number()) << final_eval.dump();
  set.cleanup(::testing::Test::HasFailure());
}

}  // namespace
