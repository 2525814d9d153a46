// The farm side of the learner, a runner of parts: the ingest thread takes and accounts the
// workers' batches (ingest_thread.h), the roster thread hears their heartbeats (roster_thread.h),
// the spec publisher publishes the experiment, the evaluator asks workers for evaluations and
// merges their answers (evaluator.h: the learner steps no simulation and links no robot), the
// checkpointer keeps RUN/checkpoint and RUN/best (checkpointer.h). This class runs the main loop:
// hands accepted batches and finished evaluations to the algorithm, publishes the weights it hands
// back, writes progress lines, asks for checkpoints, applies the stop rules and Ctrl-C, resumes from
// a checkpoint, closes the workers' streams at the end and writes the summary (farm_run_end.cpp). What it trains with
// is an Algorithm (algorithms/algorithm.h) from the registry, in its pacing (pacing.h).
#pragma once

#include <atomic>
#include <cmath>
#include <cstdint>
#include <deque>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "checkpointer.h"
#include "dds.h"
#include "evaluator.h"
#include "events.h"
#include "farm_config.pb.h"
#include "ingest.h"
#include "ingest_thread.h"
#include "pacing.h"
#include "roster_thread.h"
#include "spec_publisher.h"
#include "stats_reporter.h"
#include "task_spec.h"
#include "weight_publisher.h"
#include "worker_roster.h"

namespace farm {

struct LearnerRunOptions {
  farm::dds::BusOptions bus;
  bool resume = false;
  std::string run_dir;  // default <run_root>/<experiment_id>
};

class FarmService final : public Farm {
 public:
  FarmService(const LearnerRunOptions& o, const config::ExperimentConfig& cfg, const std::atomic<bool>& interrupted);
  // Runs the experiment to its end; returns the process exit code (130 when interrupted).
  int run();

  // --- Farm: what the algorithm may ask ---
  void publish(const PolicyParams& policy, uint32_t batch_quota) override;
  std::vector<LiveWorker> live_workers() const override;
  double first_worker_heard() const override { return roster_.first_heard(); }
  FarmFigures figures() const override;
  uint64_t env_steps() const override { return intake_.env_steps(); }
  double elapsed() const override;
  bool ask_evaluation(const PolicyParams& policy, const EvalAsk& ask) override;
  void record_evaluation(const EvalReport& report, uint64_t version, int64_t updates, double elapsed) override;
  void log(const std::string& s) const override;
  void row(const StatsRecord& r) override { stats_.row(r); }

 private:
  void prepare_run_dir();
  // --resume: the checkpoint's state taken back, or an error that says why it cannot be.
  void resume_from_checkpoint();
  void work();
  // Hands up to max batches that the ingest thread accepted to the algorithm; returns how many.
  size_t drain_batches(size_t max);
  // One accepted batch to the algorithm, and its finished episodes to the recent returns.
  void take(AcceptedBatch& a);
  // Takes batches while they come, until none came for `quiet` seconds or `most` seconds passed.
  void drain_while_arriving(double quiet, double most);
  int live_count() const;
  void progress(double elapsed, double window);
  // The stop limits of the experiment's stop block (target return, evaluation goals, time, env
  // steps, updates).
  std::string should_stop(double elapsed) const;
  // A training evaluation's report against stop.eval_goal: goal_reached_ says so once all are met.
  void note_goal(const EvalAsk& ask, const EvalReport& rep);
  // RUN/checkpoint with the algorithm's state, the policy file and the accounts (checkpointer.h);
  // a failure (a full disk) is logged and the last good checkpoint kept: false.
  bool try_checkpoint(double elapsed);
  // The manifest fields every checkpoint carries, but the accounts (accounts_to_manifest).
  config::CheckpointManifest base_manifest(uint64_t version, int64_t updates, double elapsed) const;

  // --- The end of a run (farm_run_end.cpp) ---
  // Summary lines: the head (experiment, reason, time, env steps) and one line per worker stream;
  // the streams' figures also go into the summary event (streams_open, streams_retired,
  // streams_not_listed, batches_other_experiments, and `streams`, one object a line).
  std::string summary_head(double elapsed, const std::string& reason) const;
  std::string summary_workers(nlohmann::json& event);
  // A line for the log and summary when the run ended on an env step or update limit before its
  // first evaluation (a limit that more workers reach sooner); "" otherwise.
  std::string untrained_stop_note(const std::string& reason) const;
  void write_summary(double elapsed, const std::string& reason);
  void drain_until_workers_end();
  // On Ctrl-C / SIGTERM, before the checkpoint: the batches already on their way.
  void drain_before_interrupted_stop();

  // --- Evaluations on workers (farm_evaluations.cpp; the asking and merging: evaluator.h) ---
  // Takes what the evaluator finished and hands it to the algorithm.
  void poll_evaluations();
  // One finished evaluation to the algorithm (its report, or that it was given up), with the stop
  // rule's evaluation goal and the networks asked for a new best; its snapshot dropped after.
  void report(Evaluator::Done& d);
  // After the final evaluation is asked: evaluations out are answered or counted lost, within
  // eval.answer_timeout_seconds (sooner when no worker is live for worker_timeout_seconds).
  void wait_for_evaluations();

  LearnerRunOptions opt_;
  config::ExperimentConfig cfg_;
  const std::atomic<bool>& interrupted_;
  robots::TaskSpec task_spec_;  // from the config alone: the learner builds no task
  farm::dds::Bus bus_;
  SpecPublisher spec_;
  WeightPublisher weights_;
  EventLog events_;  // before intake_, whose thread writes to it
  IngestThread intake_;
  static constexpr size_t kMaxSummaryStreams = 64;   // worker streams listed in the summary
  static constexpr size_t kMaxOpenStreamLines = 10;  // streams not closed at the end, named in the log
  static constexpr size_t kMaxLogLine = 8192;        // bytes of one log line; a longer one is cut
  static constexpr double kBusyEventS = 0.1;         // a training pass this long writes a busy event
  RosterThread roster_;
  Evaluator evaluator_;
  Checkpointer checkpointer_;
  std::unique_ptr<Pacing> algo_;  // the algorithm, in its pacing
  StatsReporter stats_;           // the pacing's records to learner.csv, events, the log, LearnerStats
  std::string run_dir_;
  // Finished training episodes: how many, and the returns of the last 100.
  struct Returns {
    uint64_t total = 0;
    std::deque<float> recent;
    void add(float episode_return);
    double mean() const;  // NaN before the first
  } returns_;
  IngestCounters last_counters_;       // at the last progress line, for its rates
  uint64_t steps_at_stop_ = 0;         // env steps when a stop rule ended the run (0: still running)
  bool evaluated_in_training_ = true;  // set when training stops, before the final evaluation
  double elapsed_offset_ = 0, t0_ = 0;
  std::string goal_reached_;                    // the stop reason once an evaluation met every stop.eval_goal
  bool last_eval_confirmed_ = true;             // the last report handed to the algorithm (confirmation())
  const std::string* eval_snapshot_ = nullptr;  // while the algorithm reports: the networks asked
};

}  // namespace farm
