#include "ppo_algorithm.h"

#include <ATen/CPUGeneratorImpl.h>

#include <algorithm>
#include <cmath>
#include <deque>
#include <filesystem>
#include <map>
#include <mutex>
#include <random>
#include <sstream>
#include <stdexcept>

#include "divergence.h"
#include "fit_scheduler.h"
#include "meter.h"
#include "ppo.h"
#include "rng_state.h"
#include "rollout_storage.h"

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

class PpoAlgorithm final : public Algorithm {
 public:
  PpoAlgorithm(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec)
      : cfg_(cfg),
        spec_(spec),
        pc_(cfg.ppo()),
        ppo_(pc_, spec.obs_dim, spec.act_dim, cfg_.seed()),
        storage_(spec.obs_dim, spec.act_dim),
        sched_(plan_of(pc_)),
        async_(pc_.mode() == "async") {}

  std::string describe() const override {
    const auto& p = pc_;
    return std::string(async_ ? "asynchronous " : "") + "PPO (" + p.variant() + ") " +
           ppo_.export_policy(0).layout.describe() + " actor, " +
           (p.steps_per_fit() > 0 ? std::to_string(p.steps_per_fit()) + " steps"
                                  : std::to_string(p.episodes_per_fit()) + " episodes") +
           " per fit, max policy lag " + std::to_string(p.max_policy_lag()) +
           (p.surrogate() == "proximal" ? ", proximal surrogate" : "");
  }

  uint64_t version() const override { return version_; }
  int64_t updates() const override { return ppo_.updates(); }
  double last_eval() const override { return last_eval_.mean; }

  void warm_up(Farm& farm) override {
    if (!pc_.warm_up() || !ppo_.device().is_cuda()) return;
    const double s = ppo_warm_up(pc_, spec_.obs_dim, spec_.act_dim, cfg_.seed(), ppo_.device().str());
    farm.log("warm-up on " + ppo_.device().str() + ": one fit of a throwaway copy on synthetic steps, " +
             fmt("%.2f", s) + " s, before the run starts (ppo.warm_up)");
  }

  void start(Farm&) override { last_data_ = now_seconds(); }

  double train(Farm& farm, bool got_data) override {
    if (!published_) {
      // The first weights wait for the first worker and a short grace for the others, so the
      // first quota is shared out over the workers that are there.
      const double first_join = farm.first_worker_heard();
      if (first_join > 0 && now_seconds() - first_join >= kJoinGraceSeconds) {
        quota_ = batches_for_next_fit(farm);
        publish_weights(farm);
        published_ = true;
        return 0;
      }
      return 0.05;
    }
    if (sched_.fit_due() && async_) drop_stale();
    if (sched_.fit_due()) {
      fit(farm, farm.elapsed());
      return 0;
    }
    if (got_data) return 0;
    top_up_if_starved(farm);
    return 0.01;
  }

  std::string csv_header() const override {
    std::string h =
        "elapsed_s,fit,policy_version,env_steps,steps_used,steps_carried,stale_dropped,lag_mean,lag_max,fit_seconds,"
        "kl,learning_rate,clip_fraction,value_loss,policy_loss,entropy,mean_return,eval_return,"
        "eval_min,eval_max,eval_length,batches_ok,batches_lost,batches_duplicate,batches_invalid,"
        "batches_stale,workers,episodes";
    // The task's own per-episode metrics: means over the episodes finished since the last fit
    // (train_*) and over the evaluation episodes (eval_*).
    for (const auto& m : spec_.metric_names) h += ",train_" + m;
    for (const auto& m : spec_.metric_names) h += ",eval_" + m;
    return h;
  }

  void load(const std::string& dir) override { ppo_.load((fs::path(dir) / "ppo").string()); }

