// Ingest on its own thread: takes the workers' batches off the bus, checks and accounts them
// (Ingest), and hands each accepted batch, owned, to a bounded queue that the learner's loop pops.
// A fit or a checkpoint on the loop's thread does not stop the door: batches keep being taken,
// checked and accounted meanwhile. When the queue is full the thread takes nothing more, so the
// reliable DDS history fills and the workers' writers wait (their backpressure): nothing is dropped.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "dds.h"
#include "events.h"
#include "first_batch_hold.h"
#include "ingest.h"

namespace farm {

// One accepted batch, owning its data; view() is what an algorithm takes.
struct AcceptedBatch {
  std::string worker_id;
  uint64_t policy_version = 0;
  int num_steps = 0, num_envs = 0;
  std::vector<uint8_t> truncated;
  std::vector<float> log_probs;
  Transitions rows;
  std::vector<FinishedEpisode> episodes;
  Batch view() {
    return Batch{worker_id, policy_version, num_steps, num_envs, truncated.data(), log_probs.data(), &rows, &episodes};
  }
  // What it holds, for the queue's bound: its rows and per-step arrays.
  size_t bytes() const {
    return 4 * (rows.obs.size() + rows.actions.size() + rows.rewards.size() + rows.next_obs.size() +
                rows.horizon.size() + log_probs.size()) +
           rows.terminated.size() + truncated.size() + 64 * episodes.size() + 256;
  }
};

class IngestThread {
 public:
  using Log = std::function<void(const std::string&)>;
  // ingest: the accounts (restored from a checkpoint before start()). The batch reader is bounded
  // by what this experiment's workers can send (Ingest::max_batch_bytes); capacity_bytes: what the
  // queued batches may hold (AcceptedBatch::bytes) before the thread stops taking. The bound is in
  // bytes, not batches, so that small batches are not held back at the DDS reader: while its
  // history was full, 40 workers' heartbeats stopped reaching the learner (integration.heartbeats).
  // hold: how first batches of sessions not announced yet wait for their announcement
  // (first_batch_hold.h).
  struct Held {
    farm::msg::TransitionBatch batch;
    eprosima::fastdds::dds::SampleInfo info;
  };
  using Hold = FirstBatchHold<Ingest::Key, Held>;
  IngestThread(farm::dds::Bus& bus, Ingest ingest, uint32_t max_sample_bytes, size_t capacity_bytes, Log log,
               EventLog& events, Hold::Limits hold = Hold::Limits());
  ~IngestThread();
  IngestThread(const IngestThread&) = delete;
  IngestThread& operator=(const IngestThread&) = delete;

  // Starts taking batches (after a resume has restored the accounts), checked against `version`,
  // the algorithm's latest: a resumed run's workers send batches of the version they had from the
  // first moment, before the run's loop publishes anything.
  void start(uint64_t version);
  // The policy version batches are checked against (the algorithm's latest).
  void set_version(uint64_t v) { version_.store(v); }
  // Pops up to max accepted batches, oldest first, and hands each to take (on the caller's thread,
  // without the queue held). Returns how many.
  size_t pop(size_t max, const std::function<void(AcceptedBatch&)>& take);
  // Waits until a batch is queued or seconds pass.
  void wait(double seconds);
  // Holds the thread, hands every queued batch to take, then runs f on the accounts: what they say
  // was accepted has all been taken (a checkpoint's accounts match the algorithm's data).
  void settle(const std::function<void(AcceptedBatch&)>& take, const std::function<void(const Ingest&)>& f);
  // Runs f on the accounts with the thread held (counters, streams, expiry).
  void with_ingest(const std::function<void(Ingest&)>& f);
  IngestCounters counters() const;
  // Env steps accepted so far, without a lock (read on every update).
  uint64_t env_steps() const { return env_steps_.load(std::memory_order_relaxed); }
  // Batches accepted so far, without a lock (read around every training pass).
  uint64_t accepted() const { return accepted_.load(std::memory_order_relaxed); }
  size_t queued() const;
  // Whether worker_id has a stream of accepted batches bound to `participant` (dds::participant_key):
  // a worker the evaluations may go to. A heartbeat costs nothing to invent; a batch stream that
  // passes every check does.
  bool delivered(const std::string& worker_id, const std::string& participant) const;
  size_t queued_bytes() const;
  size_t capacity_bytes() const { return capacity_; }
  uint32_t max_sample_bytes() const { return reader_.max_sample_bytes(); }
  // Refusal lines and events said per cause (a participant's batches, samples too large, malformed
  // samples), for at most kMaxCauses causes (the rest share one set).
  static constexpr int kMaxRefusalLines = 20, kMaxRefusalEvents = 100;
  static constexpr size_t kMaxCauses = 64;
  // Batches the thread could not take because the queue was full, counted once per wait.
  uint64_t full_waits() const { return full_waits_.load(); }
  // Batches held now for their session's announcement (first_batch_hold.h).
  size_t held() const { return held_batches_.load(std::memory_order_relaxed); }

 private:
  void loop();
  // Holds batch_ (just taken) while its session's announcement is awaited, or accepts it.
  void offer();
  // Hands the held batches whose announcement was heard, or whose time is up, to accept().
  void release_held();
  // Checks a batch and queues it; false when refused (with a line for the first ones).
  bool accept(const farm::msg::TransitionBatch& batch, const eprosima::fastdds::dds::SampleInfo& info);
  std::string token_note(const eprosima::fastrtps::rtps::GUID_t& writer, const std::string& name) const;
  void ingest_event(bool force);
  // Said in the log and the events (capped): samples the reader refused, for their size or malformed.
  void refused_for_size(uint64_t n);
  void refused_malformed(uint64_t n);

  farm::dds::Bus& bus_;
  Ingest ingest_;  // guarded by mu_
  farm::dds::Reader<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType> reader_;
  const size_t capacity_;  // bytes
  Log log_;
  EventLog& events_;
  mutable std::mutex mu_;
  std::condition_variable queued_cv_, room_cv_;
  std::deque<std::unique_ptr<AcceptedBatch>> queue_;  // guarded by mu_
  size_t queued_bytes_ = 0;                           // of queue_; guarded by mu_
  bool stop_ = false;                                 // guarded by mu_
  std::atomic<uint64_t> version_{0}, env_steps_{0}, accepted_{0}, full_waits_{0};
  std::atomic<size_t> held_batches_{0};
  std::thread thread_;
  // The loop thread's own:
  farm::msg::TransitionBatch batch_;
  eprosima::fastdds::dds::SampleInfo info_;
  uint64_t malformed_seen_ = 0;  // the reader's malformed count when last booked
  Hold hold_;
  // What the log and the events have said, to keep them bounded: refusal lines and events, stream
  // retirements, other experiments whose batches were seen.
  // Refusal lines and events said so far for one cause: batches of one participant, samples too
  // large, malformed samples.
  struct Caps {
    int lines = 0, events = 0;
  };
  Caps& caps_for(const std::string& cause);
  struct Said {
    int retirements = 0;
    std::map<std::string, Caps> by_cause;  // at most kMaxCauses + 1 (the rest share "")
    std::set<std::string> foreign;
  } said_;
  // The last ingest event: when, and the counts it gave.
  struct LastEvent {
    double t = 0;
    uint64_t ok = 0, invalid = 0;
  } last_event_;

  static constexpr double kEventEveryS = 1.0;
};

}  // namespace farm
