// The worker's evaluations: the learner's EvaluationRequests addressed to this worker are kept as
// they arrive (a queue of a few, apart from other participants' so that no flood of theirs pushes
// the learner's out), checked on the collect loop against the joined experiment and
// learner (another participant's are not run, nor answered), and
// run one at a time by a thread of their own on evaluation envs apart from the training ones, so
// batches keep flowing meanwhile; each is answered with its episodes or with what was wrong.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include <nlohmann/json.hpp>

#include "dds.h"
#include "farm.h"
#include "farmPubSubTypes.h"
#include "once_per.h"
#include "rollout.h"

namespace farm {

class Evaluations {
 public:
  using Log = std::function<void(const std::string&)>;
  // An event of the worker's record (worker_app.h): its kind and fields.
  using Event = std::function<void(const std::string&, nlohmann::json)>;
  Evaluations(farm::dds::Bus& bus, const std::string& worker_id, Log log, Event event = nullptr);
  ~Evaluations() { stop(); }

  // What a request is checked against: the joined experiment, its task, the most episodes it asks
  // (eval.episodes / final_episodes, the larger) and this worker's session.
  struct Joined {
    std::string experiment;
    std::shared_ptr<const robots::Task> task;
    int max_episodes = 0;
    uint64_t session = 0;
    std::string learner;  // the joined learner's participant (dds::participant_key)
  };
  // Checks the requests that arrived: a good one is queued for the thread, a bad one answered with
  // what was wrong (the learner counts it invalid). Before a join (no task) they are dropped.
  void poll(const Joined& joined);
  // Whether requests arrived since the last poll (the collect loop asks on every pass).
  bool arrived();
  // Ends the thread; an evaluation running stops at its next step, unanswered.
  void stop();

 private:
  struct Job {
    farm::msg::EvaluationRequest request;
    PolicyParams policy;
    std::shared_ptr<const robots::Task> task;
    uint64_t worker_session = 0;  // when it was asked
  };
  // The answer to q from this worker and `session`, episodes and error still empty.
  farm::msg::EvaluationAnswer answer_to(const farm::msg::EvaluationRequest& q, uint64_t session) const;
  void answer_error(const farm::msg::EvaluationRequest& q, uint64_t session, const std::string& why);
  void main();

  static constexpr size_t kMaxQueue = 4;
  const std::string worker_id_;
  Log log_;
  Event event_;
  std::mutex in_mu_;
  struct In {
    farm::msg::EvaluationRequest request;
    std::string participant;  // of its writer
    bool held = false;        // kept aside at a poll already (counted in not_learners_ then)
  };
  std::string learner_;      // the joined learner's participant, as of the last poll()
  std::deque<In> in_q_;      // from learner_, addressed to this worker; bounded: kMaxQueue
  std::deque<In> others_q_;  // from any other participant (or before a join); bounded: kMaxQueue
  // Requests of the worker's experiment from another participant than its learner, kept aside
  // (bounded: kMaxQueue, oldest out) and looked at again at each poll: a learner resumed after a
  // crash asks before the worker believes it (until the crashed one's lease runs out), and its
  // requests run once it does. Only the loop's thread (poll, arrived) touches it.
  std::deque<In> held_;
  uint64_t not_learners_ = 0;  // requests from another participant than the joined learner's
  OncePer not_learners_note_{std::chrono::seconds(10)};
  farm::dds::Reader<farm::msg::EvaluationRequest, farm::msg::EvaluationRequestPubSubType> in_;
  farm::dds::Writer<farm::msg::EvaluationAnswer, farm::msg::EvaluationAnswerPubSubType> out_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<Job> jobs_;  // bounded: kMaxQueue
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace farm