  std::string resumed(const config::CheckpointManifest& m, uint64_t env_steps) override {
    // Past any version the crashed learner published after its checkpoint, as the off-policy
    // learner does: a worker holding the same number would keep the old weights.
    version_ = m.policy_version() + 1 + kResumeVersionSkip;
    // The run's counters go on from where they were; data not yet fitted was not kept.
    rng_from_manifest(m, nullptr);
    sched_.restore_run(int64_t(m.run_steps()), int64_t(m.episodes()), ppo_.fits());
    return "(next policy v" + std::to_string(version_) + "): " + std::to_string(ppo_.fits()) + " fits, " +
           std::to_string(env_steps) + " env steps, learning rate " + fmt("%.3g", ppo_.learning_rate());
  }

  void hold_workers(Farm& farm) override {
    if (!published_) return;
    quota_ = 1;
    farm.publish(policy_, quota_);
  }

 private:
  // The current version's weights with the current quota; re-sent with a larger quota to top up.
  void publish_weights(Farm& farm) {
    policy_ = ppo_.export_policy(version_);
    delivered_.clear();
    farm.publish(policy_, quota_);
  }

  // Steps one round (one batch from every live worker) brings.
  int64_t round_steps(const Farm& farm) const {
    int64_t envs = 0;
    for (const auto& w : farm.live_workers()) envs += w.envs;
    if (envs == 0) envs = cfg_.worker().envs_per_worker();  // none seen yet: assume one default worker
    return envs * cfg_.worker().steps_per_batch();
  }

  // Batches each worker should send on this version so that the fit (and no more than the run)
  // gets what it needs: the fit's missing steps, or for a fit by episodes the episodes still
  // missing spread over the environments, each up to a full horizon.
  uint32_t batches_for(const Farm& farm, int64_t steps_needed) const {
    const int64_t r = round_steps(farm);
    return uint32_t(std::max<int64_t>(1, (steps_needed + r - 1) / r));
  }
  uint32_t batches_for_next_fit(const Farm& farm) const {
    // Asynchronous: what the lag window can still fit. This version's last step is fitted once the
    // S steps already held, those on their way (the arrival rate times one fit: what came in while
    // the learner fitted, which S does not hold yet) and its own Q are, (S + in flight + Q) /
    // steps_per_fit fits from now: within max_policy_lag versions when Q <= (max_policy_lag + 1) *
    // steps_per_fit - S - in flight. A learner that keeps up holds little, so workers run on
    // through its fits; one that falls behind holds more, and the workers wait instead of
    // simulating steps that would arrive too old to use.
    if (async_) {
      const int64_t in_flight = int64_t(arrival_rate_ * last_fit_seconds_);
      return batches_for(
          farm, std::max<int64_t>(1, (pc_.max_policy_lag() + 1) * pc_.steps_per_fit() - storage_.steps() - in_flight));
    }
    int64_t need = sched_.steps_wanted();
    if (pc_.episodes_per_fit() > 0) {
      const int64_t eps = std::max<int64_t>(1, sched_.episodes_wanted());
      const int64_t envs = round_steps(farm) / cfg_.worker().steps_per_batch();
      const int64_t by_eps = (eps + envs - 1) / envs * std::max(1, spec_.max_episode_steps) * envs;
      need = need < 0 ? by_eps : std::min(need, by_eps);
    }
    return batches_for(farm, std::max<int64_t>(need, 1));
  }

  // Every live worker delivered its quota and the fit still lacks data (a worker left, or
  // episodes run longer than estimated): raise the quota of the same version.
  void top_up_if_starved(Farm& farm) {
    if (sched_.run_done() || now_seconds() - last_data_ < 0.5) return;
    bool all_done = false;
    for (const auto& w : farm.live_workers()) {
      auto it = delivered_.find(w.worker_id);
      const bool done = it != delivered_.end() && it->second >= quota_;
      const bool idle = w.state == "throttled" && w.policy_version == version_;
      if (!done && !idle) return;
      all_done = true;
    }
    if (!all_done) return;
    int64_t need = sched_.steps_wanted();
    if (pc_.episodes_per_fit() > 0) need = round_steps(farm);
    quota_ += batches_for(farm, std::max<int64_t>(need, 1));
    ++top_ups_;
    last_data_ = now_seconds();
    farm.publish(policy_, quota_);
  }

