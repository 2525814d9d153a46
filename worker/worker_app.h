// The farm-worker service: joins the learner's experiment from the ExperimentSpec on the bus,
// takes its PolicyWeights, collects rollouts and streams them as TransitionBatches, and beats a
// WorkerStatus heartbeat. It can join late or restart at any time, and follows a restarted learner.
// It answers the learner's EvaluationRequests addressed to it: deterministic episodes on evaluation
// envs of their own (own seeds, apart from the training envs), in a thread of their own, so its
// batches keep flowing meanwhile.
// It is bound to one experiment (--experiment, else the first one it joins) and ignores the specs
// and weights of any other that shares the domain; it ends with its experiment.
// Simulation never waits for publishing: the main loop collects into one of two batch buffers while
// a sender thread serializes and writes the other (worker_app.cpp says why this is the farm's form
// of double-buffered sampling); the main loop waits only when both buffers wait to be sent.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>

#include "dds.h"
#include "meter.h"
#include "rollout.h"

namespace farm {

struct WorkerOptions {
  farm::dds::BusOptions bus;
  int envs = 0;  // 0: the experiment's worker.envs_per_worker
  int threads = 1;
  std::string id;
  // The experiment this worker serves; empty: the first one it can join.
  std::string experiment;
  double log_every = 5.0;
  // Fault injection for reliability tests: corrupt the batch with this sequence number (NaN).
  int64_t inject_nan_batch = -1;
  // Fault injection: the sender waits this long before each write, as if DDS were slow to take it.
  int inject_publish_delay_ms = 0;
};

class WorkerApp {
 public:
  // Creates the DDS entities. stop: set (by a signal handler) to end run() with the end of stream.
  WorkerApp(const WorkerOptions& o, const std::atomic<bool>& stop);

  // Runs until stopped or the learner finishes the experiment; returns the process exit code.
  int run();
  ~WorkerApp();

 private:
  void log(const std::string& s);
  // A spec as it arrived, with the writer that sent it.
  struct SpecIn {
    farm::msg::ExperimentSpec spec;
    eprosima::fastrtps::rtps::GUID_t writer;
  };
  void poll_spec();
  void on_spec(const SpecIn& in);
  void join(const SpecIn& in);
  // Why a spec of the joined experiment cannot replace the one this worker runs ("" when it can):
  // the checks of join() against the running task (config, sizes, its task section unchanged).
  std::string check_spec_update(const farm::msg::ExperimentSpec& s) const;
  void refuse_spec(const std::string& why);
  // One log line the first time an experiment other than this worker's shows up.
  void note_foreign(const std::string& experiment_id);
  void poll_weights();
  // The double buffer. Main loop: next_free_buffer() (the one to collect into, or -1 after waiting
  // up to `wait` seconds while both are with the sender), hand_to_sender() once it is filled.
  int next_free_buffer(double wait);
  void hand_to_sender(int buffer);
  // Waits until the sender has written (or, at shutdown, given up) every batch handed to it,
  // beating heartbeats meanwhile; with stop_sender the thread ends too.
  void drain_sender(bool stop_sender);
  void sender_main();
  // What the sender is handed: a filled buffer (or the end of stream) and the stream it belongs to.
  struct Outgoing {
    int buffer = -1;  // -1: end of stream
    std::string experiment_id;
    uint64_t session = 0;
    uint64_t obs_dim = 0, act_dim = 0, policy_version = 0;  // for the end of stream
  };
  // On the sender thread: serializes and writes one of them under sequence number sequence_, and
  // counts it; false when it gave up at shutdown.
  bool publish_batch(const Outgoing& o);
  void end_stream();
  void finish();
  void heartbeat(bool force = false);
  // The beat thread: re-sends the loop's last status while the loop is busy in one long call.
  void beat_main();
  void stop_beat_thread();
  // Evaluation requests: checked on the main loop, run by eval_thread_, answered from there.
  void poll_eval_requests();
  // The answer to q from this worker's id and `session`, episodes and error still empty.
  farm::msg::EvaluationAnswer answer_to(const farm::msg::EvaluationRequest& q, uint64_t session) const;
  void answer_error(const farm::msg::EvaluationRequest& q, const std::string& why);
  void eval_thread_main();
  void stop_eval_thread();
  std::string time_split(double t);

