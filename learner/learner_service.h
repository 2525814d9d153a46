// What every learner service does, whatever it trains with: publish the experiment, take and
// account the workers' batches, hear their heartbeats, run the main loop (progress lines,
// checkpoints, stop conditions, Ctrl-C), resume from a checkpoint, close the workers' streams at
// the end and write the summary. The off-policy learner (SAC, DQN) and the PPO learner fill in
// how they use the data, train, evaluate and checkpoint their networks.
#pragma once

#include <atomic>
#include <cmath>
#include <cstdint>
#include <deque>
#include <fstream>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "dds.h"
#include "farm_config.pb.h"
#include "ingest.h"
#include "spec_publisher.h"
#include "task.h"
#include "worker_roster.h"

namespace farm {

struct LearnerRunOptions {
  farm::dds::BusOptions bus;
  bool resume = false;
  std::string run_dir;  // default <run_root>/<experiment_id>
};

// printf-style formatting of one number.
std::string fmt(const char* f, double v);

class LearnerService {
 public:
  // Policy versions skipped on --resume, for every algorithm: more than a learner publishes between
  // two checkpoints, so the resumed learner's versions are numbers no worker holds yet (a worker
  // holding the same number would keep the crashed learner's weights).
  static constexpr uint64_t kResumeVersionSkip = 100000;

  virtual ~LearnerService() = default;
  // Runs the experiment to its end; returns the process exit code (130 when interrupted).
  int run();

 protected:
  LearnerService(const LearnerRunOptions& o, const config::ExperimentConfig& cfg, const std::atomic<bool>& interrupted);

  // --- what the algorithm fills in ---
  // The algorithm part of the start line ("SAC 64-64 ...").
  virtual std::string describe() const = 0;
  // Before the loop, after the experiment is published (the off-policy learner publishes weights).
  virtual void on_start() {}
  // One pass of the loop: take batches and heartbeats, train, publish.
  virtual void work(double t0) = 0;
  // The periodic progress line, CSV row and LearnerStats; window: seconds since the last one.
  virtual void progress(double elapsed, double window) = 0;
  virtual std::string should_stop(double elapsed) const = 0;
  virtual size_t drain_batches(size_t max) = 0;
  virtual void checkpoint(double elapsed) = 0;
  // Loads the networks (and buffers) of the checkpoint in ckpt_dir_ and returns its manifest.
  virtual config::CheckpointManifest restore_algorithm() = 0;
  // The rest of a resume, after the shared counters are back: versions, schedules, the log line.
  virtual void resumed(const config::CheckpointManifest& m) = 0;
  virtual std::string csv_header() const = 0;  // without the trailing newline
  // The final evaluation and the summary, at a normal stop.
  virtual void final_evaluation(double elapsed) = 0;
  virtual void write_summary(double elapsed, const std::string& reason) = 0;
  virtual void on_worker_heard() {}
  // Re-sends the current policy version with a quota of one batch: every worker that already sent
  // on it waits (the interrupted learner's stop uses it, so nothing is on its way at the checkpoint).
  virtual void hold_workers() = 0;
  // The algorithm's networks, as its save writes them, into their sub-folder of dir: the layout a
  // checkpoint has, so evaluation programs read <run dir>/best and <run dir>/checkpoint alike.
  virtual void save_networks(const std::string& dir) const = 0;

  // --- shared ---
  void log(const std::string& s) const;
  void drain_status();
  int live_workers() const;
  // Takes batch_ (just read) through the ingest's checks against the given policy version:
  // pending_ and episodes_ hold its transitions and finished episodes; false (and a log line for
  // the first 20) when the batch is refused.
  bool accept_batch(uint64_t version);
  void record_episode(float episode_return);
  // Each evaluation's mean return goes through here: a new best is kept in best_eval_ and its
  // networks are written to <run dir>/best (a checkpoint folder without buffers), so a run that
  // trains past its best policy does not lose it.
  void record_evaluation(double mean_return, uint64_t version, int64_t updates, double elapsed);
  double mean_recent_return() const;
  // Env steps per second and mean policy lag since the last call.
  struct Window {
    double in_rate = 0, lag = 0;
  };
  Window take_window(double window);
  // LearnerStats with the fields every learner fills the same way.
  farm::msg::LearnerStats base_stats(double elapsed, const Window& w) const;
  // The stop limits of the experiment's stop block (target return, time, env steps, updates).
  std::string limit_reached(double elapsed, double last_eval, int64_t updates) const;
  // The manifest fields every checkpoint carries.
  config::CheckpointManifest base_manifest(uint64_t version, int64_t updates, double elapsed) const;
  // Summary lines: the head (experiment, reason, time, env steps) and one line per worker stream.
  std::string summary_head(double elapsed, const std::string& reason) const;
  std::string summary_workers() const;
  // A line for the log and summary when the run ended on an env step or update limit before its
  // first evaluation (a limit that more workers reach sooner); "" otherwise.
  std::string untrained_stop_note(const std::string& reason) const;
  void emit_summary(const std::string& text) const;
  void drain_until_workers_end();
  // checkpoint() that survives a failure (a full disk): logged, the last good checkpoint kept;
  // false when it failed.
  bool try_checkpoint(double elapsed);
  // On Ctrl-C / SIGTERM, before the checkpoint: the batches already on their way.
  void drain_before_interrupted_stop();

  LearnerRunOptions opt_;
  config::ExperimentConfig cfg_;
  const std::atomic<bool>& interrupted_;
  std::shared_ptr<const robots::Task> task_;
  int obs_dim_, act_dim_;
  Ingest ingest_;
  farm::dds::Bus bus_;
  SpecPublisher spec_;
  farm::dds::Writer<farm::msg::PolicyWeights, farm::msg::PolicyWeightsPubSubType> weights_out_;
  farm::dds::Writer<farm::msg::LearnerStats, farm::msg::LearnerStatsPubSubType> stats_out_;
  farm::dds::Reader<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType> batches_in_;
  // Heartbeats are taken on Fast DDS's listener thread as they arrive, with their arrival time, so
  // a long fit or evaluation cannot let them be overwritten in the reader's history (16 deep for
  // all workers together) and live workers be marked dead; the main loop hands them to roster_.
  std::mutex heard_mu_;
  std::deque<std::pair<farm::msg::WorkerStatus, double>> heard_;  // bounded: kMaxHeard
  static constexpr size_t kMaxHeard = 65536;
  farm::dds::Reader<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType> status_in_;
  std::string run_dir_, ckpt_dir_, best_dir_;
  std::ofstream csv_;
  farm::msg::TransitionBatch batch_;
  Transitions pending_;
  std::vector<FinishedEpisode> episodes_;
  std::deque<float> recent_returns_;
  WorkerRoster roster_;
  uint64_t last_steps_ = 0, last_ok_ = 0, episodes_total_ = 0, evals_ = 0;
  bool evaluated_in_training_ = true;  // set when training stops, before the final evaluation
  double last_lag_sum_ = 0, elapsed_offset_ = 0, best_eval_ = NAN;

 private:
  void prepare_run_dir();
  int rejections_logged_ = 0;
};

}  // namespace farm
