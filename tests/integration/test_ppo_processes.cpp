// PPO over the farm, with the real farm-learner and two real farm-worker processes on Fast DDS:
// the cart-pole swing-up is trained to a stated return, every fit is logged with its numbers, and
// every batch is accounted for. A second run kills one worker with SIGKILL mid-training: the fits
// go on with the worker that is left.
#include <gtest/gtest.h>

#include <signal.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>

#include "process_util.h"

namespace fs = std::filesystem;
using namespace farm::testing;

namespace {

// The shipped cart-pole PPO experiment, with the run's clock and evaluation cadence of a test.
std::string config(const std::string& id, const std::string& stop) {
  std::string text = slurp(std::string(FARM_SOURCE_DIR) + "/deploy/configs/cartpole_ppo.txtpb");
  text = std::regex_replace(text, std::regex(R"(experiment_id: "cartpole_ppo")"), "experiment_id: \"" + id + "\"");
  text = std::regex_replace(text, std::regex(R"(stop \{[^}]*\})"), "stop { " + stop + " }");
  return text + "checkpoint_every_seconds: 30\n";
}

// A swing-up that stays up scores about 1 per step (250 steps); the untrained policy about 10, and
// one that only now and then gets the pole up 40-60. The target sits well above those.
constexpr double kTargetReturn = 150.0;
constexpr double kLearnedReturn = 50.0;

TEST(PpoProcesses, CartpoleSwingUpTrainsOverDdsAndEveryFitIsLogged) {
  ProcessSet set;
  const std::string d = set.dir(), domain = std::to_string(private_domain(61)), run = d + "/run";
  write_file(d + "/cfg.txtpb", config("it_cartpole_ppo", "target_eval_return: " + std::to_string(int(kTargetReturn)) +
                                                             " max_seconds: 480"));
  Proc& learner =
      set.start({FARM_LEARNER_BIN, "--config", d + "/cfg.txtpb", "--run-dir", run, "--domain", domain}, "learner");
  set.start({FARM_WORKER_BIN, "--domain", domain, "--id", "ppo-a", "--log-every", "5"}, "worker-a");
  set.start({FARM_WORKER_BIN, "--domain", domain, "--id", "ppo-b", "--log-every", "5"}, "worker-b");
  const int rc = wait_for(learner, 560);
  const std::string log = slurp(d + "/learner.log");
  ASSERT_EQ(rc, 0) << log;
  EXPECT_EQ(wait_for(set.procs()[1], 60), 0) << slurp(d + "/worker-a.log");
  EXPECT_EQ(wait_for(set.procs()[2], 60), 0) << slurp(d + "/worker-b.log");

  const nlohmann::json summary = summary_event(run);
  ASSERT_FALSE(summary.empty()) << log;
  EXPECT_NE(summary.value("reason", "").find("reached the target"), std::string::npos) << summary;
  const nlohmann::json final_eval = event_with(run, "evaluation", "label", "final");
  ASSERT_TRUE(final_eval.contains("mean") && final_eval["mean"].is_number()) << slurp(run + "/events.jsonl");
  // The final, larger evaluation is of the policy after one more fit, on the steps held at the stop,
  // and one PPO fit moves this task's evaluation by tens either way. What the run keeps is its best
  // (RUN/best, checked next); the final must still be a learned policy, far above the untrained one.
  EXPECT_GE(final_eval["mean"].get<double>(), kLearnedReturn) << final_eval;
  EXPECT_EQ(best_policy_problem(run, summary, "ppo"), "");  // the best evaluation's networks, kept
  ASSERT_TRUE(summary["best_eval"].is_number()) << summary;
  EXPECT_GE(summary["best_eval"].get<double>(), kTargetReturn) << summary;  // and they met the target
  const BatchCounts c = batch_counts(summary);
  EXPECT_GT(c.ok, 0);
  EXPECT_EQ(c.lost, 0) << summary;
  EXPECT_EQ(c.duplicate, 0) << summary;
  EXPECT_EQ(c.invalid, 0) << summary;
  // Each worker's stream: every number it sent arrived once.
  for (const char* id : {"ppo-a", "ppo-b"}) EXPECT_GT(closed_whole_stream(summary, id), 0) << id << "\n" << summary;

  // Every fit is a progress event (its learner.csv row) with version, steps used and carried,
  // stale drops, lag, KL, rate, clip fraction, value loss, entropy and mean return; steps used is
  // the configured steps per fit, except in the last fit, of what was held at the stop (at least a
  // mini-batch).
  const auto fits = events(run, "progress");
  ASSERT_GE(fits.size(), 2u) << log;
  for (size_t i = 0; i < fits.size(); ++i) {
    const auto& f = fits[i];
    for (const char* k : {"fit", "policy_version", "steps_used", "steps_carried", "stale_dropped", "lag_mean", "kl",
                          "learning_rate", "clip_fraction", "value_loss", "entropy", "fit_seconds"})
      EXPECT_TRUE(f[k].is_number()) << k << " in " << f;
    EXPECT_EQ(f.value("fit", 0), int(i) + 1) << f;
    if (i + 1 < fits.size()) {
      EXPECT_EQ(f.value("steps_used", 0), 8192) << f;
    } else {
      EXPECT_GE(f.value("steps_used", 0), 2048) << f;
      EXPECT_LE(f.value("steps_used", 0), 8192) << f;
    }
  }
  std::ifstream csv(run + "/learner.csv");
  std::string header;
  ASSERT_TRUE(std::getline(csv, header));
  for (const char* col : {"steps_used", "steps_carried", "stale_dropped", "lag_mean", "lag_max", "kl", "learning_rate",
                          "clip_fraction", "value_loss", "entropy", "mean_return"})
    EXPECT_NE(header.find(col), std::string::npos) << col << " not in " << header;
  // The synchronous mode fits the version it published, and only that one.
  EXPECT_EQ(summary.value("steps_fitted_by_lag", nlohmann::json::object()),
            nlohmann::json({{"0", summary.value("steps_fitted", -1)}}))
      << summary;
  set.cleanup(::testing::Test::HasFailure());
}

// The asynchronous mode: workers simulate on with the weights they have while the learner fits;
// each fit takes data of the versions within the lag window (V-trace corrects for the older ones),
// the lag of what it used is logged, and every step sent is fitted, counted stale or said to be
// still held at the end. The same swing-up is learned.
TEST(PpoProcesses, AsynchronousModeFitsRecentVersionsAndAccountsForEveryStep) {
  ProcessSet set;
  const std::string d = set.dir(), domain = std::to_string(private_domain(73)), run = d + "/run";
  // Stopped on an evaluation goal over the task's own metric: swung up for half of each episode.
  std::string text =
      config("it_ppo_async", "eval_goal { metric: \"upright_fraction\" at_least: 0.5 } max_seconds: 480");
  text = std::regex_replace(text, std::regex(R"(steps_per_run: 1000000)"),
                            "steps_per_run: 1000000\n  mode: \"async\"\n  max_policy_lag: 2");
  write_file(d + "/cfg.txtpb", text);
  Proc& learner =
      set.start({FARM_LEARNER_BIN, "--config", d + "/cfg.txtpb", "--run-dir", run, "--domain", domain}, "learner");
  set.start({FARM_WORKER_BIN, "--domain", domain, "--id", "async-a"}, "worker-a");
  set.start({FARM_WORKER_BIN, "--domain", domain, "--id", "async-b"}, "worker-b");
  const int rc = wait_for(learner, 560);
  const std::string log = slurp(d + "/learner.log");
  ASSERT_EQ(rc, 0) << log;
  const nlohmann::json summary = summary_event(run);
  ASSERT_FALSE(summary.empty()) << log;
  // Stopped on the goal: the last evaluation's upright_fraction at least 0.5.
  EXPECT_EQ(summary.value("reason", "").rfind("evaluation goal reached: upright_fraction ", 0), 0u) << summary;
  EXPECT_EQ(summary.value("mode", ""), "async") << summary;
  EXPECT_EQ(summary.value("max_policy_lag", -1), 2) << summary;
  const BatchCounts c = batch_counts(summary);
  EXPECT_EQ(c.lost, 0) << summary;
  EXPECT_EQ(c.invalid, 0) << summary;
  // Every simulated step the learner took is fitted, stale or held: the total is the run's steps.
  const long long env_steps = summary.value("env_steps", -1LL);
  EXPECT_EQ(
      summary.value("steps_fitted", -1LL) + summary.value("steps_stale", -1LL) + summary.value("steps_held", -1LL),
      env_steps)
      << summary;
  const long long held_at_end = summary.value("steps_held", -1LL);
  // The workers are held at the stop: while the final evaluation runs, each sends at most the
  // batches it had made or begun (two sender buffers and the one it collects, or its one of a
  // version just published), not the rest of its quota (16 envs x 64 steps a batch).
  ASSERT_TRUE(summary.contains("env_steps_after_stop")) << summary;
  EXPECT_LE(summary.value("env_steps_after_stop", -1LL), 2 * 4 * 16 * 64) << summary;
  // What had arrived before the stop, and what the held workers had made, went into a last fit,
  // unless it was less than a mini-batch (2,048 steps; a fit takes 8,192): left unfitted is that
  // little, and at most one batch (1,024 steps) that came later still.
  EXPECT_LT(held_at_end, 2048 + 1024) << summary << log;
  // Each fit's CSV row: lag within the window; some fits used older versions' data (workers ran on).
  std::ifstream csv(run + "/learner.csv");
  std::string header, row;
  ASSERT_TRUE(std::getline(csv, header));
  const auto column = [&](const std::string& name) {
    for (size_t at = 0, i = 0;; ++i) {
      const size_t next = header.find(',', at);
      if (header.substr(at, next == std::string::npos ? std::string::npos : next - at) == name) return int(i);
      if (next == std::string::npos) return -1;
      at = next + 1;
    }
  };
  const int lag_max = column("lag_max");
  ASSERT_GE(lag_max, 0) << header;
  int rows = 0, lagged = 0;
  while (std::getline(csv, row)) {
    std::stringstream fields(row);
    std::string f;
    for (int i = 0; i <= lag_max; ++i) std::getline(fields, f, ',');
    EXPECT_LE(std::stoi(f), 2) << row;
    lagged += std::stoi(f) > 0;
    ++rows;
  }
  EXPECT_GE(rows, 2);
  EXPECT_GT(lagged, 0) << "no fit used an older version's steps";
  // The ingest thread took the workers' batches while the loop fitted: the busy events (passes of
  // 0.1 s or more) count what it accepted meanwhile.
  uint64_t during_fits = 0;
  for (const auto& e : events(run, "busy")) during_fits += e.value("batches_accepted", uint64_t(0));
  EXPECT_GT(during_fits, 0u) << slurp(run + "/events.jsonl");
  set.cleanup(::testing::Test::HasFailure());
}

TEST(PpoProcesses, FitsCompleteWithTheRemainingWorkerWhenOneIsKilled) {
  ProcessSet set;
  const std::string d = set.dir(), domain = std::to_string(private_domain(67)), run = d + "/run";
  write_file(d + "/cfg.txtpb", config("it_ppo_fault", "max_seconds: 70"));
  Proc& learner =
      set.start({FARM_LEARNER_BIN, "--config", d + "/cfg.txtpb", "--run-dir", run, "--domain", domain}, "learner");
  set.start({FARM_WORKER_BIN, "--domain", domain, "--id", "ppo-a"}, "worker-a");
  Proc& victim = set.start({FARM_WORKER_BIN, "--domain", domain, "--id", "ppo-b"}, "worker-b");
  // The victim must have joined before it is killed: on a loaded host the learner fits with the
  // first worker alone, and a worker that never joined is never marked dead.
  ASSERT_TRUE(wait_for_join(run, "ppo-b", 120)) << slurp(d + "/learner.log");
  // The last fit a progress record names (a fit's record may wait for the evaluation asked at it).
  auto last_fit = [&] {
    const auto p = events(run, "progress");
    return p.empty() ? 0 : p.back().value("fit", 0);
  };
  ASSERT_TRUE(wait_until([&] { return last_fit() >= 2; }, 120)) << slurp(d + "/learner.log");
  kill(victim.pid, SIGKILL);
  wait_for(victim, 10);
  const int fits_at_kill = last_fit();
  ASSERT_TRUE(wait_until([&] { return marked_dead(run, "ppo-b"); }, 30)) << slurp(run + "/events.jsonl");
  const int rc = wait_for(learner, 120);
  const std::string log = slurp(d + "/learner.log");
  ASSERT_EQ(rc, 0) << log;
  // At least two more fits after the kill, made with one worker's data.
  EXPECT_GE(last_fit(), fits_at_kill + 2) << slurp(run + "/events.jsonl");
  const nlohmann::json summary = summary_event(run);
  const BatchCounts c = batch_counts(summary);
  EXPECT_EQ(c.lost, 0) << summary;
  EXPECT_EQ(c.invalid, 0) << summary;
  const auto killed = streams_of(summary, "ppo-b");
  ASSERT_EQ(killed.size(), 1u) << summary;
  EXPECT_FALSE(killed[0].value("closed", true)) << summary;  // the killed worker's stream stays open
  set.cleanup(::testing::Test::HasFailure());
}

// The PPO learner killed with SIGKILL after a fit it made past its last checkpoint, then resumed:
// the resumed learner publishes version numbers no worker holds yet (a worker holding the number
// would keep the killed learner's weights and PPO would fit on another policy's log-probabilities),
// the worker runs those weights, and the fits go on with nothing refused.
TEST(PpoProcesses, ResumeAfterSigkillPublishesVersionsNoWorkerHolds) {
  ProcessSet set;
  const std::string d = set.dir(), domain = std::to_string(private_domain(71)), run = d + "/run";
  std::string text = config("it_ppo_resume", "max_seconds: 400");
  text.replace(text.find("checkpoint_every_seconds: 30"), std::string("checkpoint_every_seconds: 30").size(),
               "checkpoint_every_seconds: 4");
  write_file(d + "/cfg.txtpb", text);
  Proc& first =
      set.start({FARM_LEARNER_BIN, "--config", d + "/cfg.txtpb", "--run-dir", run, "--domain", domain}, "learner-1");
  set.start({FARM_WORKER_BIN, "--domain", domain, "--id", "ppo-r", "--log-every", "1"}, "worker");
  // A fit after the latest checkpoint: the killed learner published a version the checkpoint lacks.
  auto fit_after_checkpoint = [&] {
    const auto c = events(run, "checkpoint");
    const auto p = events(run, "progress");
    return !c.empty() && !p.empty() && p.back().value("elapsed_s", 0.0) > c.back().value("elapsed_s", 0.0);
  };
  ASSERT_TRUE(wait_until(fit_after_checkpoint, 180)) << slurp(run + "/events.jsonl") << set.log("learner-1");
  kill(first.pid, SIGKILL);
  wait_for(first, 10);
  // The versions the killed learner published: each fit's row names the version fitted, and the
  // fit publishes the next; rows that waited for an evaluation at the kill are in the worker's
  // progress events (the version it runs).
  auto highest_version = [&] {
    uint64_t v = 0;
    for (const auto& e : set.worker_events("worker", "progress"))
      v = std::max<uint64_t>(v, e.value("policy_version", uint64_t(0)));
    return v;
  };
  uint64_t published = highest_version();
  for (const auto& e : events(run, "progress"))
    published = std::max<uint64_t>(published, e.value("policy_version", uint64_t(0)) + 1);
  ASSERT_GT(published, 0u) << slurp(run + "/events.jsonl");
  const size_t events_of_first = events(run).size();
  // The resumed learner's events: those after the first learner's.
  auto resumed = [&](const std::string& kind) {
    std::vector<nlohmann::json> out;
    const auto all = events(run);
    for (size_t i = events_of_first; i < all.size(); ++i)
      if (all[i].value("event", "") == kind) out.push_back(all[i]);
    return out;
  };

  Proc& second = set.start(
      {FARM_LEARNER_BIN, "--config", d + "/cfg.txtpb", "--run-dir", run, "--domain", domain, "--resume"}, "learner-2");
  ASSERT_TRUE(wait_until([&] { return resumed("progress").size() >= 2; }, 180))
      << slurp(d + "/learner-2.log") << "\nthe worker's log:\n"
      << set.log("worker");
  kill(second.pid, SIGINT);
  EXPECT_EQ(wait_for(second, 60), 130) << slurp(d + "/learner-2.log");
  const auto starts = resumed("start");
  ASSERT_EQ(starts.size(), 1u) << slurp(run + "/events.jsonl");
  EXPECT_TRUE(starts[0].value("resumed", false));
  // The first version the resumed learner fitted is the first it published.
  const auto fits = resumed("progress");
  ASSERT_GE(fits.size(), 2u) << slurp(run + "/events.jsonl");
  const uint64_t next = fits[0].value("policy_version", uint64_t(0));
  EXPECT_GT(next, published) << "the resumed learner reuses version numbers the killed one published\n"
                             << slurp(run + "/events.jsonl");
  // Every fit of the resumed learner was made on its own versions, and no batch was refused.
  for (const auto& f : fits) EXPECT_GE(f.value("policy_version", uint64_t(0)), next) << f.dump();
  EXPECT_TRUE(resumed("refusal").empty()) << slurp(run + "/events.jsonl");
  // The worker ran the resumed learner's weights.
  EXPECT_GE(highest_version(), next) << set.log("worker");
  set.cleanup(::testing::Test::HasFailure());
}

}  // namespace
