#include "ppo_learner.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

#include "divergence.h"
#include "checkpoint.h"
#include "config.h"
#include "fit_scheduler.h"
#include "ingest.h"
#include "meter.h"
#include "ppo.h"
#include "rollout.h"
#include "rollout_storage.h"
#include "rng_state.h"
#include "spec_publisher.h"
#include "worker_roster.h"
#include "task.h"

namespace farm {

namespace fs = std::filesystem;

namespace {

FitPlan plan_of(const config::PpoConfig& c) {
  FitPlan p;
  p.steps_per_fit = c.steps_per_fit();
  p.episodes_per_fit = c.episodes_per_fit();
  p.steps_per_run = c.steps_per_run();
  p.episodes_per_run = c.episodes_per_run();
  return p;
}

// What an evaluation reports: returns, lengths and the task's own metrics.
struct EvalReport {
  int episodes = 0;
  double mean = NAN, min = NAN, max = NAN, mean_length = NAN;
  std::vector<double> metrics;  // means, in the order of TaskSpec::metric_names
};

EvalReport summarize(const std::vector<EpisodeRecord>& recs, size_t num_metrics) {
  EvalReport r;
  r.episodes = int(recs.size());
  r.metrics.assign(num_metrics, 0.0);
  if (recs.empty()) return r;
  double sum = 0, len = 0;
  r.min = r.max = recs[0].episode_return;
  for (const auto& e : recs) {
    sum += e.episode_return;
    len += e.length;
    r.min = std::min<double>(r.min, e.episode_return);
    r.max = std::max<double>(r.max, e.episode_return);
    for (size_t i = 0; i < num_metrics && i < e.metrics.size(); ++i) r.metrics[i] += e.metrics[i];
  }
  r.mean = sum / recs.size();
  r.mean_length = len / recs.size();
  for (auto& m : r.metrics) m /= recs.size();
  return r;
}

class PpoLearner final : public LearnerService {
 public:
  PpoLearner(const LearnerRunOptions& o, const config::ExperimentConfig& cfg, const std::atomic<bool>& interrupted)
      : LearnerService(o, cfg, interrupted),
        pc_(cfg.ppo()),
        ppo_(pc_, obs_dim_, act_dim_, cfg_.seed()),
        storage_(obs_dim_, act_dim_),
        sched_(plan_of(pc_)) {
    if (task_->spec().num_actions > 0)
      throw std::invalid_argument("algorithm \"ppo\" needs continuous actions; task '" + cfg_.task().name() +
                                  "' has discrete ones");
  }

 private:
  std::string describe() const override {
    const auto& p = pc_;
    return "PPO (" + p.variant() + ") " + ppo_.export_policy(0).layout.describe() + " actor, " +
           (p.steps_per_fit() > 0 ? std::to_string(p.steps_per_fit()) + " steps"
                                  : std::to_string(p.episodes_per_fit()) + " episodes") +
           " per fit, max policy lag " + std::to_string(p.max_policy_lag());
  }

  void on_start() override { last_data_ = now_seconds(); }
  void on_worker_heard() override {
    if (first_join_ == 0) first_join_ = now_seconds();
  }

  void work(double t0) override {
    const size_t got = drain_batches(256);
    drain_status();
    if (!published_) {
      // The first weights wait for the first worker and a short grace for the others, so the
      // first quota is shared out over the workers that are there.
      if (first_join_ > 0 && now_seconds() - first_join_ >= kJoinGraceSeconds) {
        quota_ = batches_for_next_fit();
        publish_weights();
        published_ = true;
      } else {
        batches_in_.wait(0.05);
      }
    } else if (sched_.fit_due()) {
      fit(now_seconds() - t0);
    } else if (got == 0) {
      top_up_if_starved();
      batches_in_.wait(0.01);
    }
  }

