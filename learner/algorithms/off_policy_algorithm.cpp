// The replay-buffer driver that runs every off-policy algorithm (SAC, DQN): keeps the workers'
// transitions in a replay buffer, updates as fast as the data and the algorithm's pacing allow,
// publishes the policy every few updates, asks for evaluations on a timer, and checkpoints the networks with
// the buffer.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>

#include "algorithm.h"
#include "divergence.h"
#include "meter.h"
#include "off_policy.h"
#include "replay_buffer.h"
#include "rng_state.h"

namespace farm {

namespace {

class OffPolicyAlgorithm final : public Algorithm {
 public:
  OffPolicyAlgorithm(std::unique_ptr<OffPolicy> algo, const config::ExperimentConfig& cfg, const robots::TaskSpec& spec)
      : cfg_(cfg),
        algo_(std::move(algo)),
        algo_name_(algo_->name()),
        alpha_name_(algo_->alpha_name()),
        metric_names_(spec.metric_names),
        replay_(algo_->buffer_size(), spec.obs_dim, spec.act_dim),
        rng_(cfg_.seed() * 7919 + 17) {
    if (const auto device = algo_->replay_device())
      device_replay_ =
          std::make_unique<DeviceReplay>(algo_->buffer_size(), spec.obs_dim, spec.act_dim, *device, algo_->gamma());
  }

  std::string describe() const override { return algo_->describe(); }

  std::string csv_header() const override {
    return "elapsed_s,env_steps,env_steps_per_s,updates,updates_per_s,update_to_data,buffer_fill,"
           "policy_version,policy_lag,critic_loss,actor_loss,alpha,mean_return,eval_return,"
           "batches_ok,batches_lost,batches_duplicate,batches_invalid,workers";
  }

  uint64_t version() const override { return version_ > 0 ? version_ - 1 : 0; }
  int64_t updates() const override { return algo_->updates(); }
  double last_eval() const override { return last_eval_; }

  void start(Farm& farm) override {
    publish_weights(farm);
    last_eval_time_ = now_seconds();
  }

  bool take(const Batch& b) override {
    ++batches_since_publish_;
    Transitions& rows = *b.rows;
    if (rows.n > 0) {
      fold_n_step(b.num_steps, b.num_envs, b.truncated, rows, algo_->gamma(), algo_->n_step());
      replay_.add_n(rows.n, rows.obs.data(), rows.actions.data(), rows.rewards.data(), rows.terminated.data(),
                    rows.next_obs.data(), rows.horizon.data());
      if (device_replay_)
        device_replay_->add_n(rows.n, rows.obs.data(), rows.actions.data(), rows.rewards.data(), rows.terminated.data(),
                              rows.next_obs.data(), rows.horizon.data());
    }
    return true;
  }

  double train(Farm& farm, bool got_data) override {
    if (!diverged_.empty()) throw std::runtime_error(diverged_);
    // One group of updates between looks at the bus: on a GPU the algorithm queues them back to
    // back (OffPolicy::update_n).
    int n = 0;
    while (n < kUpdatesPerGroup && can_update(farm, n)) ++n;
    const bool updated = n > 0;
    if (updated) train_steps(n);
    if (algo_->max_step_scale() > 1) adapt_step(farm);
    if (updates_since_publish_ >= algo_->publish_every_updates()) publish_weights(farm);
    double wait = 0;
    if (!updated) {
      // Starved (no data, or the ratio limiter holds): let the workers' throttle go with a new
      // version, so neither side waits for the other.
      if (updates_since_publish_ > 0 || batches_since_publish_ > 0) publish_weights(farm);
      if (!got_data) wait = 0.01;
    }
    if (now_seconds() - last_eval_time_ >= cfg_.eval().every_seconds() && algo_->updates() > 0) {
      ask_evaluation(farm, cfg_.eval().episodes(), farm.elapsed(), "eval");  // answered later: evaluated()
      last_eval_time_ = now_seconds();
    }
    return wait;
  }