 public:
  bool take(const Batch& b) override {
    const Transitions& rows = *b.rows;
    if (rows.n == 0) return false;  // end of stream
    last_data_ = now_seconds();
    if (b.policy_version + uint64_t(pc_.max_policy_lag()) < version_ || sched_.run_done()) {
      // Made by a policy older than the lag allows (or after the run's end): counted, not used.
      ++stale_total_;
      ++stale_fit_;
      stale_steps_ += uint64_t(rows.n);
      return false;
    }
    if (b.policy_version == version_) delivered_[b.worker_id] += 1;
    arrived_ += uint64_t(rows.n);
    storage_.add(b.num_steps, b.num_envs, rows.obs.data(), rows.actions.data(), rows.rewards.data(),
                 rows.terminated.data(), b.truncated, b.log_probs, rows.next_obs.data(), b.policy_version);
    sched_.on_data(rows.n, int64_t(b.episodes->size()));
    for (const auto& e : *b.episodes) {
      ++fit_episodes_;
      fit_metric_sums_.resize(spec_.metric_names.size(), 0.0);
      for (size_t i = 0; i < fit_metric_sums_.size() && i < e.metrics.size(); ++i) fit_metric_sums_[i] += e.metrics[i];
    }
    return true;
  }

  void fit(Farm& farm, double elapsed) {
    const double t = now_seconds();
    const FitScheduler::Fit f = sched_.take_fit();
    PpoSamples samples;
    RolloutStorage::VTrace vtrace;
    vtrace.log_prob = [this](const float* o, const float* a, int64_t n) { return ppo_.log_probs(o, a, n); };
    vtrace.rho_bar = pc_.vtrace_rho_bar();
    vtrace.c_bar = pc_.vtrace_c_bar();
    std::map<uint64_t, int64_t> by_version;
    storage_.take(
        f.steps_used, [this](const float* o, int64_t n) { return ppo_.values(o, n); }, pc_.gamma(), pc_.gae_lambda(),
        version_, samples, async_ ? &vtrace : nullptr, &by_version);
    // The lag of what this fit uses: versions behind the one being fitted, by steps.
    double lag_sum = 0;
    uint64_t lag_max = 0;
    std::string lags;
    for (auto it = by_version.rbegin(); it != by_version.rend(); ++it) {
      const uint64_t lag = version_ - it->first;
      lag_sum += double(lag) * double(it->second);
      lag_max = std::max(lag_max, lag);
      lag_steps_[lag] += uint64_t(it->second);
      lags += (lags.empty() ? "" : " ") + std::to_string(lag) + ":" +
              fmt("%.0f%%", 100.0 * double(it->second) / double(std::max<int64_t>(1, f.steps_used)));
    }
    const double lag_mean = lag_sum / double(std::max<int64_t>(1, f.steps_used));
    used_steps_ += uint64_t(f.steps_used);
    const PpoStats st = ppo_.fit(samples);
    require_finite_update("ppo", ppo_.fits(),
                          {{"value loss", st.value_loss}, {"policy loss", st.policy_loss}, {"kl", st.kl}});
    // The normalizer moves between versions only, so a version is one fixed policy.
    if (pc_.normalize_observations()) ppo_.normalizer().update(samples.obs.data(), samples.n);
    const double fit_s = now_seconds() - t;
    // Steps/s arriving over the last fit's cycle (waiting for data, then fitting).
    if (last_fit_end_ > 0 && now_seconds() > last_fit_end_)
      arrival_rate_ = double(arrived_) / (now_seconds() - last_fit_end_);
    arrived_ = 0;
    last_fit_end_ = now_seconds();
    last_fit_seconds_ = fit_s;
    last_stats_ = st;
    const uint64_t fitted = version_;
    ++version_;
    quota_ = batches_for_next_fit(farm);
    if (!sched_.run_done() && !stopping_)
      publish_weights(farm);
    else
      policy_ = ppo_.export_policy(version_);
    // The evaluation is asked now and answered later (evaluated()); this fit's CSV row waits for it.
    const bool eval_now = !stopping_ && pc_.eval_every_fits() > 0 && ppo_.fits() % pc_.eval_every_fits() == 0 &&
                          ask_evaluation(farm, cfg_.eval().episodes(), elapsed, "eval");
    const FarmFigures c = farm.figures();
    const double mean_ret = c.mean_return;
    std::ostringstream o;
    o << "fit " << ppo_.fits() << " | v" << fitted << " -> v" << version_ << " | steps used " << f.steps_used
      << " carried " << f.steps_carried << " | stale dropped " << stale_fit_ << " | lag " << lags << " | kl "
      << fmt("%.4f", st.kl) << " lr " << fmt("%.3g", st.learning_rate) << " clip " << fmt("%.3f", st.clip_fraction)
      << " | value loss " << fmt("%.4g", st.value_loss) << " entropy " << fmt("%.3f", st.entropy) << " | return "
      << fmt("%.1f", mean_ret) << " eval " << fmt("%.1f", last_eval_.mean) << " | " << fmt("%.2f", fit_s) << " s fit, "
      << c.env_steps << " env steps, " << fmt("%.1f", elapsed) << " s";
    farm.log(o.str());
    CsvRow row;
    std::ostringstream head, tail;
    head << fmt("%.2f", elapsed) << ',' << ppo_.fits() << ',' << fitted << ',' << c.env_steps << ',' << f.steps_used
         << ',' << f.steps_carried << ',' << stale_fit_ << ',' << fmt("%.3f", lag_mean) << ',' << lag_max << ','
         << fmt("%.3f", fit_s) << ',' << fmt("%.6g", st.kl) << ',' << fmt("%.6g", st.learning_rate) << ','
         << fmt("%.4f", st.clip_fraction) << ',' << fmt("%.6g", st.value_loss) << ',' << fmt("%.6g", st.policy_loss)
         << ',' << fmt("%.5g", st.entropy) << ',' << fmt("%.3f", mean_ret) << ',';
    tail << ',' << c.ok << ',' << c.lost << ',' << c.duplicate << ',' << c.invalid << ',' << stale_total_ << ','
         << c.workers << ',' << fit_episodes_;
    const size_t nm = spec_.metric_names.size();
    for (size_t i = 0; i < nm; ++i)
      tail << ','
           << (fit_episodes_ > 0 && i < fit_metric_sums_.size() ? fmt("%.5g", fit_metric_sums_[i] / fit_episodes_)
                                                                : "");
    row.head = head.str();
    row.tail = tail.str();
    row.waits = eval_now;
    row.version = policy_.version;
    rows_.push_back(std::move(row));
    write_rows(farm);
    fit_episodes_ = 0;
    fit_metric_sums_.assign(nm, 0.0);
    stale_fit_ = 0;
  }

