// The round pacing (pacing.h) of an on-policy algorithm (PPO): each policy version goes out with a
// quota of batches per worker, sized so that one round brings what the next fit needs (in
// asynchronous mode, what the lag window can still fit); batches made by a version older than the
// lag window are counted stale and not used; the algorithm fits whenever it holds one fit's data;
// the quota is topped up when every worker delivered and the fit still lacks data. One log line
// and CSV row per fit, the row written once the evaluation asked at that fit is answered.
#include <algorithm>
#include <cmath>
#include <deque>
#include <map>
#include <sstream>
#include <string>

#include "meter.h"
#include "pacing.h"
#include "pacing_stats.h"

namespace farm {

namespace {

class RoundPacing final : public Pacing {
 public:
  RoundPacing(std::unique_ptr<Algorithm> algo, const config::ExperimentConfig& cfg, const robots::TaskSpec& spec)
      : Pacing(std::move(algo), cfg, spec),
        pc_(cfg.ppo()),
        async_(pc_.mode() == "async"),
        fit_schema_(stats::fit_schema(spec_.metric_names)),
        rows_(spec_.metric_names) {}

  uint64_t version() const override { return version_; }
  double last_eval() const override { return last_eval_.mean; }

  const StatsSchema& row_schema() const override { return fit_schema_; }

  void start(Farm&) override { arrivals_.last_data = now_seconds(); }

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
    if (algo_->ready() > 0 && async_) drop_stale();
    if (algo_->ready() > 0) {
      fit(farm, farm.elapsed());
      return 0;
    }
    if (got_data) return 0;
    top_up_if_starved(farm);
    return 0.01;
  }

  bool take(const Batch& b) override {
    const Transitions& rows = *b.rows;
    if (rows.n == 0) return false;  // end of stream
    arrivals_.last_data = now_seconds();
    if (b.policy_version + uint64_t(pc_.max_policy_lag()) < version_ || !algo_->holding().run_done.empty()) {
      // Made by a policy older than the lag allows (or after the run's end): counted, not used.
      ++counts_.stale_batches;
      ++counts_.stale_fit;
      counts_.stale_steps += uint64_t(rows.n);
      return false;
    }
    if (b.policy_version == version_) delivered_[b.worker_id] += 1;
    if (const auto it = last_sent_.find(b.worker_id); it != last_sent_.end())
      it->second = arrivals_.last_data;
    else if (last_sent_.size() < kMaxSending)
      last_sent_.emplace(b.worker_id, arrivals_.last_data);
    arrivals_.steps += uint64_t(rows.n);
    algo_->insert(b);
    for (const auto& e : *b.episodes) fit_episodes_.add(e.metrics, spec_.metric_names.size());
    return true;
  }

  void hold_workers(Farm& farm) override {
    if (!published_) return;
    quota_ = 1;
    farm.publish(policy_, quota_);
  }

  StatsRecord progress(Farm&, const FarmFigures& c, double elapsed) override {
    const Holding h = algo_->holding();
    StatsRecord r(period_schema_);
    put_figures(r, c, elapsed);
    r.set(stats::kPolicyVersion, double(version_));
    r.set(stats::kStepsCollecting, double(h.rows));
    r.set(stats::kQuota, quota_);
    r.set(stats::kUpdates, double(algo_->updates()));
    r.set(stats::kBufferFill, h.capacity > 0 ? double(h.rows) / double(h.capacity) : 0.0);
    r.set(stats::kValueLoss, latest("value loss"));
    r.set(stats::kPolicyLoss, latest("policy loss"));
    r.set(stats::kEvalReturn, last_eval_.mean);
    r.set(stats::kBatchesStale, double(counts_.stale_batches));
    return r;
  }

  std::string stop_reason() const override { return algo_->ready() > 0 ? "" : algo_->holding().run_done; }

  void final_evaluation(Farm& farm, double elapsed) override {
    fit_what_is_held(farm, elapsed);
    ask_evaluation(farm, cfg_.eval().final_episodes(), elapsed, "final");
  }

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
    if (ask.label == "eval") rows_.settle(farm, ask.version, &r);
  }