  void hold_workers(Farm& farm) override {
    settle();
    farm.publish(algo_->export_policy(version()), 1);
  }

  void progress(Farm& farm, const FarmFigures& f, double elapsed, AlgorithmStats* stats) override {
    const double upd_rate = updates_meter_.rate();
    const double utd = f.env_steps > 0 ? double(algo_->updates()) / double(f.env_steps) : 0.0;
    const double fill = double(replay_.size()) / double(replay_.capacity());
    std::ostringstream o;
    o << fmt("%7.1fs", elapsed) << " | in " << fmt("%.0f", f.in_rate) << " steps/s (" << f.env_steps << ") | "
      << fmt("%.0f", upd_rate) << " upd/s (" << algo_->updates() << ", utd " << fmt("%.3f", utd) << ") | buffer "
      << fmt("%.1f", 100 * fill) << "% | v" << version() << " lag " << fmt("%.1f", f.lag) << " | return "
      << fmt("%.1f", f.mean_return) << " eval " << fmt("%.1f", last_eval_) << " | batches ok " << f.ok << " lost "
      << f.lost << " dup " << f.duplicate << " invalid " << f.invalid << eval_counts(f) << " | workers " << f.workers
      << (algo_->max_step_scale() > 1 ? " | step x" + std::to_string(algo_->step_scale()) : "") << f.waiting_note;
    farm.log(o.str());
    std::ostringstream row;
    row << fmt("%.2f", elapsed) << ',' << f.env_steps << ',' << fmt("%.1f", f.in_rate) << ',' << algo_->updates() << ','
        << fmt("%.1f", upd_rate) << ',' << fmt("%.4f", utd) << ',' << fmt("%.4f", fill) << ',' << version() << ','
        << fmt("%.2f", f.lag) << ',' << fmt("%.5g", last_stats_.critic_loss) << ','
        << fmt("%.5g", last_stats_.actor_loss) << ',' << fmt("%.5g", last_stats_.alpha) << ','
        << fmt("%.2f", f.mean_return) << ',' << fmt("%.2f", last_eval_) << ',' << f.ok << ',' << f.lost << ','
        << f.duplicate << ',' << f.invalid << ',' << f.workers;
    farm.csv_row(row.str());
    stats->updates = algo_->updates();
    stats->updates_per_second = upd_rate;
    stats->buffer_fill = fill;
    stats->critic_loss = last_stats_.critic_loss;
    stats->actor_loss = last_stats_.actor_loss;
    stats->eval_return = last_eval_;
  }

  void final_evaluation(Farm& farm, double elapsed) override {
    ask_evaluation(farm, cfg_.eval().final_episodes(), elapsed, "final");
  }

  void evaluated(Farm& farm, const EvalAsk& ask, const EvalReport& r) override {
    const double mean = r.episodes > 0 ? r.mean : 0;
    last_eval_ = mean;
    if (ask.label == "final") final_return_ = mean;
    std::string metric_txt;
    for (size_t i = 0; i < r.metrics.size() && i < metric_names_.size() && r.episodes > 0; ++i)
      metric_txt += ", " + metric_names_[i] + " " + fmt("%.3f", r.metrics[i]);
    farm.log(ask.label + ": mean return " + fmt("%.1f", mean) + " over " + std::to_string(r.episodes) +
             " deterministic episodes" + metric_txt + " (policy v" + std::to_string(ask.version) + ", " + ask.progress +
             ", " + fmt("%.1f", ask.elapsed) + " s)");
    farm.record_evaluation(r, ask.version, ask.updates, ask.elapsed);
  }