  bool ask_evaluation(Farm& farm, int episodes, double elapsed, const std::string& label) {
    EvalAsk ask;
    ask.label = label;
    ask.episodes = episodes;
    ask.version = policy_.version;
    ask.updates = ppo_.updates();
    ask.elapsed = elapsed;
    ask.progress = std::to_string(ppo_.fits()) + " fits";
    return farm.ask_evaluation(policy_, ask);
  }

 public:
  void evaluated(Farm& farm, const EvalAsk& ask, const EvalReport& r) override {
    last_eval_ = r;
    if (ask.label == "final") final_eval_ = r;
    std::string metrics;
    for (size_t i = 0; i < r.metrics.size() && i < spec_.metric_names.size(); ++i)
      metrics += ", " + spec_.metric_names[i] + " " + fmt("%.3f", r.metrics[i]);
    farm.log(ask.label + ": mean return " + fmt("%.1f", r.mean) + " (min " + fmt("%.1f", r.min) + ", max " +
             fmt("%.1f", r.max) + ") over " + std::to_string(r.episodes) + " deterministic episodes, length " +
             fmt("%.1f", r.mean_length) + metrics + " (policy v" + std::to_string(ask.version) + ", " + ask.progress +
             ", " + fmt("%.1f", ask.elapsed) + " s)");
    farm.record_evaluation(r, ask.version, ask.updates, ask.elapsed);
    if (ask.label == "eval") settle_row(farm, ask.version, &r);
  }

