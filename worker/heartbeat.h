// The worker's heartbeat: its WorkerStatus on the bus, sent by the collect loop about once a
// second and, between those, re-sent by a thread of its own. One collect of a slow task (mCLARI:
// 4 steps of 4 envs, each step up to 3,000 physics steps) or an evaluation beside it on a busy host
// takes longer than the learner's worker_timeout_seconds (4 s), which would mark a live worker
// dead and give up the evaluation it held. The thread re-sends the loop's last status when the loop
// has sent none for 1.5 s (at most about 1.75 s apart), as long as the loop built one within
// kMaxLoopSilenceS: a loop stuck longer goes silent. Both write under one lock, so statuses go out
// in order.
#pragma once

#include <condition_variable>
#include <mutex>
#include <thread>

#include "dds.h"
#include "farm.h"
#include "farmPubSubTypes.h"

namespace farm {

class Heartbeat {
 public:
  explicit Heartbeat(farm::dds::Bus& bus);
  ~Heartbeat() { stop(); }
  void start();
  // Writes the status now; the thread re-sends it while the loop is late.
  void send(const farm::msg::WorkerStatus& s);
  // Ends the thread: no status is re-sent after the next send().
  void stop();

 private:
  void main();
  static constexpr double kMaxLoopSilenceS = 60.0;
  farm::dds::Writer<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType> out_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool stop_ = false;
  farm::msg::WorkerStatus last_;  // the loop's last status, and when it was built and last sent
  double built_ = -1, sent_ = 0;
  std::thread thread_;
};

}  // namespace farm
