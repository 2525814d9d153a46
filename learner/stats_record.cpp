#include "stats_record.h"

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <stdexcept>

namespace farm {

namespace {

// Whether `f` prints one double: a single conversion f, g or e (with flags, width and precision),
// besides any "%%".
bool one_double_conversion(const std::string& f) {
  int conversions = 0;
  for (size_t i = 0; i < f.size(); ++i) {
    if (f[i] != '%') continue;
    if (i + 1 < f.size() && f[i + 1] == '%') {
      ++i;
      continue;
    }
    size_t j = i + 1;
    while (j < f.size() && std::string("-+ #0123456789.").find(f[j]) != std::string::npos) ++j;
    if (j == f.size() || std::string("fgeFGE").find(f[j]) == std::string::npos) return false;
    ++conversions;
    i = j;
  }
  return conversions == 1;
}

std::string print(const std::string& format, double v) {
  char buf[128];
  std::snprintf(buf, sizeof buf, format.c_str(), v);
  return buf;
}

}  // namespace

size_t StatsSchema::add(const StatField& f) {
  if (f.name.empty() || f.name.find_first_of(",\"\n") != std::string::npos)
    throw std::invalid_argument("statistics field \"" + f.name + "\": a name is a CSV column, without , \" or newline");
  if (by_name_.count(f.name)) throw std::invalid_argument("statistics field \"" + f.name + "\" declared twice");
  if (f.type == StatType::Real && !one_double_conversion(f.csv))
    throw std::invalid_argument("statistics field \"" + f.name + "\": CSV format \"" + f.csv +
                                "\" is not one conversion of a double (f, g or e)");
  if (!f.line.empty() && !one_double_conversion(f.line))
    throw std::invalid_argument("statistics field \"" + f.name + "\": line format \"" + f.line +
                                "\" is not one conversion of a double (f, g or e)");
  by_name_[f.name] = fields_.size();
  fields_.push_back(f);
  return fields_.size() - 1;
}

size_t StatsSchema::find(const std::string& name) const {
  const auto it = by_name_.find(name);
  return it == by_name_.end() ? fields_.size() : it->second;
}

std::string StatsSchema::csv_header() const {
  std::string h;
  for (const StatField& f : fields_) h += (h.empty() ? "" : ",") + f.name;
  return h;
}

StatsRecord::StatsRecord(const StatsSchema& schema) : schema_(&schema), values_(schema.size(), NAN) {}

bool StatsRecord::set(const std::string& name, double value) {
  const size_t i = schema_->find(name);
  if (i >= values_.size()) return false;
  values_[i] = value;
  return true;
}

double StatsRecord::get(const std::string& name) const {
  const size_t i = schema_->find(name);
  return i < values_.size() ? values_[i] : NAN;
}

std::string StatsRecord::csv_row() const {
  std::string row;
  const auto& fields = schema_->fields();
  for (size_t i = 0; i < fields.size(); ++i) {
    if (i > 0) row += ',';
    const double v = values_[i];
    if (std::isnan(v)) continue;
    row += fields[i].type == StatType::Count ? print("%.0f", v) : print(fields[i].csv, v);
  }
  return row;
}

std::string StatsRecord::line() const {
  std::string out;
  const auto& fields = schema_->fields();
  for (size_t i = 0; i < fields.size(); ++i) {
    const std::string& f = fields[i].line;
    if (f.empty()) continue;
    const bool group = f.rfind("| ", 0) == 0;
    if (!out.empty()) out += group ? " | " : " ";
    out += print(group ? f.substr(2) : f, values_[i]);
  }
  return out;
}

nlohmann::json StatsRecord::fields() const {
  nlohmann::json o = nlohmann::json::object();
  const auto& fields = schema_->fields();
  for (size_t i = 0; i < fields.size(); ++i) {
    const double v = values_[i];
    if (!std::isfinite(v))
      o[fields[i].name] = nullptr;
    else if (fields[i].type == StatType::Count)
      o[fields[i].name] = int64_t(std::llround(v));
    else
      o[fields[i].name] = v;
  }
  return o;
}

}  // namespace farm