  void not_evaluated(Farm& farm, const EvalAsk& ask) override {
    if (ask.label == "eval") settle_row(farm, ask.version, nullptr);
  }

 private:
  // A fit's CSV row: its evaluation columns (between head and tail, and the eval_* metrics at the
  // end) are filled when the evaluation asked at that fit is answered. Rows are written in fit
  // order, so one that waits holds back the rows after it.
  struct CsvRow {
    std::string head, tail;
    bool waits = false;
    uint64_t version = 0;
    bool has_eval = false;
    EvalReport eval;
  };

  void settle_row(Farm& farm, uint64_t version, const EvalReport* r) {
    for (auto& row : rows_) {
      if (!row.waits || row.version != version) continue;
      row.waits = false;
      if (r) {
        row.has_eval = true;
        row.eval = *r;
      }
      break;
    }
    write_rows(farm);
  }

  void write_rows(Farm& farm) {
    while (!rows_.empty() && (!rows_.front().waits || rows_.size() > kMaxRowsHeld)) {
      const CsvRow& row = rows_.front();
      const bool e = row.has_eval;
      std::ostringstream csv;
      csv << row.head << (e ? fmt("%.3f", row.eval.mean) : "") << ',' << (e ? fmt("%.3f", row.eval.min) : "") << ','
          << (e ? fmt("%.3f", row.eval.max) : "") << ',' << (e ? fmt("%.1f", row.eval.mean_length) : "") << row.tail;
      for (size_t i = 0; i < spec_.metric_names.size(); ++i)
        csv << ',' << (e && i < row.eval.metrics.size() ? fmt("%.5g", row.eval.metrics[i]) : "");
      farm.csv_row(csv.str());
      rows_.pop_front();
    }
  }

 public:
  void progress(Farm& farm, const FarmFigures& c, double elapsed, AlgorithmStats* stats) override {
    stats->updates = ppo_.updates();
    stats->updates_per_second = 0;
    stats->buffer_fill = pc_.steps_per_fit() > 0 ? double(storage_.steps()) / double(pc_.steps_per_fit()) : 0.0;
    stats->critic_loss = last_stats_.value_loss;
    stats->actor_loss = last_stats_.policy_loss;
    stats->eval_return = last_eval_.mean;
    farm.log(fmt("%7.1fs", elapsed) + " | in " + fmt("%.0f", c.in_rate) + " steps/s (" + std::to_string(c.env_steps) +
             ") | v" + std::to_string(version_) + " collecting " + std::to_string(sched_.fit_steps()) +
             " steps, quota " + std::to_string(quota_) + " batches/worker | batches ok " + std::to_string(c.ok) +
             " lost " + std::to_string(c.lost) + " dup " + std::to_string(c.duplicate) + " invalid " +
             std::to_string(c.invalid) + " stale " + std::to_string(stale_total_) + eval_counts(c) + " | workers " +
             std::to_string(c.workers));
  }

  std::string stop_reason() const override {
    if (sched_.run_done() && !sched_.fit_due()) {
      if (pc_.steps_per_run() > 0 && sched_.run_steps() >= pc_.steps_per_run())
        return "run length " + std::to_string(pc_.steps_per_run()) + " steps";
      return "run length " + std::to_string(pc_.episodes_per_run()) + " episodes";
    }
    return "";
  }

  void to_manifest(config::CheckpointManifest& m) const override {
    m.set_run_steps(uint64_t(sched_.run_steps()));
    rng_to_manifest(nullptr, m);
  }

  void save_networks(const std::string& dir) const override {
    fs::create_directories(fs::path(dir) / "ppo");
    ppo_.save((fs::path(dir) / "ppo").string());
  }
  PolicyParams policy() const override { return ppo_.export_policy(version_); }

  void final_evaluation(Farm& farm, double elapsed) override {
    fit_what_is_held(farm, elapsed);
    ask_evaluation(farm, cfg_.eval().final_episodes(), elapsed, "final");
  }