  WorkerOptions opt_;
  const std::atomic<bool>& stop_;
  // Specs and weights are taken on Fast DDS's listener thread as they arrive: the readers keep
  // one sample for all learners together, so with two experiments on the domain the other one's
  // next write would otherwise replace ours before the main loop takes it. Specs are kept in
  // order (the first experiment seen binds an unbound worker), weights the latest per experiment.
  std::mutex in_mu_;
  std::deque<SpecIn> specs_in_;                                    // bounded: kMaxSpecsIn
  std::map<std::string, farm::msg::PolicyWeights> weights_in_by_;  // bounded: kMaxExperimentsKept
  static constexpr size_t kMaxSpecsIn = 256, kMaxExperimentsKept = 8;
  farm::dds::Bus bus_;
  farm::dds::Reader<farm::msg::ExperimentSpec, farm::msg::ExperimentSpecPubSubType> spec_in_;
  farm::dds::Reader<farm::msg::PolicyWeights, farm::msg::PolicyWeightsPubSubType> weights_in_;
  farm::dds::Writer<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType> batches_out_;
  farm::dds::Writer<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType> status_out_;
  std::deque<farm::msg::EvaluationRequest> eval_in_q_;  // addressed to this worker; bounded: kMaxEvalQueue
  farm::dds::Reader<farm::msg::EvaluationRequest, farm::msg::EvaluationRequestPubSubType> eval_in_;
  farm::dds::Writer<farm::msg::EvaluationAnswer, farm::msg::EvaluationAnswerPubSubType> eval_out_;
  // Jobs for the evaluation thread: requests checked, with their policy and task.
  struct EvalJob {
    farm::msg::EvaluationRequest request;
    PolicyParams policy;
    std::shared_ptr<const robots::Task> task;
    uint64_t worker_session = 0;  // when it was asked
  };
  std::mutex eval_mu_;
  std::condition_variable eval_cv_;
  std::deque<EvalJob> eval_jobs_;  // bounded: kMaxEvalQueue
  std::atomic<bool> eval_stop_{false};
  std::thread eval_thread_;
  static constexpr size_t kMaxEvalQueue = 4;
  std::shared_ptr<const robots::Task> task_;  // of the joined experiment
  int eval_max_episodes_ = 0;                 // the experiment's eval.episodes / final_episodes, the larger
  uint64_t session_;
  std::string experiment_;          // the bound experiment; empty until the first join (no --experiment)
  std::set<std::string> foreign_;   // other experiments already noted (bounded)
  farm::msg::ExperimentSpec spec_;  // of experiment_, once joined
  // The learner joined: the writer of the spec this worker runs. A spec, or the end of the
  // experiment, counts only from it; another writer's spec waits (the latest one) until that
  // learner has left the bus (a restarted learner), and is checked then.
  eprosima::fastrtps::rtps::GUID_t learner_writer_;
  std::optional<SpecIn> pending_spec_;
  std::string joined_task_;  // the joined config's task section, serialized
  int envs_ = 0;             // envs of the joined rollout
  uint64_t specs_refused_ = 0;
  std::chrono::steady_clock::time_point last_refusal_log_{};
  std::unique_ptr<Rollout> rollout_;
  // Two batch buffers: one being collected, the other with the sender (queued or being written).
  // send_q_ holds the buffers handed over, in collection order; a buffer is free again once written.
  static constexpr int kBuffers = 2;
  RolloutBatch buffers_[kBuffers];
  int next_buffer_ = 0;  // the collect loop alternates between them
  std::mutex send_mu_;
  std::condition_variable send_cv_, free_cv_;  // the sender: work to do; the collect loop: a buffer free
  std::deque<Outgoing> send_q_;                // bounded by kBuffers
  bool buffer_with_sender_[kBuffers] = {false, false};
  bool sender_stop_ = false;                 // end once the queue is empty
  std::atomic<bool> sender_give_up_{false};  // drop what is left (shutdown without a learner)
  std::atomic<bool> sender_blocked_{false};  // a write is retrying on a full reliable history
  std::atomic<bool> finishing_{false};       // finish() is draining: a write may give up after 30 s
  std::thread sender_;
  farm::msg::TransitionBatch wire_;    // the sender's sample, reused so its sequences keep their storage
  std::atomic<uint64_t> sequence_{0};  // the next sequence number: the sender's (join() resets it, queue empty)
  uint32_t batches_on_version_ = 0;
  uint32_t batch_quota_ = 0;  // 0: spec_.max_batches_per_version()
  bool have_policy_ = false;
  bool finished_ = false;
  int exit_code_ = 0;
  std::string state_ = "starting", last_error_;
  Meter steps_;
  double last_status_ = 0, last_log_ = 0;
  // Heartbeats between the loop's own: one collect of a slow task (mCLARI: 4 steps of 4 envs, each
  // step up to 3,000 physics steps) or an evaluation beside it on a busy host takes longer than the
  // learner's worker_timeout_seconds (4 s), which then marked a live worker dead and gave up the
  // evaluation it held. The beat thread re-sends the loop's last status when the loop has sent none
  // for 1.5 s (at most about 1.75 s apart), as long as the loop built one within kMaxLoopSilenceS: a
  // loop stuck longer goes silent. Both write under beat_mu_, so statuses go out in order.
  static constexpr double kMaxLoopSilenceS = 60.0;
  std::mutex beat_mu_;
  std::condition_variable beat_cv_;
  bool beat_stop_ = false;
  farm::msg::WorkerStatus beat_;  // the loop's last status, and when it was built and last sent
  double beat_built_ = -1, beat_sent_ = 0;
  std::thread beat_thread_;
  uint64_t log_steps_ = 0;  // steps_.total() at the last log line
  // Where the wall time went, for the throughput line. The collect loop's waits: on the sender
  // (both buffers with it: back-pressure) and on the learner (throttled, no weights, no learner).
  double backpressure_s_ = 0, throttled_s_ = 0, split_backpressure_s_ = 0, split_throttled_s_ = 0;
  // The sender's time in publish_batch(): finished writes, and when the current one began (0: none);
  // under send_mu_.
  double publish_s_ = 0, publishing_since_ = 0, split_publish_s_ = 0;
  Rollout::Timing split_at_;
};

}  // namespace farm