  std::string summary(const FarmFigures& f, double elapsed) const override {
    std::ostringstream o;
    o << "updates           " << algo_->updates() << " (" << fmt("%.0f", algo_->updates() / std::max(elapsed, 1e-9))
      << " updates/s)\n"
      << "policy versions   " << version() << "\n"
      << "episodes          " << f.episodes << "\n"
      << "final eval return " << fmt("%.1f", final_return_) << " (mean of " << cfg_.eval().final_episodes()
      << " deterministic episodes)\n"
      << best_eval_line(f) << "\n"
      << "batches           ok " << f.ok << ", lost " << f.lost << ", duplicate " << f.duplicate << ", invalid "
      << f.invalid << "\n";
    return o.str();
  }

  void save_networks(const std::string& dir) const override {
    settle();
    std::filesystem::create_directories(std::filesystem::path(dir) / algo_->name());
    algo_->save((std::filesystem::path(dir) / algo_->name()).string());
  }
  PolicyParams policy() const override {
    settle();
    return algo_->export_policy(version());
  }
  void save(const std::string& dir) const override {
    save_networks(dir);
    replay_.save((std::filesystem::path(dir) / "replay.pt").string());
  }
  void to_manifest(config::CheckpointManifest& m) const override { rng_to_manifest(&rng_, m); }
  void load(const std::string& dir) override {
    algo_->load((std::filesystem::path(dir) / algo_->name()).string());
    replay_.load((std::filesystem::path(dir) / "replay.pt").string());
    if (device_replay_) device_replay_->load_from(replay_);
  }

  std::string resumed(const config::CheckpointManifest& m, uint64_t env_steps) override {
    // The crashed learner may have published versions after its last checkpoint; skip past any
    // it could have reached, so versions stay unique and batches claiming a newer one are refused.
    version_ = m.policy_version() + 1 + kResumeVersionSkip;
    rng_from_manifest(m, &rng_);  // after the algorithm's constructor seeded LibTorch
    return "(next policy v" + std::to_string(version_) + "): " + std::to_string(algo_->updates()) + " updates, " +
           std::to_string(env_steps) + " env steps, buffer " + std::to_string(replay_.size());
  }

 private:
  void publish_weights(Farm& farm) {
    settle();
    algo_->set_env_steps(int64_t(farm.env_steps()));  // DQN's exploration schedule
    farm.publish(algo_->export_policy(version_), 0);
    ++version_;
    updates_since_publish_ = 0;
    batches_since_publish_ = 0;
  }

  // sac.max_step_scale: once a window of kStepWindowSeconds from the first update on, the updates
  // the data allowed in it (the pacing's max_updates_per_step x env steps received) per update made
  // set the step scale for the next window (next_step_scale).
  void adapt_step(Farm& farm) {
    const double t = now_seconds();
    const int64_t updates = algo_->updates();
    const uint64_t env_steps = farm.env_steps();
    if (updates == 0) return;
    if (step_window_start_ < 0 || t - step_window_start_ >= kStepWindowSeconds) {
      if (step_window_start_ >= 0 && updates > step_window_updates_) {
        const double allowed = algo_->max_updates_per_step() * double(env_steps - step_window_env_steps_);
        const double r = allowed / double(updates - step_window_updates_);
        const int next = next_step_scale(algo_->step_scale(), r, algo_->max_step_scale());
        if (next != algo_->step_scale()) {
          algo_->set_step_scale(next);
          farm.log(algo_name_ + " step x" + std::to_string(next) + " from update " + std::to_string(updates) +
                   ": batch " + std::to_string(algo_->batch_size()) + ", learning rates x" +
                   fmt("%.2f", std::sqrt(double(next))) + " (the last " + fmt("%.1f", t - step_window_start_) +
                   " s' data allowed " + fmt("%.2f", r) + " updates per update made)");
        }
      }
      step_window_start_ = t;
      step_window_updates_ = updates;
      step_window_env_steps_ = env_steps;
    }
  }