  void not_evaluated(Farm& farm, const EvalAsk& ask) override {
    if (ask.label == "eval") rows_.settle(farm, ask.version, nullptr);
  }

  std::string summary(const FarmFigures& c, double) const override {
    const EvalReport& fe = final_eval_;
    std::ostringstream o;
    o << "updates           " << algo_->updates() << " (" << fits_ << " fits)\n"
      << "policy versions   " << version_ << "\n"
      << "episodes          " << c.episodes << "\n"
      << "final eval return " << fmt("%.1f", fe.mean) << " (mean of " << fe.episodes << " deterministic episodes)\n"
      << "final eval range  min " << fmt("%.1f", fe.min) << ", max " << fmt("%.1f", fe.max) << ", length "
      << fmt("%.1f", fe.mean_length) << "\n";
    for (size_t i = 0; i < fe.metrics.size(); ++i)
      o << "final eval metric " << spec_.metric_names[i] << " " << fmt("%.4f", fe.metrics[i]) << "\n";
    o << best_eval_line(c) << "\n"
      << "batches           ok " << c.ok << ", lost " << c.lost << ", duplicate " << c.duplicate << ", invalid "
      << c.invalid << ", stale " << counts_.stale_batches << "\n"
      << "quota top-ups     " << counts_.top_ups << "\n"
      << "mode              " << (async_ ? "async" : "sync") << ", max policy lag " << pc_.max_policy_lag()
      << ", surrogate " << pc_.surrogate() << "\n";
    // Every simulated step the learner was sent is fitted, counted stale, or still held at the end.
    const uint64_t held = uint64_t(algo_->holding().rows), unused = counts_.stale_steps + held;
    const uint64_t all = counts_.used_steps + unused;
    o << "steps unused      " << unused << " of " << all << " ("
      << fmt("%.2f", all > 0 ? 100.0 * double(unused) / double(all) : 0.0) << " %): stale " << counts_.stale_steps
      << ", not fitted at the end " << held << "\n";
    std::string lags;
    for (const auto& [lag, n] : counts_.lag_steps)
      lags += (lags.empty() ? "" : ", ") + std::to_string(lag) + ": " +
              fmt("%.1f %%", counts_.used_steps > 0 ? 100.0 * double(n) / double(counts_.used_steps) : 0.0);
    o << "lag of fitted     " << (lags.empty() ? "none" : lags) << " (versions behind the fitted one, by steps)\n";
    return o.str();
  }

  nlohmann::json summary_fields() const override {
    nlohmann::json by_lag = nlohmann::json::object();  // steps fitted, by versions behind the fitted one
    for (const auto& [lag, n] : counts_.lag_steps) by_lag[std::to_string(lag)] = n;
    return {{"fits", fits_},
            {"batches_stale", counts_.stale_batches},
            {"quota_top_ups", counts_.top_ups},
            {"mode", async_ ? "async" : "sync"},
            {"max_policy_lag", pc_.max_policy_lag()},
            {"steps_fitted", counts_.used_steps},
            {"steps_stale", counts_.stale_steps},
            {"steps_held", uint64_t(algo_->holding().rows)},  // not fitted at the end
            {"steps_fitted_by_lag", by_lag}};
  }

  void counts_to_manifest(config::CheckpointManifest& m) const override {
    m.set_stale_batches(counts_.stale_batches);
    m.set_stale_steps(counts_.stale_steps);
    m.set_fitted_steps(counts_.used_steps);
    m.set_quota_top_ups(counts_.top_ups);
    for (const auto& [lag, n] : counts_.lag_steps) {
      config::LagSteps* l = m.add_fitted_by_lag();
      l->set_lag(lag);
      l->set_steps(n);
    }
  }
  void counts_from_manifest(const config::CheckpointManifest& m) override {
    counts_.stale_batches = m.stale_batches();
    counts_.stale_steps = m.stale_steps();
    counts_.used_steps = m.fitted_steps();
    counts_.top_ups = m.quota_top_ups();
    counts_.lag_steps.clear();
    for (const auto& l : m.fitted_by_lag()) counts_.lag_steps[l.lag()] += l.steps();
  }

