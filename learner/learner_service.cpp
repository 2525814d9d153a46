#include "learner_service.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <sstream>
#include <stdexcept>

#include "checkpoint.h"
#include "config.h"
#include "meter.h"

namespace farm {

namespace fs = std::filesystem;

std::string fmt(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

LearnerService::LearnerService(const LearnerRunOptions& o, const config::ExperimentConfig& cfg,
                               const std::atomic<bool>& interrupted)
    : opt_(o),
      cfg_(cfg),
      interrupted_(interrupted),
      task_(robots::make_task(cfg_.task())),
      obs_dim_(task_->spec().obs_dim),
      act_dim_(task_->spec().act_dim),
      ingest_(cfg_.experiment_id(), obs_dim_, act_dim_),
      bus_(o.bus, "farm-learner " + cfg_.experiment_id()),
      spec_(bus_, cfg_, obs_dim_, act_dim_),
      weights_out_(bus_, farm::dds::kWeightsTopic, "latest_writer"),
      stats_out_(bus_, farm::dds::kLearnerStatsTopic, "status_writer"),
      batches_in_(bus_, farm::dds::kBatchTopic, "batch_reader"),
      status_in_(bus_, farm::dds::kWorkerStatusTopic, "status_reader",
                 [this](eprosima::fastdds::dds::DataReader* r) {
                   farm::msg::WorkerStatus s;
                   while (decltype(status_in_)::take_from(r, s)) {
                     std::lock_guard<std::mutex> lk(heard_mu_);
                     if (heard_.size() >= kMaxHeard) heard_.pop_front();
                     heard_.emplace_back(s, now_seconds());
                   }
                 }),
      roster_(cfg_.worker_timeout_seconds(), [this](const std::string& m) { log(m); }) {
  run_dir_ = opt_.run_dir.empty() ? (fs::path(cfg_.run_root()) / cfg_.experiment_id()).string() : opt_.run_dir;
  ckpt_dir_ = (fs::path(run_dir_) / "checkpoint").string();
  best_dir_ = (fs::path(run_dir_) / "best").string();
  ingest_.set_num_actions(task_->spec().num_actions);
}

int LearnerService::run() {
  prepare_run_dir();
  spec_.publish(false);
  on_start();
  log("experiment '" + cfg_.experiment_id() + "': task " + cfg_.task().name() + " (obs " + std::to_string(obs_dim_) +
      ", act " + std::to_string(act_dim_) + "), " + describe() + ", DDS domain " + std::to_string(bus_.domain()) +
      ", run dir " + run_dir_ + (bus_.security_dir().empty() ? "" : ", DDS Security from " + bus_.security_dir()));
  log("waiting for workers: start them with `farm-worker --domain " + std::to_string(bus_.domain()) + "`");

  const double t0 = now_seconds() - elapsed_offset_;
  double last_log = now_seconds(), last_ckpt = now_seconds();
  std::string stop_reason;
  while (stop_reason.empty()) {
    if (interrupted_) { stop_reason = "interrupted"; break; }
    work(t0);
    const double now = now_seconds();
    if (now - last_log >= cfg_.log_every_seconds()) {
      progress(now - t0, now - last_log);
      last_log = now;
    }
    spec_.republish_if_due(now);
    if (now - last_ckpt >= cfg_.checkpoint_every_seconds()) {
      try_checkpoint(now - t0);  // a failure is logged and tried again next period
      last_ckpt = now_seconds();
    }
    stop_reason = should_stop(now - t0);
  }
  const double elapsed = now_seconds() - t0;
  log("stopping: " + stop_reason);
  if (stop_reason == "interrupted") {
    // Workers stay and wait: a resumed learner picks them up again. What the reader already
    // acknowledged goes into the checkpoint first, or the resumed learner counts it lost.
    drain_before_interrupted_stop();
    if (!try_checkpoint(elapsed)) return 1;
    log("checkpoint written; resume with --resume");
    return 130;
  }
  // A resumed run counts the evaluations before its checkpoint through the best return it kept.
  evaluated_in_training_ = evals_ > 0 || !std::isnan(best_eval_);
  if (const std::string n = untrained_stop_note(stop_reason); !n.empty()) log(n);
  final_evaluation(elapsed);
  spec_.publish(true);
  drain_until_workers_end();
  const bool saved = try_checkpoint(elapsed);
  write_summary(elapsed, stop_reason);
  return saved ? 0 : 1;
}

bool LearnerService::try_checkpoint(double elapsed) {
  try {
    checkpoint(elapsed);
    return true;
  } catch (const std::exception& e) {
    log(std::string("checkpoint failed: ") + e.what() + "; the last good checkpoint" +
        (checkpoint_exists(ckpt_dir_) ? " (" + usable_checkpoint(ckpt_dir_) + ")" : std::string(" (none yet)")) +
        " is kept, training goes on, next try in " + fmt("%.0f", cfg_.checkpoint_every_seconds()) + " s");
    return false;
  }
}

void LearnerService::log(const std::string& s) const {
  std::printf("[learner] %s\n", s.c_str());
  std::fflush(stdout);
}

void LearnerService::prepare_run_dir() {
  if (opt_.resume) {
    if (!checkpoint_exists(ckpt_dir_)) throw std::runtime_error("--resume: no checkpoint in " + ckpt_dir_);
    const config::CheckpointManifest m = restore_algorithm();
    elapsed_offset_ = m.elapsed_seconds();
    best_eval_ = m.has_best_eval_return() ? m.best_eval_return() : best_eval_;
    // A best policy kept after the checkpoint (the learner stopped before the next one) stays the
    // one to beat: it is not overwritten by a weaker one after the resume.
    if (checkpoint_exists(best_dir_)) {
      const config::CheckpointManifest b = read_manifest(best_dir_, cfg_.experiment_id());
      if (b.has_best_eval_return() && (std::isnan(best_eval_) || b.best_eval_return() > best_eval_))
        best_eval_ = b.best_eval_return();
    }
    episodes_total_ = m.episodes();
    accounts_from_manifest(m, ingest_);
    // The first progress line's rates count from the restored counters, not from zero.
    last_steps_ = ingest_.counters().env_steps;
    last_ok_ = ingest_.counters().ok;
    last_lag_sum_ = ingest_.counters().lag_sum;
    resumed(m);
  } else if (const std::string aside = move_run_dir_aside(run_dir_); !aside.empty()) {
    log("previous run moved to " + aside + " (use --resume to continue a run instead)");
  }
  fs::create_directories(run_dir_);
  const bool new_csv = !fs::exists(fs::path(run_dir_) / "learner.csv");
  csv_.open(fs::path(run_dir_) / "learner.csv", std::ios::app);
  if (!csv_) throw std::runtime_error("cannot write " + run_dir_ + "/learner.csv");
  if (new_csv) csv_ << csv_header() << '\n';
}

void LearnerService::drain_status() {
  std::deque<std::pair<farm::msg::WorkerStatus, double>> got;
  {
    std::lock_guard<std::mutex> lk(heard_mu_);
    got.swap(heard_);
  }
  for (const auto& [s, when] : got) {
    on_worker_heard();
    roster_.heard(s, when);
  }
  roster_.check(now_seconds());
}

int LearnerService::live_workers() const { return roster_.live_count(now_seconds()); }

bool LearnerService::accept_batch(uint64_t version) {
  pending_.clear();
  episodes_.clear();
  const std::string why = ingest_.accept(batch_, version, now_seconds(), pending_, episodes_);
  if (why.empty()) return true;
  if (++rejections_logged_ <= 20)
    log("rejected batch " + std::to_string(batch_.sequence_number()) + " from " + batch_.worker_id() + ": " + why);
  return false;
}

void LearnerService::record_episode(float episode_return) {
  recent_returns_.push_back(episode_return);
  if (recent_returns_.size() > 100) recent_returns_.pop_front();
  ++episodes_total_;
}

void LearnerService::record_evaluation(double mean_return, uint64_t version, int64_t updates, double elapsed) {
  if (std::isnan(mean_return) || mean_return <= best_eval_) return;
  const double previous_best = best_eval_;
  best_eval_ = mean_return;
  const double t = now_seconds();
  try {
    write_checkpoint(best_dir_, base_manifest(version, updates, elapsed),
                     [this](const std::string& tmp) { save_networks(tmp); });
  } catch (const std::exception& e) {
    best_eval_ = previous_best;  // the folder still holds the previous best: it stays the bar
    log(std::string("best evaluation so far (") + fmt("%.1f", mean_return) + ") not kept: " + e.what() +
        "; training goes on");
    return;
  }
  log("best evaluation so far (" + fmt("%.1f", mean_return) + ", policy v" + std::to_string(version) + "): kept in " +
      best_dir_ + " (" + fmt("%.2f", now_seconds() - t) + " s)");
}

double LearnerService::mean_recent_return() const {
  if (recent_returns_.empty()) return NAN;
  double s = 0;
  for (float x : recent_returns_) s += x;
  return s / double(recent_returns_.size());
}

LearnerService::Window LearnerService::take_window(double window) {
  const auto& c = ingest_.counters();
  Window w;
  w.in_rate = double(c.env_steps - last_steps_) / window;
  w.lag = c.ok > last_ok_ ? (c.lag_sum - last_lag_sum_) / double(c.ok - last_ok_) : 0.0;
  last_steps_ = c.env_steps;
  last_ok_ = c.ok;
  last_lag_sum_ = c.lag_sum;
  return w;
}

farm::msg::LearnerStats LearnerService::base_stats(double elapsed, const Window& w) const {
  const auto& c = ingest_.counters();
  farm::msg::LearnerStats st;
  st.experiment_id(cfg_.experiment_id());
  st.elapsed_seconds(elapsed);
  st.env_steps(c.env_steps);
  st.env_steps_per_second(w.in_rate);
  st.policy_lag(w.lag);
  st.mean_return(mean_recent_return());
  st.batches_ok(c.ok);
  st.batches_lost(c.lost);
  st.batches_duplicate(c.duplicate);
  st.batches_invalid(c.invalid);
  st.workers(live_workers());
  return st;
}

std::string LearnerService::limit_reached(double elapsed, double last_eval, int64_t updates) const {
  const auto& s = cfg_.stop();
  if (!std::isnan(s.target_eval_return()) && !std::isnan(last_eval) && last_eval >= s.target_eval_return())
    return "evaluation return " + fmt("%.1f", last_eval) + " reached the target " + fmt("%.1f", s.target_eval_return());
  if (s.max_seconds() > 0 && elapsed >= s.max_seconds()) return "time limit " + fmt("%.0f", s.max_seconds()) + " s";
  if (s.max_env_steps() > 0 && int64_t(ingest_.counters().env_steps) >= s.max_env_steps())
    return "env step limit " + std::to_string(s.max_env_steps());
  if (s.max_updates() > 0 && updates >= s.max_updates()) return "update limit " + std::to_string(s.max_updates());
  return "";
}

config::CheckpointManifest LearnerService::base_manifest(uint64_t version, int64_t updates, double elapsed) const {
  config::CheckpointManifest m;
  m.set_experiment_id(cfg_.experiment_id());
  m.set_policy_version(version);
  m.set_updates(updates);
  m.set_elapsed_seconds(elapsed);
  if (!std::isnan(best_eval_)) m.set_best_eval_return(best_eval_);
  m.set_config_text(config_to_text(cfg_));
  m.set_episodes(episodes_total_);
  accounts_to_manifest(ingest_, m);
  return m;
}

std::string LearnerService::summary_head(double elapsed, const std::string& reason) const {
  const auto& c = ingest_.counters();
  std::ostringstream o;
  o << "experiment        " << cfg_.experiment_id() << "\n"
    << "stopped because   " << reason << "\n"
    << "wall time         " << fmt("%.1f", elapsed) << " s\n"
    << "env steps         " << c.env_steps << " (" << fmt("%.0f", c.env_steps / std::max(elapsed, 1e-9)) << " steps/s)\n";
  if (const std::string n = untrained_stop_note(reason); !n.empty()) o << "note              " << n << "\n";
  return o.str();
}

std::string LearnerService::untrained_stop_note(const std::string& reason) const {
  const bool step_limit = reason.rfind("env step limit", 0) == 0 || reason.rfind("update limit", 0) == 0;
  if (!step_limit || evaluated_in_training_) return "";
  return "the run stopped on its " + reason.substr(0, reason.find(" limit")) +
         " limit before its first evaluation (eval.every_seconds " + fmt("%g", cfg_.eval().every_seconds()) +
         "): its policy was never evaluated while it trained, and more workers reach a step limit sooner; "
         "stop on time (stop.max_seconds) or on a target instead";
}

std::string LearnerService::summary_workers() const {
  std::ostringstream o;
  for (auto& [k, w] : ingest_.workers()) {
    o << "worker            " << w.worker_id << " session " << w.session << ": received " << w.received
      << " of sequence 0.." << (w.next_sequence ? w.next_sequence - 1 : 0) << ", lost " << w.lost << ", duplicate "
      << w.duplicates << ", invalid " << w.invalid << (w.ended ? ", stream closed" : ", stream open") << "\n";
  }
  return o.str();
}

void LearnerService::emit_summary(const std::string& text) const {
  std::printf("\n===== summary =====\n%s===================\n", text.c_str());
  std::ofstream(fs::path(run_dir_) / "summary.txt") << text;
  log("summary written to " + run_dir_ + "/summary.txt");
}

// The workers are told to hold (the current version re-sent with a quota of one batch; no new
// version follows), so each sends at most one more batch and then waits: take batches until none
// has come for 0.5 s and no live worker says it is running (or none for 3 s; 15 s at most).
void LearnerService::drain_before_interrupted_stop() {
  hold_workers();
  const double t0 = now_seconds(), t_end = t0 + 15.0;
  double last = t0;
  size_t taken = 0;
  while (now_seconds() < t_end) {
    const size_t got = drain_batches(1024);
    drain_status();
    const double now = now_seconds();
    if (got > 0) {
      taken += got;
      last = now;
      continue;
    }
    bool running = false;
    for (const auto& [k, v] : roster_.views()) running = running || (roster_.live(v, now) && v.last.state() == "running");
    if (now - last >= 3.0 || (now - last >= 0.5 && !running)) break;
    batches_in_.wait(0.05);
  }
  log("took the " + std::to_string(taken) + " batches in flight (" + fmt("%.1f", now_seconds() - t0) + " s)");
}

// After announcing the end, every batch still in flight is taken and accounted, so the summary
// can say exactly what was sent and what arrived.
void LearnerService::drain_until_workers_end() {
  const double t_end = now_seconds() + 15.0;
  while (now_seconds() < t_end) {
    drain_batches(1024);
    drain_status();
    bool all_ended = !ingest_.workers().empty();
    for (auto& [k, w] : ingest_.workers()) all_ended = all_ended && w.ended;
    if (all_ended) break;
    batches_in_.wait(0.05);
  }
  for (auto& [k, w] : ingest_.workers())
    if (!w.ended)
      log("worker " + w.worker_id + " did not close its stream; batches after " + std::to_string(w.next_sequence) +
          " are unaccounted");
}

}  // namespace farm
