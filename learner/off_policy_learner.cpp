#include "off_policy_learner.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>

#include "checkpoint.h"
#include "divergence.h"
#include "meter.h"
#include "off_policy.h"
#include "replay_buffer.h"
#include "rng_state.h"
#include "rollout.h"

namespace farm {

namespace {

class OffPolicyLearner final : public LearnerService {
 public:
  OffPolicyLearner(const LearnerRunOptions& o, const config::ExperimentConfig& cfg, const std::atomic<bool>& interrupted)
      : LearnerService(o, cfg, interrupted),
        algo_(make_off_policy(cfg_, task_->spec())),
        algo_name_(algo_->name()),
        replay_(algo_->buffer_size(), obs_dim_, act_dim_),
        rng_(cfg_.seed() * 7919 + 17) {}

 private:
  std::string describe() const override { return algo_->describe(); }

  void on_start() override {
    publish_weights();
    last_eval_time_ = now_seconds();
  }

  void work(double t0) override {
    const size_t got = drain_batches(256);
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
    const double now = now_seconds();
    if (now - last_eval_time_ >= cfg_.eval().every_seconds() && algo_->updates() > 0) {
      evaluate(cfg_.eval().episodes(), now - t0);
      last_eval_time_ = now_seconds();
    }
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

  void hold_workers() override {
    farm::msg::PolicyWeights w;
    farm::dds::to_wire(algo_->export_policy(current_version()), cfg_.experiment_id(), w);
    w.batch_quota(1);
    weights_out_.write(w);
  }

  uint64_t current_version() const { return version_ > 0 ? version_ - 1 : 0; }

  size_t drain_batches(size_t max) override {
    size_t n = 0;
    while (n < max && batches_in_.take(batch_)) {
      ++n;
      if (!accept_batch(current_version())) continue;
      ++batches_since_publish_;
      if (pending_.n > 0) {
        fold_n_step(batch_, pending_, algo_->gamma(), algo_->n_step());
        replay_.add_n(pending_.n, pending_.obs.data(), pending_.actions.data(), pending_.rewards.data(),
                      pending_.terminated.data(), pending_.next_obs.data(), pending_.horizon.data());
      }
      for (auto& e : episodes_) record_episode(e.episode_return);
    }
    return n;
  }

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
    return double(algo_->updates()) < algo_->max_updates_per_step() * double(ingest_.counters().env_steps) + 1;
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
    const double mean = recs.empty() ? 0 : sum / recs.size();
    last_eval_ = mean;
    std::string metric_txt;
    for (size_t i = 0; i < metrics.size() && !recs.empty(); ++i)
      metric_txt += ", " + names[i] + " " + fmt("%.3f", metrics[i] / recs.size());
    log(label + ": mean return " + fmt("%.1f", mean) + " over " + std::to_string(recs.size()) +
        " deterministic episodes" + metric_txt + " (policy v" + std::to_string(p.version) + ", " +
        std::to_string(algo_->updates()) + " updates, " + fmt("%.1f", elapsed) + " s)");
    record_evaluation(mean, p.version, algo_->updates(), elapsed);
    return mean;
  }

  void progress(double elapsed, double window) override {
    const auto& c = ingest_.counters();
    const Window w = take_window(window);
    const double upd_rate = updates_meter_.rate();
    const double utd = c.env_steps > 0 ? double(algo_->updates()) / double(c.env_steps) : 0.0;
    const double fill = double(replay_.size()) / double(replay_.capacity());
    const double mean_ret = mean_recent_return();
    std::ostringstream o;
    o << fmt("%7.1fs", elapsed) << " | in " << fmt("%.0f", w.in_rate) << " steps/s (" << c.env_steps << ") | "
      << fmt("%.0f", upd_rate) << " upd/s (" << algo_->updates() << ", utd " << fmt("%.3f", utd) << ") | buffer "
      << fmt("%.1f", 100 * fill) << "% | v" << current_version() << " lag " << fmt("%.1f", w.lag) << " | return "
      << fmt("%.1f", mean_ret) << " eval " << fmt("%.1f", last_eval_) << " | batches ok " << c.ok << " lost "
      << c.lost << " dup " << c.duplicate << " invalid " << c.invalid << " | workers " << live_workers()
      << waiting_note();
    log(o.str());
    csv_ << fmt("%.2f", elapsed) << ',' << c.env_steps << ',' << fmt("%.1f", w.in_rate) << ',' << algo_->updates()
         << ',' << fmt("%.1f", upd_rate) << ',' << fmt("%.4f", utd) << ',' << fmt("%.4f", fill) << ','
         << current_version() << ',' << fmt("%.2f", w.lag) << ',' << fmt("%.5g", last_stats_.critic_loss) << ','
         << fmt("%.5g", last_stats_.actor_loss) << ',' << fmt("%.5g", last_stats_.alpha) << ','
         << fmt("%.2f", mean_ret) << ',' << fmt("%.2f", last_eval_) << ',' << c.ok << ',' << c.lost << ','
         << c.duplicate << ',' << c.invalid << ',' << live_workers() << '\n';
    csv_.flush();
    farm::msg::LearnerStats st = base_stats(elapsed, w);
    st.updates(algo_->updates());
    st.updates_per_second(upd_rate);
    st.buffer_fill(fill);
    st.critic_loss(last_stats_.critic_loss);
    st.actor_loss(last_stats_.actor_loss);
    st.eval_return(last_eval_);
    stats_out_.write(st);
  }