 private:
  // The run's step accounts: batches and steps counted stale (over the run, and since the last
  // fit), steps fitted and by what lag, quota top-ups.
  struct Counts {
    uint64_t stale_batches = 0, stale_fit = 0, stale_steps = 0, used_steps = 0, top_ups = 0;
    std::map<uint64_t, uint64_t> lag_steps;  // fitted steps by lag, over the run
  };
  // What arrives between fits: steps taken since the last fit ended, their rate over the last
  // cycle (waiting, then fitting), the last fit's end and length, and when data last came.
  struct Arrivals {
    uint64_t steps = 0;
    double rate = 0, last_fit_end = 0, last_fit_seconds = 0, last_data = 0;
  };
  // Episodes finished since the last fit, and their task metrics summed.
  struct FitEpisodes {
    uint64_t count = 0;
    std::vector<double> sums;
    void add(const std::vector<float>& metrics, size_t n) {
      ++count;
      sums.resize(n, 0.0);
      for (size_t i = 0; i < n && i < metrics.size(); ++i) sums[i] += metrics[i];
    }
  };
  // Fits' rows: a row's evaluation fields are filled when the evaluation asked at that fit is
  // answered. Rows are written in fit order, so one that waits holds back the rows after it, up to
  // kMaxHeld rows.
  class FitRows {
   public:
    explicit FitRows(const std::vector<std::string>& metrics) : metrics_(metrics) {}
    void add(Farm& farm, StatsRecord r, bool waits, uint64_t version) {
      rows_.push_back({std::move(r), waits, version});
      write(farm);
    }
    void settle(Farm& farm, uint64_t version, const EvalReport* e) {
      for (auto& row : rows_) {
        if (!row.waits || row.version != version) continue;
        row.waits = false;
        if (e) {
          row.record.set(stats::kEvalReturn, e->mean);
          row.record.set(stats::kEvalMin, e->min);
          row.record.set(stats::kEvalMax, e->max);
          row.record.set(stats::kEvalLength, e->mean_length);
          for (size_t i = 0; i < e->metrics.size() && i < metrics_.size(); ++i)
            row.record.set("eval_" + metrics_[i], e->metrics[i]);
        }
        break;
      }
      write(farm);
    }

   private:
    struct Row {
      StatsRecord record;
      bool waits = false;
      uint64_t version = 0;
    };
    void write(Farm& farm) {
      while (!rows_.empty() && (!rows_.front().waits || rows_.size() > kMaxHeld)) {
        farm.row(rows_.front().record);
        rows_.pop_front();
      }
    }
    static constexpr size_t kMaxHeld = 256;
    const std::vector<std::string> metrics_;  // the task's, TaskSpec::metric_names
    std::deque<Row> rows_;
  };

  // The current version's weights with the current quota; re-sent with a larger quota to top up.
  void publish_weights(Farm& farm) {
    policy_ = algo_->policy(version_);
    delivered_.clear();
    published_at_ = now_seconds();
    farm.publish(policy_, quota_);
  }

  // Whether a live worker counts toward a round: it has sent a batch this run (before any worker
  // has, every live worker counts, so the first quota is shared over those that joined). One that
  // only beats, stuck or anyone's heartbeat without security, neither shrinks the quota with the
  // environments it claims nor holds back a top-up.
  bool counts(const Farm::LiveWorker& w) const { return last_sent_.empty() || last_sent_.count(w.worker_id) > 0; }

  // Whether a worker that owes batches has sent none for ppo.stalled_worker_seconds since the later
  // of its last batch and the quota's last publication: a top-up does not wait for it.
  bool stalled(const Farm::LiveWorker& w, double now) const {
    const auto it = last_sent_.find(w.worker_id);
    const double since = std::max(it == last_sent_.end() ? 0.0 : it->second, published_at_);
    return now - since >= pc_.stalled_worker_seconds();
  }

