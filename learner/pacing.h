// The pace of an algorithm against its workers: when it updates, when its weights go out and with
// what quota of batches per worker, when it is evaluated, and what each step reports: statistics
// records (pacing_stats.h) that the runner renders as the progress line, learner.csv, events.jsonl
// and LearnerStats, and the summary. The only part of the learner that reads worker state. Two
// kinds, by the registration's on_policy:
// - replay pacing (replay_pacing.cpp): updates as a samples-per-insert limiter allows
//   (samples_per_insert.h), weights every few updates, evaluations on a timer;
// - round pacing (round_pacing.cpp): a quota of batches per worker for each version, batches older
//   than the lag window counted and dropped, a fit whenever the algorithm has one's data,
//   evaluations every few fits.
// The runner (farm_service.h) owns the bus and everything around; a pacing reaches it through Farm.
#pragma once

#include <cmath>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "algorithm.h"
#include "batch.h"
#include "farm_config.pb.h"
#include "mlp.h"
#include "stats_record.h"
#include "task_spec.h"

namespace farm {

// printf-style formatting of one number.
std::string fmt(const char* f, double v);

// What an evaluation reports: returns, lengths and the task's own metrics.
struct EvalReport {
  int episodes = 0;
  double mean = NAN, min = NAN, max = NAN, mean_length = NAN;
  std::vector<double> metrics;      // means, in the order of TaskSpec::metric_names
  std::vector<double> metrics_min;  // the lowest episode's, in the same order
  // Under DDS Security, whether a second worker's episodes agree with the first's (the learner's
  // confirmation): an unconfirmed report keeps no best and stops nothing.
  bool confirmed = true;
};

// An evaluation a pacing asks for (Farm::ask_evaluation); handed back with its report
// (Pacing::evaluated), which may come many updates later.
struct EvalAsk {
  std::string label;     // the log line's first word: "eval" while training, "final" at the end
  int episodes = 0;      // deterministic episodes asked
  uint64_t version = 0;  // the policy version evaluated
  int64_t updates = 0;   // the algorithm's updates when it asked
  double elapsed = 0;    // seconds of training when it asked
  std::string progress;  // where training was when it asked, for the log line ("120 updates", "5 fits")
};

// The runner's own figures, for a progress line, fit line and summary.
struct FarmFigures {
  uint64_t env_steps = 0, ok = 0, lost = 0, duplicate = 0, invalid = 0;
  uint64_t episodes = 0;                // finished episodes taken so far
  int workers = 0;                      // live workers
  double mean_return = NAN;             // of the last 100 training episodes
  double best_eval = NAN;               // the best evaluation so far (kept in <run dir>/best), by best_measure
  std::string best_measure = "return";  // what best_eval is: "return", or eval.best_metric (best_reduce)
  // Evaluations asked of workers (retries included), answered, lost (unanswered in time, or the
  // worker died) and answers refused as invalid.
  uint64_t evals_asked = 0, evals_answered = 0, evals_lost = 0, evals_invalid = 0;
  // Live workers that wait on the learner: for new weights (throttled), or for room in the batch
  // queue (backpressure).
  int throttled = 0, backpressure = 0;
  // At a progress line only: env steps/s and mean policy lag since the last line.
  double in_rate = 0, lag = 0;
};
// The summary's "best eval return  141.5" line ("best eval share (min) 0.8712" by eval.best_metric).
std::string best_eval_line(const FarmFigures& f);

// What the runner offers a pacing.
class Farm {
 public:
  struct LiveWorker {
    std::string worker_id, state;  // state: "running", "throttled", "backpressure", ...
    uint64_t policy_version = 0;   // the version it runs
    int envs = 0;
  };

  virtual ~Farm() = default;
  // Sends a policy to the workers; batch_quota: how many batches each worker may send on this
  // version before it waits for the next (0: no limit).
  virtual void publish(const PolicyParams& policy, uint32_t batch_quota) = 0;
  virtual std::vector<LiveWorker> live_workers() const = 0;
  // When the first worker was heard (now_seconds() clock); 0 while none has been.
  virtual double first_worker_heard() const = 0;
  virtual FarmFigures figures() const = 0;
  // Env steps taken so far: figures().env_steps without the rest (read on every update).
  virtual uint64_t env_steps() const = 0;
  // Seconds of training so far (a resumed run counts on from its checkpoint).
  virtual double elapsed() const = 0;
  // Asks a live worker for ask.episodes deterministic episodes of `policy` (version ask.version)
  // and keeps the algorithm's networks as they are now, so that a new best is saved as the version
  // evaluated. Training goes on: the report comes through Pacing::evaluated when the answer
  // arrives. false (said in the log) when it is not asked: a training evaluation ("eval") is still
  // out. A final evaluation ("final") is always asked; the runner waits for it before the summary.
  virtual bool ask_evaluation(const PolicyParams& policy, const EvalAsk& ask) = 0;
  // Each evaluation's report goes through here (from Pacing::evaluated): a new best (by its mean
  // return, or by eval.best_metric) is kept in <run dir>/best, as the networks were when that
  // version was asked.
  virtual void record_evaluation(const EvalReport& report, uint64_t version, int64_t updates, double elapsed) = 0;
  virtual void log(const std::string& line) const = 0;
  // A record of the pacing's row_schema(): one row of <run dir>/learner.csv and its progress event.
  virtual void row(const StatsRecord& r) = 0;
};

class Pacing {
 public:
  Pacing(std::unique_ptr<Algorithm> algo, const config::ExperimentConfig& cfg, const robots::TaskSpec& spec);
  virtual ~Pacing() = default;

