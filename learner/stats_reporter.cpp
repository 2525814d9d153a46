#include "stats_reporter.h"

#include <cmath>
#include <filesystem>
#include <map>
#include <stdexcept>
#include <type_traits>
#include <utility>
#include <vector>

#include "learner_stats_fields.h"

namespace farm {

namespace {
// The record's value of the field `name`, or of the round pacing's name for the same quantity
// (value_loss for critic_loss, policy_loss for actor_loss); false where it has neither.
bool value_of(const StatsRecord& r, const std::string& name, double* v) {
  static const std::map<std::string, std::string> kAlso{{"critic_loss", "value_loss"}, {"actor_loss", "policy_loss"}};
  const auto also = kAlso.find(name);
  for (const std::string& n : {name, also == kAlso.end() ? name : also->second})
    if (r.schema().find(n) < r.schema().size()) {
      *v = r.get(n);
      return true;
    }
  return false;
}

// A count field takes a value that is not negative (NaN is neither).
template <class T>
bool fits(double v) {
  return std::is_floating_point_v<T> || v >= 0;
}
}  // namespace

farm::msg::LearnerStats learner_stats(const std::string& experiment_id, const StatsRecord& r) {
  farm::msg::LearnerStats st;
  st.experiment_id(experiment_id);
  double v = 0;
#define FARM_FILL(name, member, type) \
  if (value_of(r, #name, &v) && fits<type>(v)) st.member(type(v));
  FARM_LEARNER_STATS_FIELDS(FARM_FILL)
#undef FARM_FILL
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
