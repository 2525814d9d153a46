// A program's record for programs: a file of JSON lines, one event a line, each with "event" (its
// kind) and "elapsed_s" (seconds since the program's clock start, set_start). The learner writes
// RUN/events.jsonl (its kinds: learner/events.h); a worker given --events writes its own (its kinds:
// worker/worker_app.h). The human log stays for people; tests and tools read these records.
#pragma once

#include <atomic>
#include <cstdint>
#include <fstream>
#include <mutex>
#include <string>

#include <nlohmann/json.hpp>

namespace farm {

class EventLog {
 public:
  // Appends to path (a resumed run goes on in the same file). Throws when it cannot be opened.
  void open(const std::string& path);
  // The now_seconds() time that elapsed_s counts from (a resumed run's start minus its elapsed).
  void set_start(double t0) { t0_.store(t0); }
  // Writes one event of kind `event` with `fields`, and elapsed_s unless fields has it. Safe from
  // any thread; a line is written whole. A failed write is counted (failures()), never thrown: a
  // full disk must not stop training.
  void write(const std::string& event, nlohmann::json fields = nlohmann::json::object());
  uint64_t failures() const { return failures_.load(); }

 private:
  std::mutex mu_;
  std::ofstream out_;
  std::atomic<double> t0_{0};
  std::atomic<uint64_t> failures_{0};
};

}  // namespace farm
