// The roster on its own thread: takes the workers' heartbeats off the bus as they arrive, checks
// under DDS Security that each comes from the participant whose certificate bears its worker id,
// hands them to the WorkerRoster (joins, errors, and the dead marked within a heartbeat timeout),
// and keeps that going whatever the learner's loop does (a fit, a checkpoint, an evaluation's
// wait). The loop reads copies of what the roster holds.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
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
  // Takes the heartbeats that have arrived but that the roster's thread has not taken yet, from the
  // calling thread: the ingest asks before it opens a stream, so that the heartbeat that announced a
  // session is in the roster even when a copier's batch comes right behind it.
  void take_pending();
  // When the first heartbeat of this experiment was taken (now_seconds() clock); 0 before.
  double first_heard() const { return first_heard_.load(); }
  // Heartbeats whose worker id is not their writer's certificate name (security): not heard.
  uint64_t refused_for_name() const { return refused_for_name_.load(); }
  // Heartbeats over a participant's share (kMaxBeatsPerSecond): taken off the bus and not heard.
  uint64_t refused_for_rate() const { return refused_for_rate_.load(); }

  static constexpr double kCheckEveryS = 0.2;  // how often the silent are looked for
  static constexpr int kMaxRefusalNotes = 20;  // log lines and events of heartbeats refused by name
  // A participant's share of the roster's work: a worker beats once a second (its beat thread adds
  // one at most every 1.5 s); past kMaxBeatsPerSecond on average, with a burst of kBeatBurst, what a
  // participant sends is dropped before the roster looks at it, so a flood from one participant
  // (a leaked certificate under security) cannot crowd out the workers' heartbeats or the roster's
  // time. Once started, heartbeats are taken as they arrive, on Fast DDS's listener thread: the
  // reader's history (KEEP_LAST 16, one for every writer) never fills, so a burst of thousands from
  // one participant pushes no other participant's heartbeat out of it. The loop looks for the
  // silent every kCheckEveryS and tells refusals every kLoopEveryS.
  static constexpr double kMaxBeatsPerSecond = 20, kBeatBurst = 40, kLoopEveryS = 0.01;
  static constexpr size_t kMaxRatedParticipants = 4096;

 private:
  void loop();
  // Takes every heartbeat in `reader`'s history; the caller holds take_mu_.
  void take_all(eprosima::fastdds::dds::DataReader* reader);

  farm::dds::Bus& bus_;
  Log log_;
  EventLog& events_;
  mutable std::mutex mu_;
  WorkerRoster roster_;  // guarded by mu_
  std::mutex take_mu_;   // one taker at a time (the listener, the loop, take_pending()), held only to take
  std::atomic<double> first_heard_{0};
  std::atomic<uint64_t> refused_for_name_{0};
  std::atomic<uint64_t> refused_for_rate_{0};
  std::atomic<bool> stop_{false};
  std::atomic<bool> started_{false};  // heartbeats are taken on arrival from start() on
  std::thread thread_;
  // The thread's own:
  uint64_t refused_noted_ = 0, oversized_noted_ = 0, rate_noted_ = 0;  // refusals already told
  struct Bucket {
    double tokens = kBeatBurst, at = 0;
  };
  std::map<std::string, Bucket> buckets_;  // per participant (dds::participant_key)
  bool within_share(const std::string& participant, double now);
  double rate_noted_at_ = -1e9;
  int refusal_notes_ = 0, rate_notes_ = 0;  // the lines told so far: by name or size, by rate
  std::string refused_last_;                // guarded by mu_
  // Last: its listener uses the members above, and it is gone (no listener running) before they are.
  farm::dds::Reader<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType> reader_;
};

}  // namespace farm
