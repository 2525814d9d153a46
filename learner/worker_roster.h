// The learner's view of its workers, from their WorkerStatus heartbeats: who joined, who came
// back, who reports an error, and who went silent for longer than the timeout (marked dead;
// training goes on with the others, and a dead worker's batches are welcome again if it returns).
#pragma once

#include <functional>
#include <map>
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

  WorkerRoster(double timeout_seconds, Log log) : timeout_(timeout_seconds), log_(std::move(log)) {}

  // One heartbeat, received at `now`.
  void heard(const farm::msg::WorkerStatus& s, double now);
  // Marks the workers silent for longer than the timeout dead, each with a log line.
  void check(double now);
  // Heard within the timeout, not dead, not finished.
  bool live(const View& v, double now) const;
  int live_count(double now) const;
  const std::map<std::string, View>& views() const { return views_; }  // by "id#session"

 private:
  double timeout_;
  Log log_;
  std::map<std::string, View> views_;
};

}  // namespace farm
