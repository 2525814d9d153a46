// The line between the farm and an algorithm.
//
// The farm side (learner/farm_service.*) owns the bus: it takes the workers' batches through
// ingest and accounts them, keeps the roster, publishes the experiment and the weights it is
// handed, asks workers for evaluations and hands their answers back, writes checkpoints, the best
// policy, progress lines and the summary, and applies the stop rules. An algorithm takes accepted data, trains, exports
// weights and saves/loads itself; it reaches the workers only through the Farm below. SAC and DQN share one
// replay-buffer driver (off_policy_algorithm.cpp); PPO has its own (ppo_algorithm.cpp). A new
// algorithm implements Algorithm and adds one line to registry.cpp.
#pragma once

#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "batch.h"
#include "farm_config.pb.h"
#include "mlp.h"

namespace farm {

// printf-style formatting of one number.
std::string fmt(const char* f, double v);

struct FarmFigures;
// " | evals asked N answered M lost K invalid I" for a progress line.
std::string eval_counts(const FarmFigures& f);
// The summary's "best eval return  141.5" line ("best eval share (min) 0.8712" by eval.best_metric).
std::string best_eval_line(const FarmFigures& f);

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

// An evaluation an algorithm asks for (Farm::ask_evaluation); handed back with its report
// (Algorithm::evaluated), which may come many training passes later.
struct EvalAsk {
  std::string label;     // the log line's first word: "eval" while training, "final" at the end
  int episodes = 0;      // deterministic episodes asked
  uint64_t version = 0;  // the policy version evaluated
  int64_t updates = 0;   // the algorithm's updates when it asked
  double elapsed = 0;    // seconds of training when it asked
  std::string progress;  // where training was when it asked, for the log line ("120 updates", "5 fits")
};

// The farm's own figures, for an algorithm's progress line, fit line and summary.
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
  // At a progress line only: env steps/s and mean policy lag since the last line, and the live
  // workers that wait on the learner (" (2 throttled)"; "" when none).
  double in_rate = 0, lag = 0;
  std::string waiting_note;
};

// The algorithm's figures in the LearnerStats a progress line publishes.
struct AlgorithmStats {
  int64_t updates = 0;
  double updates_per_second = 0, buffer_fill = 0, critic_loss = 0, actor_loss = 0, eval_return = NAN;
};

// What the farm offers an algorithm.
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
  // evaluated. Training goes on: the report comes through Algorithm::evaluated when the answer
  // arrives. false (said in the log) when it is not asked: a training evaluation ("eval") is still
  // out. A final evaluation ("final") is always asked; the farm waits for it before the summary.
  virtual bool ask_evaluation(const PolicyParams& policy, const EvalAsk& ask) = 0;
  // Each evaluation's report goes through here (from Algorithm::evaluated): a new best (by its mean
  // return, or by eval.best_metric) is kept in <run dir>/best, as the networks were when that
  // version was asked.
  virtual void record_evaluation(const EvalReport& report, uint64_t version, int64_t updates, double elapsed) = 0;
  virtual void log(const std::string& line) const = 0;
  // One row of <run dir>/learner.csv, without the newline (columns: Algorithm::csv_header).
  virtual void csv_row(const std::string& row) = 0;
};

class Algorithm {
 public:
  virtual ~Algorithm() = default;
  // The algorithm's part of the start line ("SAC 3-256-256-2 relu actor").
  virtual std::string describe() const = 0;
  virtual std::string csv_header() const = 0;  // without the trailing newline
  // The policy version batches are checked against, and the one a checkpoint records.
  virtual uint64_t version() const = 0;
  virtual int64_t updates() const = 0;
  // The mean return of the latest evaluation (NaN before the first), for the stop target.
  virtual double last_eval() const = 0;

  // Before the experiment is published and the run's clock starts: what makes the first updates as
  // fast as the later ones (PPO on a GPU: ppo_warm_up).
  virtual void warm_up(Farm&) {}
  // After the experiment is published, before the first batch.
  virtual void start(Farm&) {}
  // One batch that ingest accepted; false when the algorithm does not use it (counted by the
  // algorithm, e.g. stale beyond its lag window): its episodes then do not count either.
  virtual bool take(const Batch& batch) = 0;
  // One pass of the loop after the farm took what arrived (got_data: whether anything did): train
  // when due, publish, evaluate. Returns how long the farm may wait for data before the next pass.
  virtual double train(Farm& farm, bool got_data) = 0;
  // Re-sends the current version with a quota of one batch, so every worker that already sent on
  // it waits: at an interrupted stop (nothing is on its way at the checkpoint) and at a stop rule
  // (no training data is made while the final evaluation runs).
  virtual void hold_workers(Farm& farm) = 0;
  // The periodic progress: a log line, and for algorithms that write per period, a CSV row.
  virtual void progress(Farm& farm, const FarmFigures& f, double elapsed, AlgorithmStats* stats) = 0;
  // The algorithm's own end (PPO's run length); "" while it goes on.
  virtual std::string stop_reason() const { return ""; }
  // Asks the final evaluation (Farm::ask_evaluation, label "final").
  virtual void final_evaluation(Farm& farm, double elapsed) = 0;
  // The report of an evaluation this algorithm asked for, when a worker's answer arrives: the log
  // line, the CSV columns, the stop target's last_eval and Farm::record_evaluation.
  virtual void evaluated(Farm& farm, const EvalAsk& ask, const EvalReport& report) = 0;
  // An evaluation it asked for that no worker answered (lost twice, or still out when the run
  // ended): nothing to report.
  virtual void not_evaluated(Farm&, const EvalAsk&) {}
  // The summary's lines between the farm's head and its worker lines.
  virtual std::string summary(const FarmFigures& f, double elapsed) const = 0;

  // The networks, in their sub-folder of dir (the layout of <run dir>/best and of a checkpoint).
  virtual void save_networks(const std::string& dir) const = 0;
  // The policy of those networks in the workers' layout, numbered version(): the checkpoint's
  // policy file (common/policy_file.h), which the programs that run a trained policy read.
  virtual PolicyParams policy() const = 0;
  // Everything a checkpoint holds of the algorithm (networks, and a replay buffer where there is
  // one), and what it adds to the manifest (random state, run counters).
  virtual void save(const std::string& dir) const { save_networks(dir); }
  virtual void to_manifest(config::CheckpointManifest& m) const = 0;
  virtual void load(const std::string& dir) = 0;
  // After load and the farm's counters: versions and schedules go on. Returns the rest of the log
  // line "resumed from DIR ...".
  virtual std::string resumed(const config::CheckpointManifest& m, uint64_t env_steps) = 0;

  // Policy versions skipped on --resume, for every algorithm: more than a learner publishes between
  // two checkpoints, so the resumed learner's versions are numbers no worker holds yet (a worker
  // holding the same number would keep the crashed learner's weights).
  static constexpr uint64_t kResumeVersionSkip = 100000;
};

}  // namespace farm
