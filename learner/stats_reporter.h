// Where the learner's statistics records (stats_record.h) go: a row to RUN/learner.csv (its header
// the schema's) and as a progress event to RUN/events.jsonl, a period's record to the log as the
// progress line and to the bus as LearnerStats. Each sink renders the record's fields; none is
// written by hand.
#pragma once

#include <fstream>
#include <functional>
#include <string>

#include "events.h"
#include "farm.h"
#include "stats_record.h"

namespace farm {

// LearnerStats of a record: `stats` holds every field; a typed field (common/learner_stats_fields.h)
// is filled from the record's field of its name (critic_loss and actor_loss also from value_loss
// and policy_loss, the round pacing's names), and keeps its default where the record has none.
farm::msg::LearnerStats learner_stats(const std::string& experiment_id, const StatsRecord& r);

class StatsReporter {
 public:
  using Log = std::function<void(const std::string&)>;
  using Publish = std::function<void(farm::msg::LearnerStats&)>;
  StatsReporter(std::string experiment_id, EventLog& events, Log log, Publish publish);

  // Appends rows to csv_path, after the header of `rows` when the file is new or empty (a resumed
  // run goes on in the same file). Throws std::runtime_error when it cannot be written.
  void open_csv(const std::string& csv_path, const StatsSchema& rows);
  // A row: learner.csv and its progress event.
  void row(const StatsRecord& r);
  // A period's record: the progress line, and LearnerStats.
  void period(const StatsRecord& r);

 private:
  const std::string experiment_id_;
  EventLog& events_;
  const Log log_;
  const Publish publish_;
  std::ofstream csv_;
};

}  // namespace farm