  std::string csv_header() const override {
    std::string h =
        "elapsed_s,fit,policy_version,env_steps,steps_used,steps_carried,stale_dropped,fit_seconds,"
        "kl,learning_rate,clip_fraction,value_loss,policy_loss,entropy,mean_return,eval_return,"
        "eval_min,eval_max,eval_length,batches_ok,batches_lost,batches_duplicate,batches_invalid,"
        "batches_stale,workers,episodes";
    // The task's own per-episode metrics: means over the episodes finished since the last fit
    // (train_*) and over the evaluation episodes (eval_*).
    for (const auto& m : task_->spec().metric_names) h += ",train_" + m;
    for (const auto& m : task_->spec().metric_names) h += ",eval_" + m;
    return h;
  }

  config::CheckpointManifest restore_algorithm() override {
    const config::CheckpointManifest m = read_manifest(ckpt_dir_, cfg_.experiment_id());
    ppo_.load((fs::path(usable_checkpoint(ckpt_dir_)) / "ppo").string());
    return m;
  }

  void resumed(const config::CheckpointManifest& m) override {
    // Past any version the crashed learner published after its checkpoint, as the off-policy
    // learner does: a worker holding the same number would keep the old weights.
    version_ = m.policy_version() + 1 + kResumeVersionSkip;
    // The run's counters go on from where they were; data not yet fitted was not kept.
    rng_from_manifest(m, nullptr);
    sched_.restore_run(int64_t(m.run_steps()), int64_t(m.episodes()), ppo_.fits());
    log("resumed from " + ckpt_dir_ + " (next policy v" + std::to_string(version_) + "): " +
        std::to_string(ppo_.fits()) + " fits, " +
        std::to_string(ingest_.counters().env_steps) + " env steps, learning rate " + fmt("%.3g", ppo_.learning_rate()));
  }

  void hold_workers() override {
    if (!published_) return;
    quota_ = 1;
    write_weights();
  }

  // The current version's weights with the current quota; re-sent with a larger quota to top up.
  void write_weights() {
    farm::msg::PolicyWeights w;
    farm::dds::to_wire(policy_, cfg_.experiment_id(), w);
    w.batch_quota(quota_);
    weights_out_.write(w);
  }

  void publish_weights() {
    policy_ = ppo_.export_policy(version_);
    delivered_.clear();
    write_weights();
  }

  // Steps one round (one batch from every live worker) brings.
  int64_t round_steps() const {
    int64_t envs = 0;
    const double now = now_seconds();
    for (auto& [k, v] : roster_.views())
      if (roster_.live(v, now)) envs += v.last.envs();
    if (envs == 0) envs = cfg_.worker().envs_per_worker();  // none seen yet: assume one default worker
    return envs * cfg_.worker().steps_per_batch();
  }

  // Batches each worker should send on this version so that the fit (and no more than the run)
  // gets what it needs: the fit's missing steps, or for a fit by episodes the episodes still
  // missing spread over the environments, each up to a full horizon.
  uint32_t batches_for(int64_t steps_needed) const {
    const int64_t r = round_steps();
    return uint32_t(std::max<int64_t>(1, (steps_needed + r - 1) / r));
  }
  uint32_t batches_for_next_fit() const {
    int64_t need = sched_.steps_wanted();
    if (pc_.episodes_per_fit() > 0) {
      const int64_t eps = std::max<int64_t>(1, sched_.episodes_wanted());
      const int64_t envs = round_steps() / cfg_.worker().steps_per_batch();
      const int64_t by_eps = (eps + envs - 1) / envs * std::max(1, task_->spec().max_episode_steps) * envs;
      need = need < 0 ? by_eps : std::min(need, by_eps);
    }
    return batches_for(std::max<int64_t>(need, 1));
  }