  // Steps one round (one batch from every live worker that counts) brings.
  int64_t round_steps(const Farm& farm) const {
    int64_t envs = 0;
    for (const auto& w : farm.live_workers())
      if (counts(w)) envs += w.envs;
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
    const Holding h = algo_->holding();
    // Asynchronous: what the lag window can still fit. This version's last step is fitted once the
    // S steps already held, those on their way (the arrival rate times one fit: what came in while
    // the learner fitted, which S does not hold yet) and its own Q are, (S + in flight + Q) /
    // steps_per_fit fits from now: within max_policy_lag versions when Q <= (max_policy_lag + 1) *
    // steps_per_fit - S - in flight. A learner that keeps up holds little, so workers run on
    // through its fits; one that falls behind holds more, and the workers wait instead of
    // simulating steps that would arrive too old to use.
    if (async_) {
      const int64_t in_flight = int64_t(arrivals_.rate * arrivals_.last_fit_seconds);
      return batches_for(farm,
                         std::max<int64_t>(1, (pc_.max_policy_lag() + 1) * pc_.steps_per_fit() - h.rows - in_flight));
    }
    int64_t need = h.steps_wanted;
    if (h.episodes_wanted >= 0) {
      const int64_t eps = std::max<int64_t>(1, h.episodes_wanted);
      const int64_t envs = round_steps(farm) / cfg_.worker().steps_per_batch();
      const int64_t by_eps = (eps + envs - 1) / envs * std::max(1, spec_.max_episode_steps) * envs;
      need = need < 0 ? by_eps : std::min(need, by_eps);
    }
    return batches_for(farm, std::max<int64_t>(need, 1));
  }

  // Every live worker delivered its quota and the fit still lacks data (a worker left, or
  // episodes run longer than estimated): raise the quota of the same version.
  void top_up_if_starved(Farm& farm) {
    const Holding h = algo_->holding();
    const double now = now_seconds();
    if (!h.run_done.empty() || now - arrivals_.last_data < 0.5) return;
    // Every counted worker delivered, is idle or is stalled, and at least one is not stalled (a
    // top-up for none would only grow the quota).
    bool any_done = false;
    for (const auto& w : farm.live_workers()) {
      if (!counts(w)) continue;
      auto it = delivered_.find(w.worker_id);
      const bool done = it != delivered_.end() && it->second >= quota_;
      const bool idle = w.state == "throttled" && w.policy_version == version_;
      if (done || idle)
        any_done = true;
      else if (!stalled(w, now))
        return;
    }
    if (!any_done) return;
    int64_t need = h.steps_wanted;
    if (h.episodes_wanted >= 0) need = round_steps(farm);
    quota_ += batches_for(farm, std::max<int64_t>(need, 1));
    ++counts_.top_ups;
    arrivals_.last_data = published_at_ = now;
    farm.publish(policy_, quota_);
  }

