// The learner's view of its workers, from their WorkerStatus heartbeats: who joined, who came
// back, who reports an error, and who went silent for longer than the timeout (marked dead;
// training goes on with the others, and a dead worker's batches are welcome again if it returns).
// Only workers of the learner's own experiment count: another experiment's workers on the same
// domain (or behind a shared Discovery Server) must not shrink what each of ours is asked for.
#pragma once

#include <functional>
#include <map>
#include <set>
#include <string>

#include "farm.h"

namespace farm {

class WorkerRoster {
 public:
  struct View {
    farm::msg::WorkerStatus last;
    double seen = 0;  // when its last heartbeat arrived
    bool dead = false;
  };
  using Log = std::function<void(const std::string&)>;

  // experiment_id: the learner's experiment; heartbeats of any other are ignored. Empty: every
  // heartbeat counts.
  WorkerRoster(double timeout_seconds, Log log, std::string experiment_id = "")
      : timeout_(timeout_seconds), log_(std::move(log)), experiment_id_(std::move(experiment_id)) {}

  // One heartbeat, received at `now`; false when it is not of this experiment (ignored; one log
  // line for the first heartbeat of each other experiment, and one for each worker that reports
  // it cannot run this experiment's spec).
  bool heard(const farm::msg::WorkerStatus& s, double now);
  // Marks the workers silent for longer than the timeout dead, each with a log line.
  void check(double now);
  // Heard within the timeout, not dead, not finished.
  bool live(const View& v, double now) const;
  int live_count(double now) const;
  const std::map<std::string, View>& views() const { return views_; }  // by "id#session"

 private:
  double timeout_;
  Log log_;
  std::string experiment_id_;
  std::map<std::string, View> views_;
  std::set<std::string> foreign_;  // other experiments already noted (bounded: kMaxForeignNoted)
  static constexpr size_t kMaxForeignNoted = 16;
  std::set<std::string> rejected_;  // "worker#error" of those that could not run our spec (bounded)
  static constexpr size_t kMaxRejectionsNoted = 64;
  void note_rejection(const farm::msg::WorkerStatus& s);
};

}  // namespace farm
