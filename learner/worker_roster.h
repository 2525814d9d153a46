// The learner's view of its workers, from their WorkerStatus heartbeats: who joined, who came
// back, who reports an error, and who went silent for longer than the timeout (marked dead;
// training goes on with the others, and a dead worker's batches are welcome again if it returns).
// Only workers of the learner's own experiment count: another experiment's workers on the same
// domain (or behind a shared Discovery Server) must not shrink what each of ours is asked for.
// Heartbeats are network input, and anyone on the domain can invent them: the roster holds at
// most kMaxViews workers and kMaxSessionsPerWorker sessions of one id (a new one past the id's
// bound replaces one of its sessions not live, else the one of them that joined last; past the
// total, a worker not live, and with none such the new worker is not taken), keeps each text cut (host, state, error),
// forgets a dead worker after forget_seconds, binds each worker (id and session) to the participant of its first
// heartbeat, and writes at most kLogBurst lines per kLogWindowS of what heartbeats cause (a farm of
// 100 workers starting together is still named worker by worker).
#pragma once

#include <functional>
#include <map>
#include <set>
#include <string>

#include <nlohmann/json.hpp>

#include "farm.h"

namespace farm {

class WorkerRoster {
 public:
  struct View {
    farm::msg::WorkerStatus last;
    double seen = 0;        // when its last heartbeat arrived
    double first_seen = 0;  // when its first did
    bool dead = false;
    std::string writer;  // the participant of its first heartbeat (dds::participant_key); "" unknown
  };
  using Log = std::function<void(const std::string&)>;
  // A worker event for RUN/events.jsonl: {"change": "joined" | "back" | "dead", "worker_id", "session",
  // "host", "envs"}; written with its log line, under the same bound.
  using Event = std::function<void(const nlohmann::json&)>;
  void on_event(Event e) { event_ = std::move(e); }

  // experiment_id: the learner's experiment; heartbeats of any other are ignored. Empty: every
  // heartbeat counts.
  WorkerRoster(double timeout_seconds, Log log, std::string experiment_id = "", double forget_seconds = 600)
      : timeout_(timeout_seconds),
        forget_(forget_seconds),
        log_(std::move(log)),
        experiment_id_(std::move(experiment_id)) {}

  // One heartbeat, received at `now` from participant `writer` (dds::participant_key; "" binds
  // nothing); false when it is not taken: not of this experiment (one log line for the first
  // heartbeat of each other experiment, and one for each worker that reports it cannot run this
  // experiment's spec), from another participant than the worker's first heartbeat, an id over
  // kMaxIdBytes, or a new worker with the roster full of live ones.
  bool heard(const farm::msg::WorkerStatus& s, double now, const std::string& writer = "");
  // Marks the workers silent for longer than the timeout dead, each with a log line, and forgets
  // those dead for forget_seconds.
  void check(double now);
  // Cuts a heartbeat's texts (host, state, error) to the lengths the roster keeps: done as each
  // one arrives, so that heartbeats waiting to be heard hold no more than that.
  static void cut(farm::msg::WorkerStatus& s);
  // Heartbeats not taken for the reasons above (other experiments aside).
  uint64_t refused() const { return refused_; }
  static constexpr size_t kMaxViews = 1024, kMaxSessionsPerWorker = 4, kMaxIdBytes = 256;
  static constexpr size_t kMaxHostBytes = 255, kMaxStateBytes = 32, kMaxErrorBytes = 1024;
  static constexpr int kLogBurst = 100;
  static constexpr double kLogWindowS = 10.0;
  // Heard within the timeout, not dead, not finished.
  bool live(const View& v, double now) const;
  int live_count(double now) const;
  const std::map<std::string, View>& views() const { return views_; }  // by "id#session"

 private:
  // Writes a line caused by a heartbeat, at most kLogBurst per kLogWindowS; the next line after a
  // window with lines held back says how many. change (with v): the worker event that goes with it,
  // written under the same bound; an empty line writes the event alone.
  void note(const std::string& line, double now, const char* change = nullptr, const View* v = nullptr);
  // Makes room for a new worker of id: false when there is none to make.
  bool make_room(const std::string& id, double now);
  double timeout_, forget_;
  Log log_;
  Event event_;
  uint64_t refused_ = 0;
  double window_start_ = -1e300;
  int window_lines_ = 0;
  uint64_t held_back_ = 0;
  std::string experiment_id_;
  std::map<std::string, View> views_;
  std::set<std::string> foreign_;  // other experiments already noted (bounded: kMaxForeignNoted)
  static constexpr size_t kMaxForeignNoted = 16;
  std::set<std::string> rejected_;  // "worker#error" of those that could not run our spec (bounded)
  static constexpr size_t kMaxRejectionsNoted = 64;
  void note_rejection(const farm::msg::WorkerStatus& s);
};

}  // namespace farm
