// The farm-worker service: joins the learner's experiment from the ExperimentSpec on the bus,
// takes its PolicyWeights, collects rollouts and streams them as TransitionBatches, and beats a
// WorkerStatus heartbeat. It can join late or restart at any time, and follows a restarted learner.
// It answers the learner's EvaluationRequests addressed to it: deterministic episodes on evaluation
// envs of their own (own seeds, apart from the training envs), in a thread of their own, so its
// batches keep flowing meanwhile.
// It is bound to one experiment (--experiment, else the first one it joins) and ignores the specs
// and weights of any other that shares the domain; it ends with its experiment.
// It is a runner of the parts its threads are: the intake of specs and weights (intake.h), the
// rollout (rollout.h), the batch sender (batch_sender.h), the evaluations (evaluations.h) and the
// heartbeat (heartbeat.h). This class runs the collect loop: it joins, follows the learner's
// versions and quotas, collects batches and hands them to the sender, and builds the status.
// With --events FILE it keeps a record for programs beside its log (common/event_log.h), one JSON
// object a line with "event" and "elapsed_s" (seconds since the worker started). Kinds:
//   start              worker_id, session, domain, experiment (--experiment; "" for any),
//                      security_dir ("" without DDS Security), participant_id (the DDS participant
//                      id it asked for; null when Fast DDS chose: a profile without shared memory),
//                      shm_segments_removed and shm_bytes_removed (data segments of ended Fast DDS
//                      processes it removed from /dev/shm before it started, and their bytes)
//   waiting            for a learner: no spec of its experiment yet (as often as the log says so)
//   joined             experiment_id, task, envs, threads, steps_per_batch, nice (worker.nice),
//                      session
//   join_failed        experiment_id, error: a spec it cannot run (it joins nothing)
//   foreign            experiment_id: another experiment on the bus, ignored (once each, bounded)
//   spec_refused       experiment_id, count, reason (at most one each 10 s, as the log)
//   weights_refused    count: weights of its experiment from another participant than its learner
//   learner_restarted  learner_session: a new learner of the same experiment, followed
//   learner_finished   experiment_id
//   progress           at each log line: state, unix_s (its wall-clock time, Unix seconds: to set
//                      against other processes' clocks), steps_per_s, batches_sent, env_steps,
//                      policy_version, and where the wall time went since the last one, as
//                      fractions (simulate, infer, backpressure, throttled, publish; null at the first)
//   eval_request       request_id, episodes, policy_version: a request of its learner taken
//   eval_refused       request_id, why: answered with what was wrong
//   eval_answered      request_id, episodes, mean_return, seconds, error ("" when none)
//   finished           batches_sent, last_sequence, env_steps, mean_steps_per_s
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <set>
#include <string>

#include "batch_sender.h"
#include "dds.h"
#include "evaluations.h"
#include "event_log.h"
#include "heartbeat.h"
#include "intake.h"
#include "meter.h"
#include "once_per.h"
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
  // The worker's events file (JSON lines); empty: none.
  std::string events;
};

class WorkerApp {
 public:
  // Creates the DDS entities. stop: set (by a signal handler) to end run() with the end of stream.
  WorkerApp(const WorkerOptions& o, const std::atomic<bool>& stop);

  // Runs until stopped or the learner finishes the experiment; returns the process exit code.
  int run();

 private:
  using SpecIn = WorkerIntake::SpecIn;
  void log(const std::string& s);
  void poll_spec();
  void on_spec(const SpecIn& in);
  void join(const SpecIn& in);
  // Why a spec of the joined experiment cannot replace the one this worker runs ("" when it can):
  // the checks of join() against the running task (config, sizes, its task section unchanged).
  std::string check_spec_update(const farm::msg::ExperimentSpec& s) const;
  void refuse_spec(const std::string& why);
  // A spec of a new learner session of the joined experiment: said in the log and the events.
  void learner_restarted(const farm::msg::ExperimentSpec& s);
  // One log line the first time an experiment other than this worker's shows up.
  void note_foreign(const std::string& experiment_id);
  void poll_weights();
  void finish();
  void heartbeat(bool force = false);
  BatchSender::Stream stream() const { return {joined_.spec.experiment_id(), session_}; }
  // Where the wall time since the last log line went (fractions; valid false at the first line),
  // and the log line's words for it.
  struct TimeSplit {
    bool valid = false;
    double simulate = 0, infer = 0, backpressure = 0, throttled = 0, publish = 0;
    std::string text() const;
  };
  TimeSplit time_split(double t);

  WorkerOptions opt_;
  const std::atomic<bool>& stop_;
  EventLog events_;
  farm::dds::Bus bus_;
  WorkerIntake intake_;
  BatchSender sender_;
  Evaluations evals_;
  Heartbeat beat_;
  std::unique_ptr<Rollout> rollout_;
  uint64_t session_;
  std::string experiment_;  // the bound experiment; empty until the first join (no --experiment)
  // The joined experiment: its spec, task and sizes. The learner joined is the writer of the spec
  // this worker runs: a spec, or the end of the experiment, counts only from it; another writer's
  // spec waits (the latest one, `pending`) until that learner has left the bus (a restarted
  // learner), and is checked then.
  struct Joined {
    farm::msg::ExperimentSpec spec;
    std::shared_ptr<const robots::Task> task;
    std::string task_section;  // the joined config's task section, serialized
    int envs = 0;
    int eval_max_episodes = 0;  // the experiment's eval.episodes / final_episodes, the larger
    eprosima::fastrtps::rtps::GUID_t learner_writer;
    std::optional<SpecIn> pending;
  } joined_;
  // Specs refused and experiments not this worker's: counted, and said in the log at a bounded rate.
  struct Refusals {
    uint64_t specs = 0, weights = 0;
    OncePer spec_note{std::chrono::seconds(10)}, weights_note{std::chrono::seconds(10)};
    std::set<std::string> foreign;  // other experiments already noted (bounded)
  } refusals_;
  // The policy run and what the learner allows on it: batches sent on this version, and the quota
  // (0: the spec's max_batches_per_version).
  struct Quota {
    bool have_policy = false;
    uint32_t sent_on_version = 0, quota = 0;
  } quota_;
  bool finished_ = false;
  int exit_code_ = 0;
  std::string state_ = "starting", last_error_;
  // Steps and where the wall time went, for the heartbeat and the throughput line: the collect
  // loop's waits on the learner (throttled, no weights, no learner), and what each had reached at
  // the last log line.
  struct Throughput {
    Meter steps;
    double last_status = 0, last_log = 0;
    uint64_t log_steps = 0;  // steps.total() at the last log line
    double throttled_s = 0;
    double at_backpressure_s = 0, at_throttled_s = 0, at_publish_s = 0;
    Rollout::Timing at_rollout;
  } tp_;
};

}  // namespace farm