  // At a stop rule (goal, time): the steps that arrived before it and wait for a fit that would
  // have come go into one last fit, so the final policy (evaluated, checkpointed) is trained on
  // everything the workers sent in time; those within the lag window, and at least a mini-batch
  // of them. The workers are held already, so the new version is not published to them.
  // A learner behind its workers holds more than a fit: one fit at a time, each version's lag
  // window checked again after the one before.
  void fit_what_is_held(Farm& farm, double elapsed) {
    if (!published_) return;
    const int64_t least = std::max<int64_t>(1, pc_.mini_batch_size());
    for (;;) {
      if (async_) drop_stale();
      if (sched_.fit_steps() < least) return;
      if (!stopping_)
        farm.log("the " + std::to_string(sched_.fit_steps()) + " steps held at the stop go into a last fit");
      stopping_ = true;
      fit(farm, elapsed);
    }
  }

  // Steps that waited in the store while versions moved on past the window: counted, not used.
  void drop_stale() {
    const uint64_t lag = uint64_t(pc_.max_policy_lag());
    const int64_t dropped = storage_.drop_older_than(version_ > lag ? version_ - lag : 0);
    sched_.forget(dropped);
    stale_steps_ += uint64_t(dropped);
  }

  std::string summary(const FarmFigures& c, double) const override {
    const EvalReport& fe = final_eval_;
    std::ostringstream o;
    o << "updates           " << ppo_.updates() << " (" << ppo_.fits() << " fits)\n"
      << "policy versions   " << version_ << "\n"
      << "episodes          " << c.episodes << "\n"
      << "final eval return " << fmt("%.1f", fe.mean) << " (mean of " << fe.episodes << " deterministic episodes)\n"
      << "final eval range  min " << fmt("%.1f", fe.min) << ", max " << fmt("%.1f", fe.max) << ", length "
      << fmt("%.1f", fe.mean_length) << "\n";
    for (size_t i = 0; i < fe.metrics.size(); ++i)
      o << "final eval metric " << spec_.metric_names[i] << " " << fmt("%.4f", fe.metrics[i]) << "\n";
    o << best_eval_line(c) << "\n"
      << "batches           ok " << c.ok << ", lost " << c.lost << ", duplicate " << c.duplicate << ", invalid "
      << c.invalid << ", stale " << stale_total_ << "\n"
      << "quota top-ups     " << top_ups_ << "\n"
      << "mode              " << (async_ ? "async" : "sync") << ", max policy lag " << pc_.max_policy_lag()
      << ", surrogate " << pc_.surrogate() << "\n";
    // Every simulated step the learner was sent is fitted, counted stale, or still held at the end.
    const uint64_t held = uint64_t(storage_.steps()), unused = stale_steps_ + held;
    const uint64_t all = used_steps_ + unused;
    o << "steps unused      " << unused << " of " << all << " ("
      << fmt("%.2f", all > 0 ? 100.0 * double(unused) / double(all) : 0.0) << " %): stale " << stale_steps_
      << ", not fitted at the end " << held << "\n";
    std::string lags;
    for (const auto& [lag, n] : lag_steps_)
      lags += (lags.empty() ? "" : ", ") + std::to_string(lag) + ": " +
              fmt("%.1f %%", used_steps_ > 0 ? 100.0 * double(n) / double(used_steps_) : 0.0);
    o << "lag of fitted     " << (lags.empty() ? "none" : lags) << " (versions behind the fitted one, by steps)\n";
    return o.str();
  }

