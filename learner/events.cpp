#include "events.h"

#include <cmath>
#include <cstdlib>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "meter.h"

namespace farm {

namespace {
std::vector<std::string> split_commas(const std::string& s) {
  std::vector<std::string> out;
  std::string cell;
  std::istringstream in(s);
  while (std::getline(in, cell, ',')) out.push_back(cell);
  if (!s.empty() && s.back() == ',') out.emplace_back();
  return out;
}
}  // namespace

void EventLog::open(const std::string& path) {
  std::lock_guard<std::mutex> lk(mu_);
  out_.open(path, std::ios::app);
  if (!out_) throw std::runtime_error("cannot write " + path);
}

void EventLog::write(const std::string& event, nlohmann::json fields) {
  nlohmann::json e = nlohmann::json::object();
  e["event"] = event;
  if (!fields.contains("elapsed_s")) e["elapsed_s"] = std::round((now_seconds() - t0_.load()) * 1000.0) / 1000.0;
  e.update(fields);
  // Texts from the network are not trusted to be UTF-8: invalid bytes are replaced, not thrown on.
  const std::string line = e.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  std::lock_guard<std::mutex> lk(mu_);
  if (!out_.is_open()) return;
  out_ << line << '\n';
  out_.flush();
  if (!out_) {
    failures_.fetch_add(1);
    out_.clear();
  }
}

nlohmann::json EventLog::from_csv(const std::string& header, const std::string& row) {
  const std::vector<std::string> names = split_commas(header), cells = split_commas(row);
  nlohmann::json o = nlohmann::json::object();
  for (size_t i = 0; i < names.size(); ++i) {
    const std::string c = i < cells.size() ? cells[i] : "";
    char* end = nullptr;
    const double v = c.empty() ? NAN : std::strtod(c.c_str(), &end);
    if (c.empty() || std::isnan(v))
      o[names[i]] = nullptr;
    else if (end && *end == '\0' && std::isfinite(v))
      o[names[i]] = (c.find_first_of(".eE") == std::string::npos && std::abs(v) < 9e15) ? nlohmann::json(int64_t(v))
                                                                                        : nlohmann::json(v);
    else
      o[names[i]] = c;
  }
  return o;
}

}  // namespace farm