  // Whether one more update may run after `ahead` more than have run so far.
  bool can_update(const Farm& farm, int ahead) const {
    const int64_t done = algo_->updates() + ahead;
    if (replay_.size() < std::max<int64_t>(algo_->learning_starts(), algo_->batch_size())) return false;
    if (cfg_.stop().max_updates() > 0 && done >= cfg_.stop().max_updates()) return false;
    return double(done) < algo_->max_updates_per_step() * double(farm.env_steps()) + 1;
  }

  // On a GPU update_n returns while its last updates still run, so that the device works while
  // this thread reads the bus; their figures come with the next group, or with settle().
  // With a replay on the device the updates draw their batches there (sac.replay_on_device).
  void train_steps(int n) {
    if (device_replay_)
      check(algo_->update_n_from(n, *device_replay_));
    else
      check(algo_->update_n(n, [this] { return replay_.sample(algo_->batch_size(), rng_); }));
    updates_since_publish_ += n;
  }

  // The figures of updates that have run, oldest first: a non-finite one stops the run.
  // A divergence found is kept: whoever catches the error (a periodic checkpoint logs its failure
  // and goes on), every later train(), publish, evaluation and checkpoint throws it again, though
  // the figures that showed it have been read.
  void check(const std::vector<OffPolicyStats>& stats) const {
    const int64_t first = algo_->updates() - algo_->updates_in_flight() - int64_t(stats.size()) + 1;
    try {
      for (size_t k = 0; k < stats.size(); ++k)
        require_finite_update(algo_name_, first + int64_t(k),
                              {{"critic loss", stats[k].critic_loss},
                               {"actor loss", stats[k].actor_loss},
                               {alpha_name_.c_str(), stats[k].alpha}});
    } catch (const std::runtime_error& e) {
      diverged_ = e.what();
      throw;
    }
    if (!stats.empty()) last_stats_ = stats.back();
    updates_meter_.add(stats.size());
  }

  // Waits for the updates still running and checks their figures: before any weights leave the
  // learner (to the workers, to an evaluation, to a checkpoint), as the divergence guard promises.
  void settle() const {
    if (!diverged_.empty()) throw std::runtime_error(diverged_);
    check(algo_->finish_updates());
  }

  void ask_evaluation(Farm& farm, int episodes, double elapsed, const std::string& label) {
    settle();
    EvalAsk ask;
    ask.label = label;
    ask.episodes = episodes;
    ask.version = version();
    ask.updates = algo_->updates();
    ask.elapsed = elapsed;
    ask.progress = std::to_string(ask.updates) + " updates";
    farm.ask_evaluation(algo_->export_policy(ask.version), ask);
  }

  const config::ExperimentConfig cfg_;
  std::unique_ptr<OffPolicy> algo_;
  const std::string algo_name_, alpha_name_;  // for the per-update divergence check
  const std::vector<std::string> metric_names_;
  ReplayBuffer replay_;
  std::mt19937_64 rng_;
  std::unique_ptr<DeviceReplay> device_replay_;  // the same rows on the updates' device, where they draw
  mutable OffPolicyStats last_stats_{};          // check() runs from const save_networks() too
  mutable Meter updates_meter_;
  mutable std::string diverged_;  // the divergence error, once one was found (check())
  uint64_t version_ = 0;          // the next version to publish
  int updates_since_publish_ = 0, batches_since_publish_ = 0;
  double last_eval_ = NAN, last_eval_time_ = 0, final_return_ = NAN;
  static constexpr double kStepWindowSeconds = 1.0;
  double step_window_start_ = -1;
  int64_t step_window_updates_ = 0;
  uint64_t step_window_env_steps_ = 0;
};

}  // namespace

std::unique_ptr<Algorithm> make_off_policy_algorithm(std::unique_ptr<OffPolicy> algo,
                                                     const config::ExperimentConfig& cfg,
                                                     const robots::TaskSpec& spec) {
  return std::make_unique<OffPolicyAlgorithm>(std::move(algo), cfg, spec);
}

}  // namespace farm