  void fit(Farm& farm, double elapsed) {
    const double t = now_seconds();
    const std::vector<UpdateFigures> done = algo_->update(1, version_);
    check(done);
    if (done.empty()) return;
    const UpdateFigures& u = done.back();
    fits_ = u.update;
    const int64_t used = int64_t(u.get("steps used"));
    // The lag of what this fit uses: versions behind the one being fitted, by steps.
    double lag_sum = 0;
    uint64_t lag_max = 0;
    for (auto it = u.steps_by_version.rbegin(); it != u.steps_by_version.rend(); ++it) {
      const uint64_t lag = version_ - it->first;
      lag_sum += double(lag) * double(it->second);
      lag_max = std::max(lag_max, lag);
      counts_.lag_steps[lag] += uint64_t(it->second);
    }
    const double lag_mean = lag_sum / double(std::max<int64_t>(1, used));
    counts_.used_steps += uint64_t(used);
    const double fit_s = now_seconds() - t;
    if (arrivals_.last_fit_end > 0 && now_seconds() > arrivals_.last_fit_end)
      arrivals_.rate = double(arrivals_.steps) / (now_seconds() - arrivals_.last_fit_end);
    arrivals_.steps = 0;
    arrivals_.last_fit_end = now_seconds();
    arrivals_.last_fit_seconds = fit_s;
    const uint64_t fitted = version_;
    ++version_;
    quota_ = batches_for_next_fit(farm);
    if (algo_->holding().run_done.empty() && !stopping_)
      publish_weights(farm);
    else
      policy_ = algo_->policy(version_);
    // The evaluation is asked now and answered later (evaluated()); this fit's CSV row waits for it.
    const bool eval_now = !stopping_ && pc_.eval_every_fits() > 0 && fits_ % pc_.eval_every_fits() == 0 &&
                          ask_evaluation(farm, cfg_.eval().episodes(), elapsed, "eval");
    StatsRecord r(fit_schema_);
    put_figures(r, farm.figures(), elapsed);
    r.set(stats::kFit, double(fits_));
    r.set(stats::kPolicyVersion, double(fitted));
    r.set(stats::kStepsUsed, double(used));
    r.set(stats::kStepsCarried, u.get("steps carried"));
    r.set(stats::kStaleDropped, double(counts_.stale_fit));
    r.set(stats::kLagMean, lag_mean);
    r.set(stats::kLagMax, double(lag_max));
    r.set(stats::kFitSeconds, fit_s);
    r.set(stats::kKl, u.get("kl"));
    r.set(stats::kLearningRate, u.get("learning rate"));
    r.set(stats::kClipFraction, u.get("clip fraction"));
    r.set(stats::kValueLoss, u.get("value loss"));
    r.set(stats::kPolicyLoss, u.get("policy loss"));
    r.set(stats::kEntropy, u.get("entropy"));
    r.set(stats::kBatchesStale, double(counts_.stale_batches));
    r.set(stats::kEpisodes, double(fit_episodes_.count));
    for (size_t i = 0; i < spec_.metric_names.size() && i < fit_episodes_.sums.size() && fit_episodes_.count > 0; ++i)
      r.set("train_" + spec_.metric_names[i], fit_episodes_.sums[i] / double(fit_episodes_.count));
    farm.log(r.line());
    rows_.add(farm, std::move(r), eval_now, policy_.version);
    fit_episodes_ = FitEpisodes{};
    counts_.stale_fit = 0;
  }

  bool ask_evaluation(Farm& farm, int episodes, double elapsed, const std::string& label) {
    EvalAsk ask;
    ask.label = label;
    ask.episodes = episodes;
    ask.version = policy_.version;
    ask.updates = algo_->updates();
    ask.elapsed = elapsed;
    ask.progress = std::to_string(fits_) + " fits";
    return farm.ask_evaluation(policy_, ask);
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
      const int64_t held = algo_->holding().rows;
      if (held < least) return;
      if (!stopping_) farm.log("the " + std::to_string(held) + " steps held at the stop go into a last fit");
      stopping_ = true;
      fit(farm, elapsed);
    }
  }

  // Steps that waited in the store while versions moved on past the window: counted, not used.
  void drop_stale() {
    const uint64_t lag = uint64_t(pc_.max_policy_lag());
    counts_.stale_steps += uint64_t(algo_->forget_older_than(version_ > lag ? version_ - lag : 0));
  }

  const config::PpoConfig pc_;
  const bool async_;
  uint32_t quota_ = 1;
  int64_t fits_ = 0;
  bool published_ = false;
  bool stopping_ = false;                      // a stop rule fired: fits no longer publish or evaluate
  std::map<std::string, uint32_t> delivered_;  // batches of the current version per worker id
  std::map<std::string, double> last_sent_;    // when each worker that sent this run last did (bounded)
  static constexpr size_t kMaxSending = 4096;  // past it, workers not in it yet do not count
  double published_at_ = 0;                    // the current quota's publication (a top-up's too)
  PolicyParams policy_;                        // the current version's
  EvalReport last_eval_, final_eval_;
  Counts counts_;
  Arrivals arrivals_;
  FitEpisodes fit_episodes_;
  const StatsSchema fit_schema_, period_schema_ = stats::period_schema();
  FitRows rows_;
  static constexpr double kJoinGraceSeconds = 1.0;
};

}  // namespace

std::unique_ptr<Pacing> make_round_pacing(std::unique_ptr<Algorithm> algo, const config::ExperimentConfig& cfg,
                                          const robots::TaskSpec& spec) {
  return std::make_unique<RoundPacing>(std::move(algo), cfg, spec);
}

}  // namespace farm
