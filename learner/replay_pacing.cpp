// The replay pacing (pacing.h) of an off-policy algorithm: updates in groups as fast as the
// samples-per-insert limiter allows, the policy published every few updates (and whenever updates
// starve, so neither side waits for the other), evaluations on a timer, the step scaled where the
// data outrun the updates. Its numbers come from the algorithm's config section: learning_starts,
// max_updates_per_step (or samples_per_insert, where the section has it and sets it),
// publish_every_updates, batch_size.
#include <google/protobuf/descriptor.h>
#include <google/protobuf/message.h>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>

#include "meter.h"
#include "pacing.h"
#include "pacing_stats.h"
#include "replay_schedule.h"

namespace farm {

namespace {

// A number of the algorithm's config section (cfg.<algorithm>.<field>), its default where unset.
double section_number(const config::ExperimentConfig& cfg, const std::string& field) {
  using google::protobuf::FieldDescriptor;
  const auto* section = cfg.GetDescriptor()->FindFieldByName(cfg.algorithm());
  const auto* f = section && section->type() == FieldDescriptor::TYPE_MESSAGE
                      ? section->message_type()->FindFieldByName(field)
                      : nullptr;
  if (!f || f->is_repeated())
    throw std::invalid_argument("the replay pacing of an off-policy algorithm reads " + cfg.algorithm() + "." + field +
                                ", which the config section \"" + cfg.algorithm() + "\" does not have");
  const google::protobuf::Message& m = cfg.GetReflection()->GetMessage(cfg, section);
  const auto* r = m.GetReflection();
  switch (f->cpp_type()) {
    case FieldDescriptor::CPPTYPE_INT32:
      return r->GetInt32(m, f);
    case FieldDescriptor::CPPTYPE_INT64:
      return double(r->GetInt64(m, f));
    case FieldDescriptor::CPPTYPE_UINT32:
      return r->GetUInt32(m, f);
    case FieldDescriptor::CPPTYPE_UINT64:
      return double(r->GetUInt64(m, f));
    case FieldDescriptor::CPPTYPE_DOUBLE:
      return r->GetDouble(m, f);
    case FieldDescriptor::CPPTYPE_FLOAT:
      return r->GetFloat(m, f);
    default:
      throw std::invalid_argument(cfg.algorithm() + "." + field + " is not a number");
  }
}

// `field` of the algorithm's config section where the section has it, else `otherwise`.
double section_number_or(const config::ExperimentConfig& cfg, const std::string& field, double otherwise) {
  const auto* section = cfg.GetDescriptor()->FindFieldByName(cfg.algorithm());
  if (!section || !section->message_type() || !section->message_type()->FindFieldByName(field)) return otherwise;
  return section_number(cfg, field);
}

// Updates per env step received: samples_per_insert / batch_size where the section sets
// samples_per_insert (a ratio that means the same at any batch size), else max_updates_per_step.
double updates_per_step(const config::ExperimentConfig& cfg) {
  const double spi = section_number_or(cfg, "samples_per_insert", 0);
  if (spi <= 0) return section_number(cfg, "max_updates_per_step");
  if (section_number_or(cfg, "max_step_scale", 1) > 1)
    throw std::invalid_argument(cfg.algorithm() + ".samples_per_insert and " + cfg.algorithm() +
                                ".max_step_scale > 1 both set the update-to-data ratio: set one of them");
  return spi / section_number(cfg, "batch_size");
}

class ReplayPacing final : public Pacing {
 public:
  ReplayPacing(std::unique_ptr<Algorithm> algo, const config::ExperimentConfig& cfg, const robots::TaskSpec& spec)
      : Pacing(std::move(algo), cfg, spec),
        batch_size_(int(section_number(cfg_, "batch_size"))),
        per_step_(updates_per_step(cfg_)),
        schedule_{
            SamplesPerInsert(int64_t(section_number(cfg_, "learning_starts")), per_step_, cfg_.stop().max_updates()),
            kUpdatesPerGroup, int(section_number(cfg_, "publish_every_updates")), cfg_.eval().every_seconds()} {}

