// The worker's batch sender: two batch buffers, one filled by the collect loop while a thread of
// the sender's serializes and writes the other, in order, each under the next sequence number of
// the worker's stream; the end of the stream follows the last batch (batch_sender.cpp says why this
// is the farm's form of double-buffered sampling). The collect loop waits only when both buffers
// are with the sender: back-pressure from the learner. A write refused by a full reliable history
// is retried, never dropped; at shutdown, after 30 s without a learner acknowledging, it is given up.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <string>
#include <thread>

#include "dds.h"
#include "farm.h"
#include "farmPubSubTypes.h"
#include "rollout.h"

namespace farm {

class BatchSender {
 public:
  using Log = std::function<void(const std::string&)>;
  // Fault injection for reliability tests: the batch with this sequence number carries a NaN
  // (-1: none); each write waits this long first, as if DDS were slow to take it.
  struct Faults {
    int64_t nan_batch = -1;
    int publish_delay_ms = 0;
  };
  // stop: the worker's stop flag (a signal); at shutdown nobody is waited for.
  BatchSender(farm::dds::Bus& bus, const std::string& worker_id, Faults faults, const std::atomic<bool>& stop, Log log);
  // What is still queued is given up.
  ~BatchSender();
  void start();

  // The stream a batch belongs to: its experiment and the worker's session.
  struct Stream {
    std::string experiment_id;
    uint64_t session = 0;
  };
  // The buffer to collect into next, or null after waiting up to `wait` seconds while both are
  // with the sender.
  RolloutBatch* free_buffer(double wait);
  // Hands the buffer free_buffer() gave over, filled.
  void hand_over(const Stream& stream);
  // Waits until every batch handed over is written (or given up), calling `meanwhile` (the
  // heartbeat) every 100 ms; with stop the thread ends too.
  void drain(bool stop, const std::function<void()>& meanwhile);
  // The end of the stream, after the last batch (under the next number), then drain(true); waits up
  // to 10 s for the learner's acknowledgements. Without a learner matched, the thread just ends.
  void end_stream(const Stream& stream, uint64_t obs_dim, uint64_t act_dim, uint64_t policy_version,
                  const std::function<void()>& meanwhile);
  // At shutdown: a write may give up after 30 s.
  void finishing() { finishing_ = true; }

  size_t learners_matched() const { return out_.matched(); }
  uint64_t sent() const { return sequence_; }  // batches written: the next sequence number
  // A new session: the numbering restarts (only with the queue empty, after drain()).
  void restart_numbering() { sequence_ = 0; }
  // A write is retrying on a full reliable history.
  bool blocked() const { return blocked_; }
  // Seconds the collect loop waited for a free buffer, and the sender spent writing (the write in
  // progress included), so far.
  double backpressure_seconds() const { return backpressure_s_; }
  double publish_seconds(double now);

 private:
  // What the thread is handed: a filled buffer (or the end of stream) and the stream it belongs to.
  struct Outgoing {
    int buffer = -1;  // -1: end of stream
    Stream stream;
    uint64_t obs_dim = 0, act_dim = 0, policy_version = 0;  // for the end of stream
  };
  void main();
  // Serializes and writes one under sequence_, and counts it; false when it gave up at shutdown.
  bool publish(const Outgoing& o);

  static constexpr int kBuffers = 2;
  const std::string worker_id_;
  const Faults faults_;
  const std::atomic<bool>& stop_;
  Log log_;
  farm::dds::Writer<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType> out_;
  RolloutBatch buffers_[kBuffers];
  int next_ = 0;  // the buffer the collect loop fills next: they alternate
  std::mutex mu_;
  std::condition_variable work_cv_, free_cv_;  // the thread: work to do; the collect loop: a buffer free
  std::deque<Outgoing> queue_;                 // in collection order; bounded by kBuffers (+ the end)
  bool with_sender_[kBuffers] = {false, false};
  bool stop_thread_ = false;          // end once the queue is empty
  std::atomic<bool> give_up_{false};  // drop what is left (shutdown without a learner)
  std::atomic<bool> blocked_{false};
  std::atomic<bool> finishing_{false};
  std::thread thread_;
  farm::msg::TransitionBatch wire_;  // the sample, reused so its sequences keep their storage
  std::atomic<uint64_t> sequence_{0};
  double backpressure_s_ = 0;
  double publish_s_ = 0, publishing_since_ = 0;  // under mu_
};

}  // namespace farm
