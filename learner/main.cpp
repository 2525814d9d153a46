// farm-learner: publishes the experiment, ingests the workers' batches, trains with SAC and
// broadcasts the policy, logs throughput and learning progress, checkpoints and resumes.
#include <signal.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>

#include <torch/torch.h>

#include "checkpoint.h"
#include "config.h"
#include "dds.h"
#include "ingest.h"
#include "meter.h"
#include "replay_buffer.h"
#include "rng_state.h"
#include "spec_publisher.h"
#include "worker_roster.h"
#include "rollout.h"
#include "divergence.h"
#include "off_policy.h"
#include "ppo_learner.h"
#include "sac.h"
#include "task.h"

using namespace farm;
namespace fs = std::filesystem;

namespace {

std::atomic<bool> g_interrupted{false};
void on_signal(int) { g_interrupted = true; }

struct Options {
  std::string config_path;
  farm::dds::BusOptions bus;
  bool resume = false;
  std::string run_dir;  // default <run_root>/<experiment_id>
};

void usage() {
  std::cout << "usage: farm-learner --config FILE [--resume] [--run-dir DIR] [--domain D]\n"
               "                    [--dds-profiles FILE] [--security DIR]\n"
               "Trains the experiment in FILE with the workers that join on DDS domain D.\n"
               "Logs to stdout and <run-dir>/learner.csv; checkpoints to <run-dir>/checkpoint.\n"
               "--resume carries on from the checkpoint in the run dir. Without it, an existing\n"
               "run dir is moved aside (renamed with a time stamp), never overwritten.\n";
}

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
      return argv[++i];
    };
    if (farm::dds::parse_bus_flag(argc, argv, i, o.bus)) continue;
    if (a == "--config") o.config_path = value();
    else if (a == "--resume") o.resume = true;
    else if (a == "--run-dir") o.run_dir = value();
    else if (a == "-h" || a == "--help") { usage(); std::exit(0); }
    else throw std::invalid_argument("unknown option '" + a + "' (see --help)");
  }
  if (o.config_path.empty()) throw std::invalid_argument("--config FILE is required (see --help)");
  return o;
}