  const StatsSchema& row_schema() const override { return schema_; }
  uint64_t version() const override { return version_ > 0 ? version_ - 1 : 0; }
  double last_eval() const override { return last_eval_; }

  void start(Farm& farm) override {
    publish_weights(farm);
    last_eval_time_ = now_seconds();
  }

  bool take(const Batch& b) override {
    ++batches_since_publish_;
    if (b.rows->n > 0) algo_->insert(b);
    return true;
  }

  double train(Farm& farm, bool got_data) override {
    if (!diverged_.empty()) throw std::runtime_error(diverged_);
    // What this pass does (replay_schedule.h), from counts and clocks; carried out below. The
    // updates are one group between looks at the bus: on a GPU the algorithm queues them back to
    // back, and returns while the last still run.
    const ReplayDecision d =
        schedule_.decide({algo_->updates(), algo_->holding().rows, farm.env_steps(), algo_->ready(),
                          updates_since_publish_, batches_since_publish_, got_data, now_seconds() - last_eval_time_});
    if (d.updates > 0) {
      check(algo_->update(d.updates, version_));
      samples_ += double(d.updates) * batch_size_ * step_scale_;
      updates_meter_.add(d.updates);
      updates_since_publish_ += d.updates;
    }
    if (algo_->max_step_scale() > 1) adapt_step(farm);
    if (d.publish) publish_weights(farm);
    if (d.evaluate) {
      ask_evaluation(farm, cfg_.eval().episodes(), farm.elapsed(), "eval");  // answered later: evaluated()
      last_eval_time_ = now_seconds();
    }
    return d.wait;
  }

  void hold_workers(Farm& farm) override { farm.publish(policy(), 1); }

  StatsRecord progress(Farm& farm, const FarmFigures& f, double elapsed) override {
    StatsRecord r(schema_);
    put_figures(r, f, elapsed);
    const int64_t updates = algo_->updates();
    const Holding h = algo_->holding();
    r.set(stats::kUpdates, double(updates));
    r.set(stats::kUpdatesPerS, updates_meter_.rate());
    r.set(stats::kUpdateToData, f.env_steps > 0 ? double(updates) / double(f.env_steps) : 0.0);
    r.set(stats::kSamplesPerInsert, f.env_steps > 0 ? samples_ / double(f.env_steps) : 0.0);
    r.set(stats::kBufferFill, h.capacity > 0 ? double(h.rows) / double(h.capacity) : 0.0);
    r.set(stats::kPolicyVersion, double(version()));
    r.set(stats::kCriticLoss, latest("critic loss"));
    r.set(stats::kActorLoss, latest("actor loss"));
    r.set(stats::kAlpha, std::isnan(last_.get("alpha")) ? latest("epsilon") : latest("alpha"));
    r.set(stats::kEvalReturn, last_eval_);
    r.set(stats::kStepScale, step_scale_);
    farm.row(r);
    return r;
  }

  void final_evaluation(Farm& farm, double elapsed) override {
    ask_evaluation(farm, cfg_.eval().final_episodes(), elapsed, "final");
  }

  void evaluated(Farm& farm, const EvalAsk& ask, const EvalReport& r) override {
    const double mean = r.episodes > 0 ? r.mean : 0;
    last_eval_ = mean;
    if (ask.label == "final") final_return_ = mean;
    std::string metric_txt;
    for (size_t i = 0; i < r.metrics.size() && i < spec_.metric_names.size() && r.episodes > 0; ++i)
      metric_txt += ", " + spec_.metric_names[i] + " " + fmt("%.3f", r.metrics[i]);
    farm.log(ask.label + ": mean return " + fmt("%.1f", mean) + " over " + std::to_string(r.episodes) +
             " deterministic episodes" + metric_txt + " (policy v" + std::to_string(ask.version) + ", " + ask.progress +
             ", " + fmt("%.1f", ask.elapsed) + " s)");
    farm.record_evaluation(r, ask.version, ask.updates, ask.elapsed);
  }

