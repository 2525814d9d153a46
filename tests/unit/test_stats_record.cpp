// The learner's statistics record (learner/stats_record.h, stats_reporter.h): a field declared once
// in a schema reaches learner.csv's header and row, the progress line, LearnerStats and the
// progress event of events.jsonl; declarations are checked; an unset value is an empty cell and a
// null, a count a whole number.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "learner_stats_fields.h"
#include "pacing.h"
#include "pacing_stats.h"
#include "stats_record.h"
#include "stats_reporter.h"

namespace farm {
namespace {

namespace fs = std::filesystem;

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out(1);
  for (char c : s) {
    if (c == ',')
      out.emplace_back();
    else
      out.back().push_back(c);
  }
  return out;
}

// What each sink made of one record: learner.csv's header and row, the progress line, LearnerStats
// and the progress event of events.jsonl, each through StatsReporter into a folder of its own.
struct Sinks {
  std::vector<std::string> header, row;
  std::string line;
  farm::msg::LearnerStats stats;
  nlohmann::json event;
};

Sinks report(const StatsRecord& r, const std::string& tag) {
  const fs::path dir = fs::temp_directory_path() / ("stats_record_" + std::to_string(getpid()) + "_" + tag);
  fs::remove_all(dir);
  fs::create_directories(dir);
  Sinks out;
  {
    EventLog events;
    events.open((dir / "events.jsonl").string());
    StatsReporter reporter(
        "exp", events, [&](const std::string& l) { out.line = l; },
        [&](farm::msg::LearnerStats& st) { out.stats = st; });
    reporter.open_csv((dir / "learner.csv").string(), r.schema());
    reporter.row(r);
    reporter.period(r);
  }
  std::ifstream csv(dir / "learner.csv");
  std::string header, row, extra;
  EXPECT_TRUE(std::getline(csv, header));
  EXPECT_TRUE(std::getline(csv, row));
  EXPECT_FALSE(std::getline(csv, extra)) << extra;
  out.header = split(header);
  out.row = split(row);
  std::ifstream ev(dir / "events.jsonl");
  std::string e;
  EXPECT_TRUE(std::getline(ev, e));
  out.event = nlohmann::json::parse(e);
  fs::remove_all(dir);
  return out;
}

// The runner's figures of a progress period, as put_figures takes them.
FarmFigures figures() {
  FarmFigures f;
  f.env_steps = 4096;
  f.ok = 12;
  f.lost = 1;
  f.workers = 2;
  f.throttled = 1;
  f.in_rate = 512.4;
  f.mean_return = -150.3;
  return f;
}

StatsSchema base() {
  using namespace stats;
  return {kElapsed, kEnvSteps, kEnvStepsPerS, kMeanReturn, kBatchesOk, kBatchesLost, kWorkers, kWorkersThrottled};
}

TEST(StatsRecord, AFieldAddedInOnePlaceReachesEverySink) {
  const StatsSchema without = base();
  StatsSchema with = base();
  with.real("grad_norm", "", "%.3f", "| grad norm %.2f");  // the one place
  StatsRecord a(without), b(with);
  put_figures(a, figures(), 12.5);
  put_figures(b, figures(), 12.5);
  b.set("grad_norm", 1.25);
  const Sinks sa = report(a, "without"), sb = report(b, "with");

  // learner.csv: the header and the row gain the one column, last, and nothing else changes.
  std::vector<std::string> header = sa.header, row = sa.row;
  header.push_back("grad_norm");
  row.push_back("1.250");
  EXPECT_EQ(sb.header, header);
  EXPECT_EQ(sb.row, row);
  EXPECT_EQ(sa.header, (std::vector<std::string>{"elapsed_s", "env_steps", "env_steps_per_s", "mean_return",
                                                 "batches_ok", "batches_lost", "workers", "workers_throttled"}));
  EXPECT_EQ(sa.row, (std::vector<std::string>{"12.50", "4096", "512.4", "-150.300", "12", "1", "2", "1"}));

  // The progress line gains the field's part.
  EXPECT_EQ(sb.line, sa.line + " | grad norm 1.25");
  EXPECT_EQ(sa.line,
            "   12.5s | env steps 4096 (512/s) | return -150.3 | batches ok 12 lost 1 | workers 2 | throttled 1");

  // LearnerStats: the keyed list gains the field; the typed fields are those of the same names.
  ASSERT_EQ(sb.stats.stats().size(), sa.stats.stats().size() + 1);
  EXPECT_EQ(sb.stats.stats().back().name(), "grad_norm");
  EXPECT_EQ(sb.stats.stats().back().unit(), "");
  EXPECT_DOUBLE_EQ(sb.stats.stats().back().value(), 1.25);
  for (size_t i = 0; i < sa.stats.stats().size(); ++i) {
    EXPECT_EQ(sa.stats.stats()[i].name(), sa.header[i]);
    EXPECT_EQ(sb.stats.stats()[i].name(), sa.header[i]);
  }
  EXPECT_EQ(sb.stats.experiment_id(), "exp");
  EXPECT_DOUBLE_EQ(sb.stats.elapsed_seconds(), 12.5);
  EXPECT_EQ(sb.stats.env_steps(), 4096u);
  EXPECT_DOUBLE_EQ(sb.stats.env_steps_per_second(), 512.4);
  EXPECT_EQ(sb.stats.batches_ok(), 12u);
  EXPECT_EQ(sb.stats.workers(), 2u);
  EXPECT_EQ(sb.stats.stats()[1].unit(), "steps");

  // events.jsonl: the progress event gains the key, the rest as before.
  nlohmann::json event = sa.event;
  event["grad_norm"] = 1.25;
  EXPECT_EQ(sb.event, event);
  EXPECT_EQ(sa.event.value("event", ""), "progress");
  EXPECT_TRUE(sa.event["env_steps"].is_number_integer());
  EXPECT_EQ(sa.event["env_steps"].get<int64_t>(), 4096);
  EXPECT_DOUBLE_EQ(sa.event["elapsed_s"].get<double>(), 12.5);  // the record's, not the clock's
  EXPECT_EQ(sa.event.size(), sa.header.size() + 1);             // the fields and "event"
}

TEST(StatsRecord, AnUnsetValueIsAnEmptyCellAndNull) {
  StatsSchema s;
  s.real("eval_return", "", "%.2f", "eval %.1f");
  s.count("fit", "fits");
  StatsRecord r(s);
  EXPECT_EQ(r.csv_row(), ",");
  EXPECT_TRUE(r.fields()["eval_return"].is_null());
  EXPECT_TRUE(r.fields()["fit"].is_null());
  r.set("fit", 3);
  EXPECT_EQ(r.csv_row(), ",3");
  EXPECT_TRUE(std::isnan(r.get("no_such_field")));
  EXPECT_FALSE(r.set("no_such_field", 1.0));
}

TEST(StatsRecord, DeclarationsAreChecked) {
  StatsSchema s;
  s.count("env_steps", "steps");
  EXPECT_THROW(s.count("env_steps", "steps"), std::invalid_argument);     // declared twice
  EXPECT_THROW(s.real("a,b", "", "%.2f"), std::invalid_argument);         // not a CSV column
  EXPECT_THROW(s.real("r", "", "%d"), std::invalid_argument);             // not a double's conversion
  EXPECT_THROW(s.real("r", "", "%s"), std::invalid_argument);             // not a double's conversion
  EXPECT_THROW(s.real("r", "", "%.2f %.2f"), std::invalid_argument);      // two values
  EXPECT_THROW(s.count("c", "", "| count %lld"), std::invalid_argument);  // the line's too
  EXPECT_NO_THROW(s.real("fill", "", "%.4f", "| buffer %.1f%%"));         // a literal % is text
  EXPECT_EQ(s.csv_header(), "env_steps,fill");
}

// The round pacing names its losses value_loss and policy_loss: LearnerStats' critic_loss and
// actor_loss carry them.
TEST(StatsRecord, LearnerStatsTakesTheRoundPacingsLossNames) {
  StatsSchema s;
  s.real("value_loss", "", "%.6g");
  s.real("policy_loss", "", "%.6g");
  StatsRecord r(s);
  r.set("value_loss", 0.5);
  r.set("policy_loss", -0.25);
  const farm::msg::LearnerStats st = learner_stats("e", r);
  EXPECT_DOUBLE_EQ(st.critic_loss(), 0.5);
  EXPECT_DOUBLE_EQ(st.actor_loss(), -0.25);
  EXPECT_EQ(st.stats().size(), 2u);
}

// Every typed field of LearnerStats is filled from the record's field of the name declared with it
// (common/learner_stats_fields.h); a count that is negative or unset keeps its default.
TEST(StatsRecord, EveryTypedFieldComesFromItsDeclaredName) {
  StatsSchema s;
  std::vector<std::string> names;
#define FARM_NAME(name, member, type) names.push_back(#name);
  FARM_LEARNER_STATS_FIELDS(FARM_NAME)
#undef FARM_NAME
  ASSERT_EQ(names.size(), 16u);
  for (const std::string& n : names) s.real(n, "", "%.3f");
  StatsRecord r(s);
  for (size_t i = 0; i < names.size(); ++i) r.set(names[i], double(i + 1));
  const farm::msg::LearnerStats st = learner_stats("e", r);
  size_t i = 0;
#define FARM_CHECK(name, member, type) EXPECT_EQ(st.member(), type(++i)) << #name;
  FARM_LEARNER_STATS_FIELDS(FARM_CHECK)
#undef FARM_CHECK

  r.set("env_steps", -1);
  r.set("workers", NAN);
  const farm::msg::LearnerStats unset = learner_stats("e", r);
  EXPECT_EQ(unset.env_steps(), 0u);
  EXPECT_EQ(unset.workers(), 0u);
}

}  // namespace
}  // namespace farm
