// The run's saved policies: RUN/checkpoint, everything a resumed learner needs (written whole or
// not at all, checkpoint.h; a failure, a full disk say, is logged, counted and tried again at the
// next period while the last good checkpoint stays), and RUN/best, the networks of the best
// evaluation so far by the experiment's measure (eval.best_metric, else the mean return), as they
// were when that version was asked. On --resume it takes the bar of the best back.
#pragma once

#include <cmath>
#include <cstdint>
#include <functional>
#include <string>

#include "events.h"
#include "farm_config.pb.h"
#include "pacing.h"
#include "task_spec.h"

namespace farm {

class Checkpointer {
 public:
  using Log = std::function<void(const std::string&)>;
  using Manifest = std::function<config::CheckpointManifest()>;
  using Parts = std::function<void(const std::string& folder)>;
  Checkpointer(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec, const std::string& run_dir,
               EventLog& events, Log log);

  const std::string& checkpoint_dir() const { return checkpoint_dir_; }
  const std::string& best_dir() const { return best_dir_; }
  // What the kept best is the best of: "return", or "<eval.best_metric> (<best_reduce>)".
  std::string measure() const;
  // An evaluation's score by that measure; NaN for one without episodes.
  double score(const EvalReport& r) const;
  // The best score kept so far; NaN before the first.
  double best() const { return best_; }
  // The episodes of the kept best's evaluation; -1 with no best, or one taken back from a
  // manifest that does not say.
  int64_t best_episodes() const { return best_episodes_; }

  // Writes RUN/checkpoint: the manifest `manifest` gives, and what `parts` writes into the folder.
  // false when it failed (logged, an event, counted; the last good checkpoint is kept).
  bool save(const Manifest& manifest, const Parts& parts);
  uint64_t failed() const { return failed_; }

  // The report of an evaluation of policy `version`: a new best by the measure is kept in RUN/best,
  // copied from `snapshot` (the networks as asked) with the manifest `manifest` gives. A report not
  // confirmed (security) keeps nothing, nor does one of fewer episodes than eval.episodes (a smaller
  // final evaluation: its noise would win) once a best is kept; a named measure is logged for
  // every report.
  void offer(const EvalReport& report, uint64_t version, int64_t updates, double elapsed, const std::string* snapshot,
             const Manifest& manifest);

  // On --resume, from the checkpoint's manifest: the best it recorded, or RUN/best's where that one
  // is better (kept after the checkpoint); a best by another measure is no bar.
  void resume(const config::CheckpointManifest& m);

 private:
  const config::ExperimentConfig& cfg_;
  const robots::TaskSpec& spec_;
  EventLog& events_;
  Log log_;
  std::string checkpoint_dir_, best_dir_;
  double best_ = NAN;
  int64_t best_episodes_ = -1;
  uint64_t failed_ = 0;
};

}  // namespace farm