  std::string summary(const FarmFigures& f, double elapsed) const override {
    std::ostringstream o;
    o << "updates           " << algo_->updates() << " ("
      << fmt("%.0f", double(algo_->updates()) / std::max(elapsed, 1e-9)) << " updates/s)\n"
      << "policy versions   " << version() << "\n"
      << "episodes          " << f.episodes << "\n"
      << "final eval return " << fmt("%.1f", final_return_) << " (mean of " << cfg_.eval().final_episodes()
      << " deterministic episodes)\n"
      << best_eval_line(f) << "\n"
      << "batches           ok " << f.ok << ", lost " << f.lost << ", duplicate " << f.duplicate << ", invalid "
      << f.invalid << "\n";
    return o.str();
  }

 private:
  void publish_weights(Farm& farm) {
    farm.publish(policy_of(version_), 0);
    ++version_;
    updates_since_publish_ = 0;
    batches_since_publish_ = 0;
  }
  PolicyParams policy_of(uint64_t v) const {
    settle();
    return algo_->policy(v);
  }

  // sac.max_step_scale: once a window of kStepWindowSeconds from the first update on, the updates
  // the data allowed in it (max_updates_per_step x env steps received) per update made set the
  // step scale for the next window (next_step_scale).
  void adapt_step(Farm& farm) {
    const double t = now_seconds();
    const int64_t updates = algo_->updates();
    const uint64_t env_steps = farm.env_steps();
    if (updates == 0) return;
    if (step_window_start_ < 0 || t - step_window_start_ >= kStepWindowSeconds) {
      if (step_window_start_ >= 0 && updates > step_window_updates_) {
        const double allowed = per_step_ * double(env_steps - step_window_env_steps_);
        const double r = allowed / double(updates - step_window_updates_);
        const int next = next_step_scale(step_scale_, r, algo_->max_step_scale());
        if (next != step_scale_) {
          step_scale_ = next;
          algo_->set_step_scale(next);
          farm.log(algo_->name() + " step x" + std::to_string(next) + " from update " + std::to_string(updates) +
                   ": batch " + std::to_string(batch_size_ * next) + ", learning rates x" +
                   fmt("%.2f", std::sqrt(double(next))) + " (the last " + fmt("%.1f", t - step_window_start_) +
                   " s' data allowed " + fmt("%.2f", r) + " updates per update made)");
        }
      }
      step_window_start_ = t;
      step_window_updates_ = updates;
      step_window_env_steps_ = env_steps;
    }
  }

  void ask_evaluation(Farm& farm, int episodes, double elapsed, const std::string& label) {
    EvalAsk ask;
    ask.label = label;
    ask.episodes = episodes;
    ask.version = version();
    ask.updates = algo_->updates();
    ask.elapsed = elapsed;
    ask.progress = std::to_string(ask.updates) + " updates";
    farm.ask_evaluation(policy_of(ask.version), ask);
  }

  const StatsSchema schema_ = stats::replay_schema();
  const int batch_size_;  // the config's; the step scale multiplies it
  const double per_step_;
  const ReplaySchedule schedule_;
  Meter updates_meter_;
  int updates_since_publish_ = 0, batches_since_publish_ = 0;
  double last_eval_ = NAN, last_eval_time_ = 0, final_return_ = NAN;
  int step_scale_ = 1;
  double samples_ = 0;  // samples the updates drew (batch_size x step scale each): samples_per_insert's numerator
  static constexpr double kStepWindowSeconds = 1.0;
  double step_window_start_ = -1;
  int64_t step_window_updates_ = 0;
  uint64_t step_window_env_steps_ = 0;
};

}  // namespace

std::unique_ptr<Pacing> make_replay_pacing(std::unique_ptr<Algorithm> algo, const config::ExperimentConfig& cfg,
                                           const robots::TaskSpec& spec) {
  return std::make_unique<ReplayPacing>(std::move(algo), cfg, spec);
}

}  // namespace farm