  // Every live worker delivered its quota and the fit still lacks data (a worker left, or
  // episodes run longer than estimated): raise the quota of the same version.
  void top_up_if_starved() {
    if (sched_.run_done() || now_seconds() - last_data_ < 0.5) return;
    const double now = now_seconds();
    bool all_done = false;
    for (auto& [k, v] : roster_.views()) {
      if (!roster_.live(v, now)) continue;
      auto it = delivered_.find(v.last.worker_id());
      const bool done = it != delivered_.end() && it->second >= quota_;
      const bool idle = v.last.state() == "throttled" && v.last.policy_version() == version_;
      if (!done && !idle) return;
      all_done = true;
    }
    if (!all_done) return;
    int64_t need = sched_.steps_wanted();
    if (pc_.episodes_per_fit() > 0) need = round_steps();
    quota_ += batches_for(std::max<int64_t>(need, 1));
    ++top_ups_;
    last_data_ = now_seconds();
    write_weights();
  }

  size_t drain_batches(size_t max) override {
    size_t n = 0;
    while (n < max && batches_in_.take(batch_)) {
      ++n;
      if (!accept_batch(version_)) continue;
      if (pending_.n == 0) continue;  // end of stream
      last_data_ = now_seconds();
      if (batch_.policy_version() + uint64_t(pc_.max_policy_lag()) < version_ || sched_.run_done()) {
        // Made by a policy older than the lag allows (or after the run's end): counted, not used.
        ++stale_total_;
        ++stale_fit_;
        continue;
      }
      if (batch_.policy_version() == version_) delivered_[batch_.worker_id()] += 1;
      storage_.add(int(batch_.num_steps()), int(batch_.num_envs()), pending_.obs.data(), pending_.actions.data(),
                   pending_.rewards.data(), pending_.terminated.data(), batch_.truncated().data(),
                   batch_.log_probs().data(), pending_.next_obs.data(), batch_.policy_version());
      sched_.on_data(pending_.n, int64_t(episodes_.size()));
      for (auto& e : episodes_) {
        record_episode(e.episode_return);
        ++fit_episodes_;
        fit_metric_sums_.resize(task_->spec().metric_names.size(), 0.0);
        for (size_t i = 0; i < fit_metric_sums_.size() && i < e.metrics.size(); ++i) fit_metric_sums_[i] += e.metrics[i];
      }
    }
    return n;
  }

  void fit(double elapsed) {
    const double t = now_seconds();
    const FitScheduler::Fit f = sched_.take_fit();
    PpoSamples samples;
    storage_.take(f.steps_used, [this](const float* o, int64_t n) { return ppo_.values(o, n); }, pc_.gamma(),
                  pc_.gae_lambda(), version_, samples);
    const PpoStats st = ppo_.fit(samples);
    require_finite_update("ppo", ppo_.fits(),
                          {{"value loss", st.value_loss}, {"policy loss", st.policy_loss}, {"kl", st.kl}});
    // The normalizer moves between versions only, so a version is one fixed policy.
    if (pc_.normalize_observations()) ppo_.normalizer().update(samples.obs.data(), samples.n);
    const double fit_s = now_seconds() - t;
    last_stats_ = st;
    const uint64_t fitted = version_;
    ++version_;
    quota_ = batches_for_next_fit();
    if (!sched_.run_done()) publish_weights();
    else policy_ = ppo_.export_policy(version_);
    const bool eval_now = pc_.eval_every_fits() > 0 && ppo_.fits() % pc_.eval_every_fits() == 0;
    if (eval_now) evaluate(cfg_.eval().episodes(), elapsed, "eval");
    const double mean_ret = mean_recent_return();
    const auto& c = ingest_.counters();
    std::ostringstream o;
    o << "fit " << ppo_.fits() << " | v" << fitted << " -> v" << version_ << " | steps used " << f.steps_used
      << " carried " << f.steps_carried << " | stale dropped " << stale_fit_ << " | kl " << fmt("%.4f", st.kl)
      << " lr " << fmt("%.3g", st.learning_rate) << " clip " << fmt("%.3f", st.clip_fraction) << " | value loss "
      << fmt("%.4g", st.value_loss) << " entropy " << fmt("%.3f", st.entropy) << " | return " << fmt("%.1f", mean_ret)
      << " eval " << fmt("%.1f", last_eval_.mean) << " | " << fmt("%.2f", fit_s) << " s fit, " << c.env_steps
      << " env steps, " << fmt("%.1f", elapsed) << " s";
    log(o.str());
    csv_ << fmt("%.2f", elapsed) << ',' << ppo_.fits() << ',' << fitted << ',' << c.env_steps << ',' << f.steps_used
         << ',' << f.steps_carried << ',' << stale_fit_ << ',' << fmt("%.3f", fit_s) << ',' << fmt("%.6g", st.kl) << ','
         << fmt("%.6g", st.learning_rate) << ',' << fmt("%.4f", st.clip_fraction) << ',' << fmt("%.6g", st.value_loss)
         << ',' << fmt("%.6g", st.policy_loss) << ',' << fmt("%.5g", st.entropy) << ',' << fmt("%.3f", mean_ret) << ','
         << (eval_now ? fmt("%.3f", last_eval_.mean) : "") << ',' << (eval_now ? fmt("%.3f", last_eval_.min) : "")
         << ',' << (eval_now ? fmt("%.3f", last_eval_.max) : "") << ','
         << (eval_now ? fmt("%.1f", last_eval_.mean_length) : "") << ',' << c.ok << ',' << c.lost << ','
         << c.duplicate << ',' << c.invalid << ',' << stale_total_ << ',' << live_workers() << ',' << fit_episodes_;
    const size_t nm = task_->spec().metric_names.size();
    for (size_t i = 0; i < nm; ++i)
      csv_ << ',' << (fit_episodes_ > 0 && i < fit_metric_sums_.size() ? fmt("%.5g", fit_metric_sums_[i] / fit_episodes_) : "");
    for (size_t i = 0; i < nm; ++i)
      csv_ << ',' << (eval_now && i < last_eval_.metrics.size() ? fmt("%.5g", last_eval_.metrics[i]) : "");
    csv_ << '\n';
    csv_.flush();
    fit_episodes_ = 0;
    fit_metric_sums_.assign(nm, 0.0);
    stale_fit_ = 0;
  }

