// The run's saved policies (checkpointer.h).
#include "checkpointer.h"

#include <algorithm>
#include <filesystem>
#include <stdexcept>

#include "checkpoint.h"
#include "meter.h"

namespace farm {

namespace fs = std::filesystem;

Checkpointer::Checkpointer(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec,
                           const std::string& run_dir, EventLog& events, Log log)
    : cfg_(cfg),
      spec_(spec),
      events_(events),
      log_(std::move(log)),
      checkpoint_dir_((fs::path(run_dir) / "checkpoint").string()),
      best_dir_((fs::path(run_dir) / "best").string()) {}

std::string Checkpointer::measure() const {
  const auto& e = cfg_.eval();
  return e.best_metric().empty() ? std::string("return") : e.best_metric() + " (" + e.best_reduce() + ")";
}

double Checkpointer::score(const EvalReport& r) const {
  if (r.episodes <= 0) return NAN;
  const auto& e = cfg_.eval();
  if (e.best_metric().empty()) return r.mean;
  const auto& names = spec_.metric_names;
  const size_t k = size_t(std::find(names.begin(), names.end(), e.best_metric()) - names.begin());
  const auto& values = e.best_reduce() == "min" ? r.metrics_min : r.metrics;
  return k < values.size() ? values[k] : NAN;  // the config check named a metric of the task
}

bool Checkpointer::save(const Manifest& manifest, const Parts& parts) {
  try {
    const config::CheckpointManifest m = manifest();
    const double t = now_seconds();
    write_checkpoint(checkpoint_dir_, m, parts);
    log_("checkpoint " + checkpoint_dir_ + " (" + fmt("%.2f", now_seconds() - t) + " s)");
    events_.write("checkpoint", {{"dir", checkpoint_dir_},
                                 {"ok", true},
                                 {"seconds", now_seconds() - t},
                                 {"policy_version", m.policy_version()},
                                 {"updates", m.updates()}});
    return true;
  } catch (const std::exception& e) {
    ++failed_;
    events_.write("checkpoint", {{"dir", checkpoint_dir_}, {"ok", false}, {"error", e.what()}});
    log_(std::string("checkpoint failed: ") + e.what() + "; the last good checkpoint" +
         (checkpoint_exists(checkpoint_dir_) ? " (" + usable_checkpoint(checkpoint_dir_) + ")"
                                             : std::string(" (none yet)")) +
         " is kept, training goes on, next try in " + fmt("%.0f", cfg_.checkpoint_every_seconds()) + " s");
    return false;
  }
}

void Checkpointer::offer(const EvalReport& report, uint64_t version, int64_t updates, double elapsed,
                         const std::string* snapshot, const Manifest& manifest) {
  if (!report.confirmed) return;  // under security: a second worker did not agree (evaluator.h)
  const double s = score(report);
  const std::string what = measure() + " " + fmt(cfg_.eval().best_metric().empty() ? "%.1f" : "%.4f", s);
  // A named measure is not in the evaluation's own line (that gives means): each one is logged, so
  // its curve along the run can be read from the log.
  if (!cfg_.eval().best_metric().empty() && !std::isnan(s))
    log_("evaluation of policy v" + std::to_string(version) + " at " + fmt("%.1f", elapsed) + " s: " + what +
         (std::isnan(best_) ? "" : ", best so far " + fmt("%.4f", best_)));
  if (std::isnan(s)) return;
  // The kept best compares like with like: an evaluation of fewer episodes than the training's
  // (a final one of eval.final_episodes < eval.episodes) is noisier, and the highest of many noisy
  // scores favours the noisiest. Its policy stays in RUN/checkpoint, measured in the summary.
  // Without any best yet (no training evaluation came back) it is kept: something beats nothing,
  // and then it is no bar for an evaluation of the training's size, which replaces it whatever
  // its score (after a resume, too: the manifest records the best's episodes).
  const int64_t needed = cfg_.eval().episodes();
  const bool full = report.episodes >= needed;
  const bool small_bar = !std::isnan(best_) && best_episodes_ >= 0 && best_episodes_ < needed;
  if (!(full && small_bar) && s <= best_) return;
  if (!full && !std::isnan(best_)) {
    log_("evaluation of policy v" + std::to_string(version) + " (" + what + ", " + std::to_string(report.episodes) +
         " episodes) is not kept as the best: it has fewer episodes than the training's evaluations (" +
         std::to_string(cfg_.eval().episodes()) + ")");
    events_.write("best_not_kept", {{"measure", measure()},
                                    {"score", s},
                                    {"policy_version", version},
                                    {"episodes", report.episodes},
                                    {"episodes_needed", cfg_.eval().episodes()}});
    return;
  }
  const double previous_best = best_;
  const int64_t previous_episodes = best_episodes_;
  best_ = s;
  best_episodes_ = report.episodes;
  const double t = now_seconds();
  try {
    // The networks as they were when this version was asked (training went on meanwhile).
    if (!snapshot || snapshot->empty())
      throw std::runtime_error("the networks of policy v" + std::to_string(version) +
                               " were not kept when it was asked");
    const std::string from = *snapshot;
    write_checkpoint(best_dir_, manifest(), [&from](const std::string& tmp) {
      fs::copy(from, tmp, fs::copy_options::recursive | fs::copy_options::overwrite_existing);
    });
  } catch (const std::exception& e) {
    best_ = previous_best;  // the folder still holds the previous best: it stays the bar
    best_episodes_ = previous_episodes;
    log_(std::string("best evaluation so far (") + what + ") not kept: " + e.what() + "; training goes on");
    return;
  }
  log_("best evaluation so far (" + what + ", policy v" + std::to_string(version) + "): kept in " + best_dir_ + " (" +
       fmt("%.2f", now_seconds() - t) + " s)" +
       (full && small_bar && s <= previous_best
            ? "; it replaces a best of " + std::to_string(previous_episodes) + " episodes at " +
                  fmt("%.4f", previous_best) + ", fewer than the training's " + std::to_string(needed)
            : std::string()));
  events_.write("best", {{"measure", measure()},
                         {"score", s},
                         {"policy_version", version},
                         {"updates", updates},
                         {"episodes", report.episodes},
                         {"dir", best_dir_}});
}

void Checkpointer::resume(const config::CheckpointManifest& m) {
  // A best kept by another measure (the config's eval.best_metric changed) is no bar for this one.
  const auto same_measure = [this](const config::CheckpointManifest& k) {
    return (k.has_best_eval_measure() ? k.best_eval_measure() : std::string("return")) == measure();
  };
  // Where a manifest does not say how many episodes its best had (an older learner's), -1: the
  // best is held as the bar whatever evaluation comes.
  const auto episodes = [](const config::CheckpointManifest& k) {
    return k.has_best_eval_episodes() ? k.best_eval_episodes() : int64_t(-1);
  };
  if (m.has_best_eval_return() && same_measure(m)) {
    best_ = m.best_eval_return();
    best_episodes_ = episodes(m);
  }
  // A best policy kept after the checkpoint (the learner stopped before the next one) stays the
  // one to beat: it is not overwritten by a weaker one after the resume.
  if (checkpoint_exists(best_dir_)) {
    const config::CheckpointManifest b = read_manifest(best_dir_, cfg_.experiment_id());
    if (b.has_best_eval_return() && !same_measure(b))
      log_("the best kept in " + best_dir_ + " was by " +
           (b.has_best_eval_measure() ? b.best_eval_measure() : std::string("return")) + ", this run keeps by " +
           measure() + ": the next evaluation replaces it");
    else if (b.has_best_eval_return() && (std::isnan(best_) || b.best_eval_return() > best_)) {
      best_ = b.best_eval_return();
      best_episodes_ = episodes(b);
    }
  }
}

}  // namespace farm
