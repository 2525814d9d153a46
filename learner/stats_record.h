// The learner's statistics as one typed record. A StatsSchema declares each field once: its name,
// unit and type, and how learner.csv and the progress line print it. A StatsRecord holds one value
// a field. Every sink renders records of a schema and none reads text back: the progress line and
// the CSV header and row here, the progress event of events.jsonl (fields()), LearnerStats and
// through it farm-monitor's Prometheus page (stats_reporter.h).
#pragma once

#include <cstddef>
#include <initializer_list>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace farm {

enum class StatType {
  Count,  // a whole number: printed whole, an integer in JSON
  Real,   // a real number, printed by the field's format
};

struct StatField {
  std::string name;  // learner.csv's column, the progress event's key, LearnerStats' name
  std::string unit;  // "s", "steps", "steps/s", "versions", ...; "" for a ratio or a plain number
  StatType type = StatType::Real;
  std::string csv;  // Real: the printf format of its CSV cell ("%.2f"); unused for a Count
  // Its part of the progress line, a printf format of the value ("in %.0f steps/s"); a leading "| "
  // opens a group of the line. "" leaves the field off the line.
  std::string line;
};

class StatsSchema {
 public:
  StatsSchema() = default;
  StatsSchema(std::initializer_list<StatField> fields) {
    for (const StatField& f : fields) add(f);
  }
  // Adds a field after those already declared; returns its place in a record. Throws
  // std::invalid_argument on a name declared already, or on a format that is not one conversion of
  // a double (f, g or e).
  size_t add(const StatField& f);
  size_t count(const std::string& name, const std::string& unit, const std::string& line = "") {
    return add({name, unit, StatType::Count, "", line});
  }
  size_t real(const std::string& name, const std::string& unit, const std::string& csv, const std::string& line = "") {
    return add({name, unit, StatType::Real, csv, line});
  }

  const std::vector<StatField>& fields() const { return fields_; }
  size_t size() const { return fields_.size(); }
  // The place of the field `name`; size() when the schema has none.
  size_t find(const std::string& name) const;
  // learner.csv's header: the fields' names, comma-separated, without the newline.
  std::string csv_header() const;

 private:
  std::vector<StatField> fields_;
  std::map<std::string, size_t> by_name_;
};

class StatsRecord {
 public:
  // Every field unset (NaN): an empty CSV cell, null in JSON. The schema outlives the record.
  explicit StatsRecord(const StatsSchema& schema);

  void set(size_t field, double value) { values_.at(field) = value; }
  // Sets the field `name` where the schema has one; false where it has none.
  bool set(const std::string& name, double value);
  bool set(const StatField& f, double value) { return set(f.name, value); }
  double get(size_t field) const { return values_.at(field); }
  // NaN where the schema has no field `name`.
  double get(const std::string& name) const;
  const StatsSchema& schema() const { return *schema_; }

  // One row of learner.csv without the newline, in the header's order.
  std::string csv_row() const;
  // The progress line: the fields that have a line format, in the schema's order.
  std::string line() const;
  // The progress event's fields: each under its name, a Count as an integer, NaN as null.
  nlohmann::json fields() const;

 private:
  const StatsSchema* schema_;
  std::vector<double> values_;
};

}  // namespace farm