  EvalReport evaluate(int episodes, double elapsed, const std::string& label) {
    auto recs = evaluate_policy(task_, policy_, episodes, cfg_.seed() + 1000003ull * ++evals_);
    EvalReport r = summarize(recs, task_->spec().metric_names.size());
    last_eval_ = r;
    std::string metrics;
    for (size_t i = 0; i < r.metrics.size(); ++i)
      metrics += ", " + task_->spec().metric_names[i] + " " + fmt("%.3f", r.metrics[i]);
    log(label + ": mean return " + fmt("%.1f", r.mean) + " (min " + fmt("%.1f", r.min) + ", max " + fmt("%.1f", r.max) +
        ") over " + std::to_string(r.episodes) + " deterministic episodes, length " + fmt("%.1f", r.mean_length) +
        metrics + " (policy v" + std::to_string(policy_.version) + ", " + std::to_string(ppo_.fits()) + " fits, " +
        fmt("%.1f", elapsed) + " s)");
    record_evaluation(r.mean, policy_.version, ppo_.updates(), elapsed);
    return r;
  }

  void progress(double elapsed, double window) override {
    const auto& c = ingest_.counters();
    const Window w = take_window(window);
    farm::msg::LearnerStats st = base_stats(elapsed, w);
    st.updates(ppo_.updates());
    st.updates_per_second(0);
    st.buffer_fill(pc_.steps_per_fit() > 0 ? double(storage_.steps()) / double(pc_.steps_per_fit()) : 0.0);
    st.critic_loss(last_stats_.value_loss);
    st.actor_loss(last_stats_.policy_loss);
    st.eval_return(last_eval_.mean);
    stats_out_.write(st);
    log(fmt("%7.1fs", elapsed) + " | in " + fmt("%.0f", w.in_rate) + " steps/s (" + std::to_string(c.env_steps) +
        ") | v" + std::to_string(version_) + " collecting " + std::to_string(sched_.fit_steps()) + " steps, quota " +
        std::to_string(quota_) + " batches/worker | batches ok " + std::to_string(c.ok) + " lost " +
        std::to_string(c.lost) + " dup " + std::to_string(c.duplicate) + " invalid " + std::to_string(c.invalid) +
        " stale " + std::to_string(stale_total_) + " | workers " + std::to_string(live_workers()));
  }

