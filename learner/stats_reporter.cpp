#include "stats_reporter.h"

#include <cmath>
#include <filesystem>
#include <initializer_list>
#include <stdexcept>
#include <utility>
#include <vector>

namespace farm {

namespace {
// Whether the record has a field of one of `names` (the first it has): its value in *v.
bool has(const StatsRecord& r, std::initializer_list<const char*> names, double* v) {
  for (const char* n : names)
    if (r.schema().find(n) < r.schema().size()) {
      *v = r.get(n);
      return true;
    }
  return false;
}
}  // namespace

farm::msg::LearnerStats learner_stats(const std::string& experiment_id, const StatsRecord& r) {
  farm::msg::LearnerStats st;
  st.experiment_id(experiment_id);
  double v = 0;
  const auto count = [&](std::initializer_list<const char*> names) { return has(r, names, &v) && v >= 0; };
  if (has(r, {"elapsed_s"}, &v)) st.elapsed_seconds(v);
  if (count({"env_steps"})) st.env_steps(uint64_t(v));
  if (has(r, {"env_steps_per_s"}, &v)) st.env_steps_per_second(v);
  if (count({"updates"})) st.updates(uint64_t(v));
  if (has(r, {"updates_per_s"}, &v)) st.updates_per_second(v);
  if (has(r, {"buffer_fill"}, &v)) st.buffer_fill(v);
  if (has(r, {"policy_lag"}, &v)) st.policy_lag(v);
  if (has(r, {"critic_loss", "value_loss"}, &v)) st.critic_loss(v);
  if (has(r, {"actor_loss", "policy_loss"}, &v)) st.actor_loss(v);
  if (has(r, {"mean_return"}, &v)) st.mean_return(v);
  if (has(r, {"eval_return"}, &v)) st.eval_return(v);
  if (count({"batches_ok"})) st.batches_ok(uint64_t(v));
  if (count({"batches_lost"})) st.batches_lost(uint64_t(v));
  if (count({"batches_duplicate"})) st.batches_duplicate(uint64_t(v));
  if (count({"batches_invalid"})) st.batches_invalid(uint64_t(v));
  if (count({"workers"})) st.workers(uint32_t(v));
  std::vector<farm::msg::LearnerStat> all;
  all.reserve(r.schema().size());
  for (size_t i = 0; i < r.schema().size(); ++i) {
    farm::msg::LearnerStat s;
    s.name(r.schema().fields()[i].name);
    s.unit(r.schema().fields()[i].unit);
    s.value(r.get(i));
    all.push_back(std::move(s));
  }
  st.stats(std::move(all));
  return st;
}

StatsReporter::StatsReporter(std::string experiment_id, EventLog& events, Log log, Publish publish)
    : experiment_id_(std::move(experiment_id)), events_(events), log_(std::move(log)), publish_(std::move(publish)) {}

void StatsReporter::open_csv(const std::string& csv_path, const StatsSchema& rows) {
  std::error_code ec;
  const bool new_csv = !std::filesystem::exists(csv_path, ec) || std::filesystem::file_size(csv_path, ec) == 0;
  csv_.open(csv_path, std::ios::app);
  if (!csv_) throw std::runtime_error("cannot write " + csv_path);
  if (new_csv) csv_ << rows.csv_header() << '\n';
  csv_.flush();
}

void StatsReporter::row(const StatsRecord& r) {
  csv_ << r.csv_row() << '\n';
  csv_.flush();
  events_.write("progress", r.fields());
}

void StatsReporter::period(const StatsRecord& r) {
  log_(r.line());
  farm::msg::LearnerStats st = learner_stats(experiment_id_, r);
  publish_(st);
}

}  // namespace farm
