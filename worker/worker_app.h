// The farm-worker service: joins the learner's experiment from the ExperimentSpec on the bus,
// takes its PolicyWeights, collects rollouts and streams them as TransitionBatches, and beats a
// WorkerStatus heartbeat. It follows whatever experiment the bus announces (join, learner restart,
// a new experiment, the end), so a worker can join late or restart at any time.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>

#include "dds.h"
#include "meter.h"
#include "rollout.h"

namespace farm {

struct WorkerOptions {
  farm::dds::BusOptions bus;
  int envs = 0;      // 0: the experiment's worker.envs_per_worker
  int threads = 1;
  std::string id;
  double log_every = 5.0;
  // Fault injection for reliability tests: corrupt the batch with this sequence number (NaN).
  int64_t inject_nan_batch = -1;
};

class WorkerApp {
 public:
  // Creates the DDS entities. stop: set (by a signal handler) to end run() with the end of stream.
  WorkerApp(const WorkerOptions& o, const std::atomic<bool>& stop);

  // Runs until stopped or the learner finishes the experiment; returns the process exit code.
  int run();

 private:
  void log(const std::string& s);
  void poll_spec();
  void poll_weights();
  void publish_batch(bool end_of_stream);
  void end_stream();
  void finish();
  void heartbeat(bool force = false);
  std::string time_split(double t);

  WorkerOptions opt_;
  const std::atomic<bool>& stop_;
  farm::dds::Bus bus_;
  farm::dds::Reader<farm::msg::ExperimentSpec, farm::msg::ExperimentSpecPubSubType> spec_in_;
  farm::dds::Reader<farm::msg::PolicyWeights, farm::msg::PolicyWeightsPubSubType> weights_in_;
  farm::dds::Writer<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType> batches_out_;
  farm::dds::Writer<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType> status_out_;
  uint64_t session_;
  farm::msg::ExperimentSpec spec_;
  std::unique_ptr<Rollout> rollout_;
  RolloutBatch batch_;
  uint64_t sequence_ = 0;
  uint32_t batches_on_version_ = 0;
  uint32_t batch_quota_ = 0;  // 0: spec_.max_batches_per_version()
  bool have_policy_ = false;
  bool finished_ = false;
  int exit_code_ = 0;
  std::string state_ = "starting", last_error_;
  Meter steps_;
  double last_status_ = 0, last_log_ = 0;
  double publish_s_ = 0, split_publish_s_ = 0;  // seconds in publish_batch()
  Rollout::Timing split_at_;
};

}  // namespace farm
