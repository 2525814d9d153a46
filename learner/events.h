// The learner's record for programs: RUN/events.jsonl, one JSON object a line, each with "event"
// (its kind) and "elapsed_s" (seconds of the run, as learner.csv counts them). Kinds:
//   start       the run's experiment, task, algorithm and domain
//   progress    one per learner.csv row: the fields of its statistics record (stats_record.h)
//               under the CSV's column names, the live workers throttled or in backpressure
//               (workers_throttled, workers_backpressure) among them
//   ingest      from the ingest thread, at most once a second while batches arrive: its counters
//               (batches_ok, batches_lost, batches_duplicate, batches_invalid, env_steps, queued)
//   refusal     a batch, batch sample or heartbeat refused (the first ones; the ingest counters
//               count every batch)
//   worker      a worker joined, came back, built its environments ("sized": envs known) or was
//               marked dead (roster; bounded as its log lines)
//   answer      one worker's answer to a part of an evaluation: who, its episodes and seconds
//   busy        a training pass of the loop that took at least 0.1 s (a PPO fit): its seconds, and
//               the batches and env steps the ingest thread accepted meanwhile (queued: held for
//               the loop at its end)
//   evaluation  an evaluation's report: label, policy_version, episodes, mean, min, max, metrics
//   grants      the worker grants read again on SIGHUP (security): what changed, who is granted
//   best        a new best policy kept in RUN/best
//   checkpoint  a checkpoint written (ok) or failed (error)
//   stop        why the run stopped
//   summary     the end-of-run figures of summary.txt
// The human log stays what it is; tests, tools/seeds.py and the benchmark scripts read this.
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