std::string fmt(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

// Versions skipped on --resume: more than a learner publishes between two checkpoints.
constexpr uint64_t kResumeVersionSkip = 100000;

class Learner {
 public:
  Learner(const Options& o, config::ExperimentConfig cfg)
      : opt_(o),
        cfg_(std::move(cfg)),
        task_(robots::make_task(cfg_.task())),
        obs_dim_(task_->spec().obs_dim),
        act_dim_(task_->spec().act_dim),
        algo_(make_off_policy(cfg_, task_->spec())),
        replay_(algo_->buffer_size(), obs_dim_, act_dim_),
        ingest_(cfg_.experiment_id(), obs_dim_, act_dim_),
        rng_(cfg_.seed() * 7919 + 17),
        bus_(o.bus, "farm-learner " + cfg_.experiment_id()),
        spec_(bus_, cfg_, obs_dim_, act_dim_),
        weights_out_(bus_, farm::dds::kWeightsTopic, "latest_writer"),
        stats_out_(bus_, farm::dds::kLearnerStatsTopic, "status_writer"),
        batches_in_(bus_, farm::dds::kBatchTopic, "batch_reader"),
        status_in_(bus_, farm::dds::kWorkerStatusTopic, "status_reader") {
    run_dir_ = opt_.run_dir.empty() ? (fs::path(cfg_.run_root()) / cfg_.experiment_id()).string() : opt_.run_dir;
    ckpt_dir_ = (fs::path(run_dir_) / "checkpoint").string();
    ingest_.set_num_actions(task_->spec().num_actions);
  }

  int run() {
    prepare_run_dir();
    spec_.publish(false);
    publish_weights();
    log("experiment '" + cfg_.experiment_id() + "': task " + cfg_.task().name() + " (obs " +
        std::to_string(obs_dim_) + ", act " + std::to_string(act_dim_) + "), " +
        algo_->describe() + ", DDS domain " + std::to_string(bus_.domain()) +
        ", run dir " + run_dir_ + (bus_.security_dir().empty() ? "" : ", DDS Security from " + bus_.security_dir()));
    log("waiting for workers: start them with `farm-worker --domain " + std::to_string(bus_.domain()) + "`");

    const double t0 = now_seconds() - elapsed_offset_;
    double last_log = now_seconds(), last_eval = now_seconds(), last_ckpt = now_seconds();
    std::string stop_reason;
    while (stop_reason.empty()) {
      if (g_interrupted) { stop_reason = "interrupted"; break; }
      size_t got = drain_batches(256);
      drain_status();
      bool updated = false;
      for (int k = 0; k < 8 && can_update(); ++k) {
        train_step();
        updated = true;
      }
      if (updates_since_publish_ >= algo_->publish_every_updates()) publish_weights();
      if (!updated) {
        // Starved (no data, or the ratio limiter holds): let the workers' throttle go with a new
        // version, so neither side waits for the other.
        if (updates_since_publish_ > 0 || batches_since_publish_ > 0) publish_weights();
        if (got == 0) batches_in_.wait(0.01);
      }
      double now = now_seconds();
      if (now - last_eval >= cfg_.eval().every_seconds() && algo_->updates() > 0) {
        evaluate(cfg_.eval().episodes(), now - t0);
        last_eval = now_seconds();
      }
      if (now - last_log >= cfg_.log_every_seconds()) {
        log_progress(now - t0, now - last_log);
        last_log = now;
      }
      spec_.republish_if_due(now);
      if (now - last_ckpt >= cfg_.checkpoint_every_seconds()) {
        checkpoint(now - t0);
        last_ckpt = now_seconds();
      }
      stop_reason = should_stop(now - t0);
    }
    const double elapsed = now_seconds() - t0;
    log("stopping: " + stop_reason);
    if (stop_reason == "interrupted") {
      // Workers stay and wait: a resumed learner picks them up again.
      checkpoint(elapsed);
      log("checkpoint written; resume with --resume");
      return 130;
    }
    double final_return = evaluate(cfg_.eval().final_episodes(), elapsed, "final");
    spec_.publish(true);
    drain_until_workers_end();
    checkpoint(elapsed);
    write_summary(elapsed, stop_reason, final_return);
    return 0;
  }

 private:
  void log(const std::string& s) {
    std::printf("[learner] %s\n", s.c_str());
    std::fflush(stdout);
  }

  void prepare_run_dir() {
    if (opt_.resume) {
      if (!checkpoint_exists(ckpt_dir_))
        throw std::runtime_error("--resume: no checkpoint in " + ckpt_dir_);
      auto m = load_checkpoint(ckpt_dir_, cfg_.experiment_id(), *algo_, replay_);
      // The crashed learner may have published versions after its last checkpoint; skip past any
      // it could have reached, so versions stay unique and batches claiming a newer one are refused.
      version_ = m.policy_version() + 1 + kResumeVersionSkip;
      elapsed_offset_ = m.elapsed_seconds();
      best_eval_ = m.has_best_eval_return() ? m.best_eval_return() : best_eval_;
      episodes_total_ = m.episodes();
      accounts_from_manifest(m, ingest_);
      // The first progress line's rates count from the restored counters, not from zero.
      last_steps_ = ingest_.counters().env_steps;
      last_ok_ = ingest_.counters().ok;
      last_lag_sum_ = ingest_.counters().lag_sum;
      rng_from_manifest(m, &rng_);  // after the algorithm's constructor seeded LibTorch
      log("resumed from " + ckpt_dir_ + ": " + std::to_string(algo_->updates()) + " updates, " +
          std::to_string(ingest_.counters().env_steps) + " env steps, buffer " +
          std::to_string(replay_.size()));
    } else if (const std::string aside = move_run_dir_aside(run_dir_); !aside.empty()) {
      log("previous run moved to " + aside + " (use --resume to continue a run instead)");
    }
    fs::create_directories(run_dir_);
    bool new_csv = !fs::exists(fs::path(run_dir_) / "learner.csv");
    csv_.open(fs::path(run_dir_) / "learner.csv", std::ios::app);
    if (!csv_) throw std::runtime_error("cannot write " + run_dir_ + "/learner.csv");
    if (new_csv)
      csv_ << "elapsed_s,env_steps,env_steps_per_s,updates,updates_per_s,update_to_data,buffer_fill,"
              "policy_version,policy_lag,critic_loss,actor_loss,alpha,mean_return,eval_return,"
              "batches_ok,batches_lost,batches_duplicate,batches_invalid,workers\n";
  }

  void publish_weights() {
    farm::msg::PolicyWeights w;
    algo_->set_env_steps(int64_t(ingest_.counters().env_steps));  // DQN's exploration schedule
    farm::dds::to_wire(algo_->export_policy(version_), cfg_.experiment_id(), w);
    weights_out_.write(w);
    ++version_;
    updates_since_publish_ = 0;
    batches_since_publish_ = 0;
  }

  uint64_t current_version() const { return version_ > 0 ? version_ - 1 : 0; }

  size_t drain_batches(size_t max) {
    size_t n = 0;
    while (n < max && batches_in_.take(batch_)) {
      ++n;
      pending_.clear();
      std::string why = ingest_.accept(batch_, current_version(), now_seconds(), pending_, episodes_);
      if (!why.empty()) {
        if (++rejections_logged_ <= 20) log("rejected batch " + std::to_string(batch_.sequence_number()) + " from " + batch_.worker_id() + ": " + why);
        continue;
      }
      ++batches_since_publish_;
      if (pending_.n > 0) {
        fold_n_step(batch_, pending_, algo_->gamma(), algo_->n_step());
        replay_.add_n(pending_.n, pending_.obs.data(), pending_.actions.data(), pending_.rewards.data(),
                      pending_.terminated.data(), pending_.next_obs.data(), pending_.horizon.data());
      }
      for (auto& e : episodes_) {
        recent_returns_.push_back(e.episode_return);
        if (recent_returns_.size() > 100) recent_returns_.pop_front();
        ++episodes_total_;
      }
      episodes_.clear();
    }
    return n;
  }

  void drain_status() {
    farm::msg::WorkerStatus s;
    while (status_in_.take(s)) roster_.heard(s, now_seconds());
    roster_.check(now_seconds());
  }

  int live_workers() const { return roster_.live_count(now_seconds()); }

  // Live workers that wait on the learner (for new weights, or for room in the batch queue): the
  // learner is the bottleneck and the workers are held back instead of piling up data.
  std::string waiting_note() const {
    int throttled = 0, backpressure = 0;
    const double now = now_seconds();
    for (auto& [k, v] : roster_.views()) {
      if (!roster_.live(v, now)) continue;
      throttled += v.last.state() == "throttled";
      backpressure += v.last.state() == "backpressure";
    }
    std::string note;
    if (throttled) note += ", " + std::to_string(throttled) + " throttled";
    if (backpressure) note += ", " + std::to_string(backpressure) + " in backpressure";
    return note.empty() ? "" : " (" + note.substr(2) + ")";
  }

  bool can_update() const {
    if (replay_.size() < std::max<int64_t>(algo_->learning_starts(), algo_->batch_size())) return false;
    if (cfg_.stop().max_updates() > 0 && algo_->updates() >= cfg_.stop().max_updates()) return false;
    return double(algo_->updates() - updates_at_start_) < algo_->max_updates_per_step() * double(ingest_.counters().env_steps - steps_at_start_) + 1;
  }

  void train_step() {
    last_stats_ = algo_->update(replay_.sample(algo_->batch_size(), rng_));
    require_finite_update(algo_name_, algo_->updates(),
                          {{"critic loss", last_stats_.critic_loss}, {"actor loss", last_stats_.actor_loss},
                           {algo_name_ == "dqn" ? "epsilon" : "alpha", last_stats_.alpha}});
    ++updates_since_publish_;
    updates_meter_.add(1);
  }

  double evaluate(int episodes, double elapsed, const std::string& label = "eval") {
    PolicyParams p = algo_->export_policy(current_version());
    auto recs = evaluate_policy(task_, p, episodes, cfg_.seed() + 1000003ull * ++evals_);
    const auto& names = task_->spec().metric_names;
    double sum = 0;
    std::vector<double> metrics(names.size(), 0.0);
    for (auto& r : recs) {
      sum += r.episode_return;
      for (size_t i = 0; i < metrics.size() && i < r.metrics.size(); ++i) metrics[i] += r.metrics[i];
    }
    double mean = recs.empty() ? 0 : sum / recs.size();
    last_eval_ = mean;
    best_eval_ = std::isnan(best_eval_) ? mean : std::max(best_eval_, mean);
    std::string metric_txt;
    for (size_t i = 0; i < metrics.size() && !recs.empty(); ++i)
      metric_txt += ", " + names[i] + " " + fmt("%.3f", metrics[i] / recs.size());
    log(label + ": mean return " + fmt("%.1f", mean) + " over " + std::to_string(recs.size()) +
        " deterministic episodes" + metric_txt + " (policy v" + std::to_string(p.version) + ", " +
        std::to_string(algo_->updates()) + " updates, " + fmt("%.1f", elapsed) + " s)");
    return mean;
  }

  void log_progress(double elapsed, double window) {
    const auto& c = ingest_.counters();
    double in_rate = double(c.env_steps - last_steps_) / window;
    last_steps_ = c.env_steps;
    double upd_rate = updates_meter_.rate();
    double lag = c.ok > last_ok_ ? (c.lag_sum - last_lag_sum_) / double(c.ok - last_ok_) : 0.0;
    last_ok_ = c.ok;
    last_lag_sum_ = c.lag_sum;
    double utd = c.env_steps > 0 ? double(algo_->updates()) / double(c.env_steps) : 0.0;
    double fill = double(replay_.size()) / double(replay_.capacity());
    double mean_ret = recent_returns_.empty() ? NAN : mean_of(recent_returns_);
    std::ostringstream o;
    o << fmt("%7.1fs", elapsed) << " | in " << fmt("%.0f", in_rate) << " steps/s (" << c.env_steps
      << ") | " << fmt("%.0f", upd_rate) << " upd/s (" << algo_->updates() << ", utd " << fmt("%.3f", utd)
      << ") | buffer " << fmt("%.1f", 100 * fill) << "% | v" << current_version() << " lag "
      << fmt("%.1f", lag) << " | return " << fmt("%.1f", mean_ret) << " eval " << fmt("%.1f", last_eval_)
      << " | batches ok " << c.ok << " lost " << c.lost << " dup " << c.duplicate << " invalid " << c.invalid
      << " | workers " << live_workers() << waiting_note();
    log(o.str());
    csv_ << fmt("%.2f", elapsed) << ',' << c.env_steps << ',' << fmt("%.1f", in_rate) << ',' << algo_->updates()
         << ',' << fmt("%.1f", upd_rate) << ',' << fmt("%.4f", utd) << ',' << fmt("%.4f", fill) << ','
         << current_version() << ',' << fmt("%.2f", lag) << ',' << fmt("%.5g", last_stats_.critic_loss) << ','
         << fmt("%.5g", last_stats_.actor_loss) << ',' << fmt("%.5g", last_stats_.alpha) << ','
         << fmt("%.2f", mean_ret) << ',' << fmt("%.2f", last_eval_) << ',' << c.ok << ',' << c.lost << ','
         << c.duplicate << ',' << c.invalid << ',' << live_workers() << '\n';
    csv_.flush();
    farm::msg::LearnerStats st;
    st.experiment_id(cfg_.experiment_id());
    st.elapsed_seconds(elapsed);
    st.env_steps(c.env_steps);
    st.env_steps_per_second(in_rate);
    st.updates(algo_->updates());
    st.updates_per_second(upd_rate);
    st.buffer_fill(fill);
    st.policy_lag(lag);
    st.critic_loss(last_stats_.critic_loss);
    st.actor_loss(last_stats_.actor_loss);
    st.mean_return(mean_ret);
    st.eval_return(last_eval_);
    st.batches_ok(c.ok);
    st.batches_lost(c.lost);
    st.batches_duplicate(c.duplicate);
    st.batches_invalid(c.invalid);
    st.workers(live_workers());
    stats_out_.write(st);
  }

  static double mean_of(const std::deque<float>& d) {
    double s = 0;
    for (float x : d) s += x;
    return s / d.size();
  }

  std::string should_stop(double elapsed) const {
    const auto& s = cfg_.stop();
    if (!std::isnan(s.target_eval_return()) && !std::isnan(last_eval_) && last_eval_ >= s.target_eval_return())
      return "evaluation return " + fmt("%.1f", last_eval_) + " reached the target " + fmt("%.1f", s.target_eval_return());
    if (s.max_seconds() > 0 && elapsed >= s.max_seconds()) return "time limit " + fmt("%.0f", s.max_seconds()) + " s";
    if (s.max_env_steps() > 0 && int64_t(ingest_.counters().env_steps) >= s.max_env_steps())
      return "env step limit " + std::to_string(s.max_env_steps());
    if (s.max_updates() > 0 && algo_->updates() >= s.max_updates()) return "update limit " + std::to_string(s.max_updates());
    return "";
  }

  // After announcing the end, every batch still in flight is taken and accounted, so the summary
  // can say exactly what was sent and what arrived.
  void drain_until_workers_end() {
    double t_end = now_seconds() + 15.0;
    while (now_seconds() < t_end) {
      drain_batches(1024);
      drain_status();
      bool all_ended = !ingest_.workers().empty();
      for (auto& [k, w] : ingest_.workers()) all_ended = all_ended && w.ended;
      if (all_ended) break;
      batches_in_.wait(0.05);
    }
    for (auto& [k, w] : ingest_.workers())
      if (!w.ended) log("worker " + w.worker_id + " did not close its stream; batches after " +
                        std::to_string(w.next_sequence) + " are unaccounted");
  }

  void checkpoint(double elapsed) {
    config::CheckpointManifest m;
    m.set_experiment_id(cfg_.experiment_id());
    m.set_policy_version(current_version());
    m.set_updates(algo_->updates());
    m.set_elapsed_seconds(elapsed);
    if (!std::isnan(best_eval_)) m.set_best_eval_return(best_eval_);
    m.set_config_text(config_to_text(cfg_));
    m.set_episodes(episodes_total_);
    accounts_to_manifest(ingest_, m);
    rng_to_manifest(&rng_, m);
    double t = now_seconds();
    save_checkpoint(ckpt_dir_, m, *algo_, replay_);
    log("checkpoint " + ckpt_dir_ + " (" + fmt("%.2f", now_seconds() - t) + " s)");
  }

  void write_summary(double elapsed, const std::string& reason, double final_return) {
    const auto& c = ingest_.counters();
    std::ostringstream o;
    o << "experiment        " << cfg_.experiment_id() << "\n"
      << "stopped because   " << reason << "\n"
      << "wall time         " << fmt("%.1f", elapsed) << " s\n"
      << "env steps         " << c.env_steps << " (" << fmt("%.0f", c.env_steps / std::max(elapsed, 1e-9)) << " steps/s)\n"
      << "updates           " << algo_->updates() << " (" << fmt("%.0f", algo_->updates() / std::max(elapsed, 1e-9)) << " updates/s)\n"
      << "policy versions   " << current_version() << "\n"
      << "episodes          " << episodes_total_ << "\n"
      << "final eval return " << fmt("%.1f", final_return) << " (mean of " << cfg_.eval().final_episodes() << " deterministic episodes)\n"
      << "best eval return  " << fmt("%.1f", best_eval_) << "\n"
      << "batches           ok " << c.ok << ", lost " << c.lost << ", duplicate " << c.duplicate << ", invalid " << c.invalid << "\n";
    for (auto& [k, w] : ingest_.workers()) {
      o << "worker            " << w.worker_id << " session " << w.session << ": received " << w.received
        << " of sequence 0.." << (w.next_sequence ? w.next_sequence - 1 : 0) << ", lost " << w.lost
        << ", duplicate " << w.duplicates << ", invalid " << w.invalid << (w.ended ? ", stream closed" : ", stream open") << "\n";
    }
    std::string text = o.str();
    std::printf("\n===== summary =====\n%s===================\n", text.c_str());
    std::ofstream(fs::path(run_dir_) / "summary.txt") << text;
    log("summary written to " + run_dir_ + "/summary.txt");
  }

  Options opt_;
  config::ExperimentConfig cfg_;
  std::shared_ptr<const robots::Task> task_;
  int obs_dim_, act_dim_;
  std::unique_ptr<OffPolicy> algo_;
  const std::string algo_name_ = algo_->name();  // for the per-update divergence check
  ReplayBuffer replay_;
  Ingest ingest_;
  std::mt19937_64 rng_;
  farm::dds::Bus bus_;
  SpecPublisher spec_;
  farm::dds::Writer<farm::msg::PolicyWeights, farm::msg::PolicyWeightsPubSubType> weights_out_;
  farm::dds::Writer<farm::msg::LearnerStats, farm::msg::LearnerStatsPubSubType> stats_out_;
  farm::dds::Reader<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType> batches_in_;
  farm::dds::Reader<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType> status_in_;
  std::string run_dir_, ckpt_dir_;
  std::ofstream csv_;
  farm::msg::TransitionBatch batch_;
  Transitions pending_;
  std::vector<FinishedEpisode> episodes_;
  std::deque<float> recent_returns_;
  WorkerRoster roster_{cfg_.worker_timeout_seconds(), [this](const std::string& m) { log(m); }};
  OffPolicyStats last_stats_{};
  Meter updates_meter_;
  uint64_t version_ = 0;
  int updates_since_publish_ = 0, batches_since_publish_ = 0;
  int64_t updates_at_start_ = 0;
  uint64_t steps_at_start_ = 0;
  uint64_t last_steps_ = 0, last_ok_ = 0, episodes_total_ = 0, evals_ = 0;
  double last_lag_sum_ = 0, elapsed_offset_ = 0;
  double last_eval_ = NAN, best_eval_ = NAN;
  int rejections_logged_ = 0;
};

}  // namespace

int main(int argc, char** argv) {
  Options opt;
  config::ExperimentConfig cfg;
  try {
    opt = parse(argc, argv);
    cfg = load_config_file(opt.config_path);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-learner: %s\n", e.what());
    return 2;
  }
  signal(SIGINT, on_signal);
  signal(SIGTERM, on_signal);
  configure_compute(cfg.torch_threads());
  try {
    if (cfg.algorithm() == "ppo") return run_ppo_learner({opt.bus, opt.resume, opt.run_dir}, cfg, g_interrupted);
    Learner l(opt, cfg);
    return l.run();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-learner: %s\n", e.what());
    return 1;
  }
}