  std::string should_stop(double elapsed) const override {
    if (sched_.run_done() && !sched_.fit_due()) {
      if (pc_.steps_per_run() > 0 && sched_.run_steps() >= pc_.steps_per_run())
        return "run length " + std::to_string(pc_.steps_per_run()) + " steps";
      return "run length " + std::to_string(pc_.episodes_per_run()) + " episodes";
    }
    return limit_reached(elapsed, last_eval_.mean, ppo_.updates());
  }

  void checkpoint(double elapsed) override {
    config::CheckpointManifest m = base_manifest(version_, ppo_.updates(), elapsed);
    m.set_run_steps(uint64_t(sched_.run_steps()));
    rng_to_manifest(nullptr, m);
    const double t = now_seconds();
    write_checkpoint(ckpt_dir_, m, [this](const std::string& tmp) { save_networks(tmp); });
    log("checkpoint " + ckpt_dir_ + " (" + fmt("%.2f", now_seconds() - t) + " s)");
  }

  void save_networks(const std::string& dir) const override {
    farm::save_networks(dir, "ppo", [this](const std::string& d) { ppo_.save(d); });
  }

  void final_evaluation(double elapsed) override { final_eval_ = evaluate(cfg_.eval().final_episodes(), elapsed, "final"); }

  void write_summary(double elapsed, const std::string& reason) override {
    const auto& c = ingest_.counters();
    const EvalReport& fe = final_eval_;
    std::ostringstream o;
    o << summary_head(elapsed, reason) << "updates           " << ppo_.updates() << " (" << ppo_.fits() << " fits)\n"
      << "policy versions   " << version_ << "\n"
      << "episodes          " << episodes_total_ << "\n"
      << "final eval return " << fmt("%.1f", fe.mean) << " (mean of " << fe.episodes << " deterministic episodes)\n"
      << "final eval range  min " << fmt("%.1f", fe.min) << ", max " << fmt("%.1f", fe.max) << ", length "
      << fmt("%.1f", fe.mean_length) << "\n";
    for (size_t i = 0; i < fe.metrics.size(); ++i)
      o << "final eval metric " << task_->spec().metric_names[i] << " " << fmt("%.4f", fe.metrics[i]) << "\n";
    o << "best eval return  " << fmt("%.1f", best_eval_) << "\n"
      << "batches           ok " << c.ok << ", lost " << c.lost << ", duplicate " << c.duplicate << ", invalid "
      << c.invalid << ", stale " << stale_total_ << "\n"
      << "quota top-ups     " << top_ups_ << "\n"
      << summary_workers();
    emit_summary(o.str());
  }

  config::PpoConfig pc_;
  Ppo ppo_;
  RolloutStorage storage_;
  FitScheduler sched_;
  uint64_t fit_episodes_ = 0;              // episodes finished since the last fit
  std::vector<double> fit_metric_sums_;    // their task metrics, summed
  std::map<std::string, uint32_t> delivered_;  // batches of the current version per worker id
  PolicyParams policy_;
  PpoStats last_stats_{};
  EvalReport last_eval_, final_eval_;
  uint64_t version_ = 0;
  uint32_t quota_ = 1;
  uint64_t stale_total_ = 0, stale_fit_ = 0, top_ups_ = 0;
  double last_data_ = 0, first_join_ = 0;
  bool published_ = false;
  static constexpr double kJoinGraceSeconds = 1.0;
};

}  // namespace

int run_ppo_learner(const LearnerRunOptions& opt, const config::ExperimentConfig& cfg,
                    const std::atomic<bool>& interrupted) {
  check_ppo_config(cfg.ppo());
  PpoLearner l(opt, cfg, interrupted);
  return l.run();
}

}  // namespace farm
