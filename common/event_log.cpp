#include "event_log.h"

#include <cmath>
#include <stdexcept>

#include "meter.h"

namespace farm {

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

}  // namespace farm