 private:
  const config::ExperimentConfig cfg_;
  const robots::TaskSpec spec_;
  config::PpoConfig pc_;
  Ppo ppo_;
  RolloutStorage storage_;
  FitScheduler sched_;
  uint64_t fit_episodes_ = 0;                  // episodes finished since the last fit
  std::vector<double> fit_metric_sums_;        // their task metrics, summed
  std::map<std::string, uint32_t> delivered_;  // batches of the current version per worker id
  PolicyParams policy_;
  PpoStats last_stats_{};
  EvalReport last_eval_, final_eval_;
  std::deque<CsvRow> rows_;  // fits' CSV rows not yet written (the first waits for its evaluation)
  // Rows held back behind one evaluation at most; past this the oldest is written without it.
  static constexpr size_t kMaxRowsHeld = 256;
  uint64_t version_ = 0;
  uint32_t quota_ = 1;
  uint64_t stale_total_ = 0, stale_fit_ = 0, top_ups_ = 0;
  uint64_t stale_steps_ = 0, used_steps_ = 0;  // simulated steps counted stale, and fitted
  std::map<uint64_t, uint64_t> lag_steps_;     // fitted steps by lag, over the run
  uint64_t arrived_ = 0;                       // steps taken since the last fit ended
  double arrival_rate_ = 0, last_fit_end_ = 0, last_fit_seconds_ = 0;
  const bool async_;
  double last_data_ = 0;
  bool published_ = false;
  bool stopping_ = false;  // a stop rule fired: fits no longer publish or evaluate
  static constexpr double kJoinGraceSeconds = 1.0;
};

}  // namespace

double ppo_warm_up(const config::PpoConfig& pc_in, int obs_dim, int act_dim, uint64_t seed, const std::string& device) {
  const double t = now_seconds();
  auto gen = at::detail::getDefaultCPUGenerator();
  torch::Tensor cpu_state;
  {
    std::lock_guard<std::mutex> lock(gen.mutex());
    cpu_state = gen.get_state();
  }
  {
    config::PpoConfig pc = pc_in;
    pc.set_device(device);  // resolved: "auto" is said once, by the run's own networks
    Ppo ppo(pc, obs_dim, act_dim, seed);
    RolloutStorage storage(obs_dim, act_dim);
    const int T = 24, N = 64;  // a batch's shape; the fit's shapes are what matter
    const int64_t steps = pc.steps_per_fit() > 0 ? pc.steps_per_fit() : int64_t(T) * N;
    const uint64_t lag = uint64_t(std::max(0, pc.max_policy_lag()));
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    std::vector<float> obs(size_t(T) * N * obs_dim), next(obs.size()), act(size_t(T) * N * act_dim);
    std::vector<float> rew(size_t(T) * N);
    std::vector<uint8_t> term(rew.size(), 0), trunc(rew.size(), 0);
    for (int64_t added = 0, b = 0; added < steps; added += int64_t(T) * N, ++b) {
      for (auto* v : {&obs, &next, &act, &rew})
        for (float& x : *v) x = u(rng);
      term.assign(term.size(), 0);
      term[size_t(b) % term.size()] = 1;  // an episode ends in each batch
      const std::vector<float> lp = ppo.log_probs(obs.data(), act.data(), int64_t(T) * N);
      storage.add(T, N, obs.data(), act.data(), rew.data(), term.data(), trunc.data(), lp.data(), next.data(),
                  uint64_t(b) % (lag + 1));
    }
    RolloutStorage::VTrace vtrace;
    vtrace.log_prob = [&ppo](const float* o, const float* a, int64_t n) { return ppo.log_probs(o, a, n); };
    vtrace.rho_bar = pc.vtrace_rho_bar();
    vtrace.c_bar = pc.vtrace_c_bar();
    PpoSamples samples;
    storage.take(
        std::min(steps, storage.steps()), [&ppo](const float* o, int64_t n) { return ppo.values(o, n); }, pc.gamma(),
        pc.gae_lambda(), lag, samples, pc.mode() == "async" ? &vtrace : nullptr);
    ppo.fit(samples);
    (void)ppo.export_policy(1);
  }
  std::lock_guard<std::mutex> lock(gen.mutex());
  gen.set_state(cpu_state);
  return now_seconds() - t;
}

std::unique_ptr<Algorithm> make_ppo(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  if (spec.num_actions > 0)
    throw std::invalid_argument("algorithm \"ppo\" needs continuous actions; task '" + cfg.task().name() +
                                "' has discrete ones");
  return std::make_unique<PpoAlgorithm>(cfg, spec);
}

}  // namespace farm