  std::string csv_header() const override {
    return "elapsed_s,env_steps,env_steps_per_s,updates,updates_per_s,update_to_data,buffer_fill,"
           "policy_version,policy_lag,critic_loss,actor_loss,alpha,mean_return,eval_return,"
           "batches_ok,batches_lost,batches_duplicate,batches_invalid,workers";
  }

  std::string should_stop(double elapsed) const override {
    return limit_reached(elapsed, last_eval_, algo_->updates());
  }

  config::CheckpointManifest restore_algorithm() override {
    return load_checkpoint(ckpt_dir_, cfg_.experiment_id(), *algo_, replay_);
  }

  void resumed(const config::CheckpointManifest& m) override {
    // The crashed learner may have published versions after its last checkpoint; skip past any
    // it could have reached, so versions stay unique and batches claiming a newer one are refused.
    version_ = m.policy_version() + 1 + kResumeVersionSkip;
    rng_from_manifest(m, &rng_);  // after the algorithm's constructor seeded LibTorch
    log("resumed from " + ckpt_dir_ + " (next policy v" + std::to_string(version_) + "): " +
        std::to_string(algo_->updates()) + " updates, " +
        std::to_string(ingest_.counters().env_steps) + " env steps, buffer " + std::to_string(replay_.size()));
  }

  void checkpoint(double elapsed) override {
    config::CheckpointManifest m = base_manifest(current_version(), algo_->updates(), elapsed);
    rng_to_manifest(&rng_, m);
    const double t = now_seconds();
    save_checkpoint(ckpt_dir_, m, *algo_, replay_);
    log("checkpoint " + ckpt_dir_ + " (" + fmt("%.2f", now_seconds() - t) + " s)");
  }

  void save_networks(const std::string& dir) const override { farm::save_networks(dir, *algo_); }

  void final_evaluation(double elapsed) override { final_return_ = evaluate(cfg_.eval().final_episodes(), elapsed, "final"); }

  void write_summary(double elapsed, const std::string& reason) override {
    const auto& c = ingest_.counters();
    std::ostringstream o;
    o << summary_head(elapsed, reason) << "updates           " << algo_->updates() << " ("
      << fmt("%.0f", algo_->updates() / std::max(elapsed, 1e-9)) << " updates/s)\n"
      << "policy versions   " << current_version() << "\n"
      << "episodes          " << episodes_total_ << "\n"
      << "final eval return " << fmt("%.1f", final_return_) << " (mean of " << cfg_.eval().final_episodes()
      << " deterministic episodes)\n"
      << "best eval return  " << fmt("%.1f", best_eval_) << "\n"
      << "batches           ok " << c.ok << ", lost " << c.lost << ", duplicate " << c.duplicate << ", invalid "
      << c.invalid << "\n"
      << summary_workers();
    emit_summary(o.str());
  }

  std::unique_ptr<OffPolicy> algo_;
  const std::string algo_name_;  // for the per-update divergence check
  ReplayBuffer replay_;
  std::mt19937_64 rng_;
  OffPolicyStats last_stats_{};
  Meter updates_meter_;
  uint64_t version_ = 0;
  int updates_since_publish_ = 0, batches_since_publish_ = 0;
  double last_eval_ = NAN, last_eval_time_ = 0, final_return_ = NAN;
};

}  // namespace

int run_off_policy_learner(const LearnerRunOptions& opt, const config::ExperimentConfig& cfg,
                           const std::atomic<bool>& interrupted) {
  OffPolicyLearner l(opt, cfg, interrupted);
  return l.run();
}

}  // namespace farm