  std::string describe() const { return algo_->describe(); }
  // The fields of learner.csv's rows and their progress events (Farm::row).
  virtual const StatsSchema& row_schema() const = 0;
  std::string csv_header() const { return row_schema().csv_header(); }
  // The policy version batches are checked against, and the one a checkpoint records.
  virtual uint64_t version() const = 0;
  int64_t updates() const { return algo_->updates(); }
  // The mean return of the latest evaluation (NaN before the first), for the stop target.
  virtual double last_eval() const = 0;

  // Before the experiment is published and the run's clock starts.
  void warm_up(Farm& farm);
  // After the experiment is published, before the first batch.
  virtual void start(Farm&) {}
  // One batch that ingest accepted; false when it is not used (stale beyond the lag window, or
  // after the algorithm's run ended): its episodes then do not count either.
  virtual bool take(const Batch& batch) = 0;
  // One pass of the loop after the runner took what arrived (got_data: whether anything did):
  // update when due, publish, evaluate. Returns how long the runner may wait for data.
  virtual double train(Farm& farm, bool got_data) = 0;
  // Re-sends the current version with a quota of one batch, so every worker that already sent on
  // it waits: at an interrupted stop and at a stop rule.
  virtual void hold_workers(Farm& farm) = 0;
  // The periodic progress: the record the runner logs as the progress line and publishes as
  // LearnerStats; where rows are written per period, the same record is a row (Farm::row).
  virtual StatsRecord progress(Farm& farm, const FarmFigures& f, double elapsed) = 0;
  // The algorithm's own end (PPO's run length); "" while it goes on.
  virtual std::string stop_reason() const { return ""; }
  // Asks the final evaluation (Farm::ask_evaluation, label "final").
  virtual void final_evaluation(Farm& farm, double elapsed) = 0;
  // The report of an evaluation this pacing asked for: the log line, the CSV columns, the stop
  // target's last_eval and Farm::record_evaluation.
  virtual void evaluated(Farm& farm, const EvalAsk& ask, const EvalReport& report) = 0;
  // An evaluation it asked for that no worker answered: nothing to report.
  virtual void not_evaluated(Farm&, const EvalAsk&) {}
  // The summary's lines between the runner's head and its worker lines.
  virtual std::string summary(const FarmFigures& f, double elapsed) const = 0;
  // The pacing's own figures of those lines for the summary event, as data (the round pacing's
  // stale batches, unused steps and lags of what it fitted); none by default.
  virtual nlohmann::json summary_fields() const { return nlohmann::json::object(); }

  // What leaves the learner, each after the updates still running are checked (settle()): the
  // networks (RUN/best's layout), the policy of version(), a checkpoint's parts.
  void save_networks(const std::string& dir) const;
  PolicyParams policy() const;
  void save(const std::string& dir) const;
  void to_manifest(config::CheckpointManifest& m) const {
    algo_->to_manifest(m);
    counts_to_manifest(m);
  }
  void load(const std::string& dir) { algo_->load(dir); }
  // After load and the runner's counters: versions go on past any the crashed learner published.
  // Returns the rest of the log line "resumed from DIR ...".
  std::string resumed(const config::CheckpointManifest& m, uint64_t env_steps);

  // Policy versions skipped on --resume: more than a learner publishes between two checkpoints, so
  // the resumed learner's versions are numbers no worker holds yet (a worker holding the same
  // number would keep the crashed learner's weights).
  static constexpr uint64_t kResumeVersionSkip = 100000;

 protected:
  // The pacing's own accounts of the run (steps counted stale, fitted), kept in a checkpoint and
  // restored on --resume, so a resumed run's summary covers the whole run.
  virtual void counts_to_manifest(config::CheckpointManifest&) const {}
  virtual void counts_from_manifest(const config::CheckpointManifest&) {}

  // The figures of finished updates: a figure that is not finite stops the run, and stays found:
  // whoever catches the error (a periodic checkpoint logs its failure and goes on), every later
  // train(), publish, evaluation and checkpoint throws it again.
  void check(const std::vector<UpdateFigures>& figures) const;
  // Waits for the updates still running and checks their figures: before any weights leave.
  void settle() const;
  // A figure of the latest update, 0 where the algorithm has no such figure (the CSV's columns).
  double latest(const std::string& name) const;

  std::unique_ptr<Algorithm> algo_;
  const config::ExperimentConfig cfg_;
  const robots::TaskSpec spec_;
  mutable UpdateFigures last_;  // the latest update checked
  mutable std::string diverged_;
  // The policy version counter: the replay pacing's next to publish, the round pacing's current;
  // a resumed run goes on past any version the crashed learner published.
  uint64_t version_ = 0;
};

// The pacing of cfg.algorithm() (its registration's on_policy) around the algorithm.
std::unique_ptr<Pacing> make_pacing(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec);
std::unique_ptr<Pacing> make_replay_pacing(std::unique_ptr<Algorithm> algo, const config::ExperimentConfig& cfg,
                                           const robots::TaskSpec& spec);
std::unique_ptr<Pacing> make_round_pacing(std::unique_ptr<Algorithm> algo, const config::ExperimentConfig& cfg,
                                          const robots::TaskSpec& spec);

// Updates the replay pacing runs between two looks at the bus, as one Algorithm::update group.
inline constexpr int kUpdatesPerGroup = 8;

// sac.max_step_scale's rule, from the scale in use and r, the updates the data allowed over the
// last window per update made (max_updates_per_step x env steps received / updates made): up to
// the power of 2 nearest r on a log scale (s where r is s / sqrt(2) or more), down to it once r
// falls below 0.8 s / sqrt(2) for the scale s in use (the margin keeps a scale from flapping on a
// ratio near a band's edge), never past `most` nor below 1.
int next_step_scale(int current, double r, int most);

}  // namespace farm
