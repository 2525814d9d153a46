// The roster on its own thread: takes the workers' heartbeats off the bus as they arrive, checks
// under DDS Security that each comes from the participant whose certificate bears its worker id,
// hands them to the WorkerRoster (joins, errors, and the dead marked within a heartbeat timeout),
// and keeps that going whatever the learner's loop does (a fit, a checkpoint, an evaluation's
// wait). The loop reads copies of what the roster holds.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "dds.h"
#include "events.h"
#include "worker_roster.h"

namespace farm {

class RosterThread {
 public:
  using Log = std::function<void(const std::string&)>;
  // roster: its log and its worker events are written from this thread (log must be safe there).
  RosterThread(farm::dds::Bus& bus, WorkerRoster roster, Log log, EventLog& events);
  ~RosterThread();
  RosterThread(const RosterThread&) = delete;
  RosterThread& operator=(const RosterThread&) = delete;
  void start();

  // A worker of the roster as it was when asked, keyed "id#session".
  struct Worker {
    std::string key;
    WorkerRoster::View view;
    bool live = false;
  };
  std::vector<Worker> workers() const;
  std::optional<Worker> find(const std::string& key) const;
  int live_count() const;
  // When the first heartbeat of this experiment was taken (now_seconds() clock); 0 before.
  double first_heard() const { return first_heard_.load(); }
  // Heartbeats whose worker id is not their writer's certificate name (security): not heard.
  uint64_t refused_for_name() const { return refused_for_name_.load(); }

  static constexpr double kCheckEveryS = 0.2;  // how often the silent are looked for
  static constexpr int kMaxRefusalNotes = 20;  // log lines and events of heartbeats refused by name

 private:
  void loop();
  void take_all();

  farm::dds::Bus& bus_;
  farm::dds::Reader<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType> reader_;
  Log log_;
  EventLog& events_;
  mutable std::mutex mu_;
  WorkerRoster roster_;  // guarded by mu_
  std::atomic<double> first_heard_{0};
  std::atomic<uint64_t> refused_for_name_{0};
  std::atomic<bool> stop_{false};
  std::thread thread_;
  // The thread's own:
  uint64_t refused_noted_ = 0, oversized_noted_ = 0;  // refusals by name and by size already told
  int refusal_notes_ = 0;
  std::string refused_last_;
};

}  // namespace farm
