// The farm-worker service (worker_app.h): the experiment it follows, the policy it runs, the
// batches it streams, the heartbeats it beats and the evaluations it answers.
#include "worker_app.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "config.h"
#include "task.h"

namespace farm {

// Why two alternating batch buffers and a sender thread. Sample Factory's double-buffered sampling
// splits a worker's envs into two halves so that one half steps while the other half's actions are
// computed elsewhere (its inference runs in another process, often on a GPU): the CPU never idles
// waiting for actions. Here inference is a small MLP evaluated on the stepping thread itself, row by
// row, with nothing to wait for, so halves would only interleave work on the same core. What a worker
// did wait for was its own publishing: copying a finished batch into the DDS sample, the write, and
// a write held by a full reliable history. So the halves alternate in time instead: the rollout fills
// one RolloutBatch while the sender thread serializes and writes the other, and they swap; a batch
// is never copied between the two threads, and the collect loop waits only when both buffers are
// still with the sender (back-pressure from the learner). Weights still change between batches, on
// the collect loop, so every batch is made by one policy version, which it carries.
namespace {

constexpr size_t kMaxForeignNoted = 16;
// At shutdown (stopped, or the experiment over), a batch whose write has been refused this long by a
// full history, or that has no learner to go to, is given up: nobody acknowledges it.
constexpr double kShutdownSendGiveUpS = 30.0;

uint64_t fnv1a(const std::string& s) {
  uint64_t h = 1469598103934665603ull;
  for (unsigned char c : s) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return h;
}

void to_wire(const RolloutBatch& r, farm::msg::TransitionBatch& b) {
  b.num_steps(r.T);
  b.num_envs(r.N);
  b.obs_dim(r.obs_dim);
  b.act_dim(r.act_dim);
  b.policy_version(r.policy_version);
  b.observations(r.obs);
  b.actions(r.actions);
  b.rewards(r.rewards);
  b.terminated(r.terminated);
  b.truncated(r.truncated);
  b.log_probs(r.log_probs);
  b.next_observations(r.next_obs);
  b.final_index(r.final_index);
  b.final_observations(r.final_obs);
  std::vector<farm::msg::EpisodeSummary> eps(r.episodes.size());
  for (size_t i = 0; i < eps.size(); ++i) {
    eps[i].env(r.episodes[i].env);
    eps[i].episode_return(r.episodes[i].episode_return);
    eps[i].length(r.episodes[i].length);
    eps[i].terminated(r.episodes[i].terminated);
    eps[i].metrics(r.episodes[i].metrics);
  }
  b.episodes(std::move(eps));
}

}  // namespace

WorkerApp::WorkerApp(const WorkerOptions& o, const std::atomic<bool>& stop)
    : opt_(o),
      stop_(stop),
      bus_(o.bus, "farm-worker " + o.id),
      spec_in_(bus_, farm::dds::kSpecTopic, "latest_reader",
               [this](eprosima::fastdds::dds::DataReader* r) {
                 farm::msg::ExperimentSpec s;
                 while (decltype(spec_in_)::take_from(r, s)) {
                   std::lock_guard<std::mutex> lk(in_mu_);
                   if (specs_in_.size() >= kMaxSpecsIn) specs_in_.pop_front();
                   specs_in_.push_back(s);
                 }
               }),
      weights_in_(bus_, farm::dds::kWeightsTopic, "latest_reader",
                  [this](eprosima::fastdds::dds::DataReader* r) {
                    farm::msg::PolicyWeights w;
                    while (decltype(weights_in_)::take_from(r, w)) {
                      std::lock_guard<std::mutex> lk(in_mu_);
                      if (weights_in_by_.size() >= kMaxExperimentsKept && !weights_in_by_.count(w.experiment_id())) {
                        // Bounded against a flood of invented experiments; the bound one is kept.
                        auto victim = weights_in_by_.begin();
                        if (victim->first == experiment_) ++victim;
                        weights_in_by_.erase(victim);
                      }
                      weights_in_by_[w.experiment_id()] = std::move(w);
                    }
                  }),
      batches_out_(bus_, farm::dds::kBatchTopic, "batch_writer"),
      status_out_(bus_, farm::dds::kWorkerStatusTopic, "status_writer"),
      // Requests are kept only when addressed to this worker (a queue of a few); the checks of
      // their contents come on the main loop.
      eval_in_(bus_, farm::dds::kEvalRequestTopic, "batch_reader",
               [this](eprosima::fastdds::dds::DataReader* r) {
                 farm::msg::EvaluationRequest q;
                 while (decltype(eval_in_)::take_from(r, q)) {
                   if (q.worker_id() != opt_.id) continue;
                   std::lock_guard<std::mutex> lk(in_mu_);
                   if (eval_in_q_.size() >= kMaxEvalQueue) eval_in_q_.pop_front();
                   eval_in_q_.push_back(std::move(q));
                 }
               }),
      eval_out_(bus_, farm::dds::kEvalAnswerTopic, "batch_writer"),
      session_(farm::dds::random_session_id()),
      experiment_(o.experiment) {}

int WorkerApp::run() {
  log("started: session " + std::to_string(session_) + ", domain " + std::to_string(bus_.domain()) +
      (experiment_.empty() ? "" : ", experiment '" + experiment_ + "'") + ", DDS profiles " + bus_.profiles_file() +
      (bus_.security_dir().empty() ? "" : ", DDS Security from " + bus_.security_dir()));
  sender_ = std::thread([this] { sender_main(); });
  double last_wait_note = -1e9;
  while (!stop_) {
    poll_spec();
    if (finished_) break;
    poll_eval_requests();
    if (!rollout_) {
      state_ = "waiting_for_learner";
      if (now_seconds() - last_wait_note > 5.0) {
        log("waiting for a learner: no ExperimentSpec" +
            (experiment_.empty() ? std::string() : " of experiment '" + experiment_ + "'") + " on DDS domain " +
            std::to_string(bus_.domain()) + " yet");
        last_wait_note = now_seconds();
      }
      heartbeat();
      spec_in_.wait(0.2);
      continue;
    }
    poll_weights();
    // The learner's quota for this version (PPO: how much the next fit needs), else the spec's cap.
    const uint32_t cap = batch_quota_ > 0 ? batch_quota_ : spec_.max_batches_per_version();
    if (!have_policy_ || batches_on_version_ >= cap) {
      // No weights yet, or this version has produced its share: wait for the next one.
      state_ = have_policy_ ? "throttled" : "waiting_for_weights";
      heartbeat();
      const double t = now_seconds();
      weights_in_.wait(0.05);
      throttled_s_ += now_seconds() - t;
      continue;
    }
    if (batches_out_.matched() == 0) {
      // Nobody would receive the batch: hold on rather than lose it.
      state_ = "waiting_for_learner";
      heartbeat();
      const double t = now_seconds();
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
      throttled_s_ += now_seconds() - t;
      continue;
    }
    const int buffer = next_free_buffer(0.05);
    if (buffer < 0) {
      // Both buffers still wait for the sender (a full history: the learner is behind).
      state_ = "backpressure";
      heartbeat();
      continue;
    }
    state_ = "running";
    rollout_->collect(static_cast<int>(spec_.steps_per_batch()), buffers_[buffer]);
    steps_.add(static_cast<uint64_t>(buffers_[buffer].T) * buffers_[buffer].N);
    ++batches_on_version_;
    hand_to_sender(buffer);
    heartbeat();
  }
  finish();
  return exit_code_;
}

void WorkerApp::log(const std::string& s) {
  std::printf("[worker %s] %s\n", opt_.id.c_str(), s.c_str());
  std::fflush(stdout);
}

void WorkerApp::poll_spec() {
  std::deque<farm::msg::ExperimentSpec> got;
  {
    std::lock_guard<std::mutex> lk(in_mu_);
    got.swap(specs_in_);
  }
  for (const auto& s : got) {
    on_spec(s);
    if (finished_) return;
  }
}

void WorkerApp::on_spec(const farm::msg::ExperimentSpec& s) {
  if (experiment_.empty()) {
    // Without --experiment the first experiment this worker can run binds it (join); one that is
    // over is no one's to join, and one it cannot run (a forged or broken spec) must not keep it
    // from the next.
    if (!s.finished()) join(s);
    return;
  }
  // One experiment per worker process: another one's spec (a second learner on the domain, or
  // behind a shared Discovery Server) never takes this worker over, and its sequence numbers never
  // restart under a learner that already counted them. When its experiment ends the worker ends
  // too, so serving a new experiment always starts a new process with a new session.
  if (s.experiment_id() != experiment_) {
    note_foreign(s.experiment_id());
    return;
  }
  if (s.finished()) {
    if (rollout_) {
      log("learner finished experiment '" + s.experiment_id() + "'");
      finished_ = true;
    }
    return;
  }
  if (rollout_) {
    if (s.learner_session() != spec_.learner_session()) log("learner restarted; carrying on");
    spec_ = s;
    return;
  }
  join(s);
}

void WorkerApp::join(const farm::msg::ExperimentSpec& s) {
  drain_sender(false);  // batches of an earlier join keep their session; the numbering restarts below
  try {
    config::ExperimentConfig cfg = parse_config_from_bus(s.config_text(), "ExperimentSpec(" + s.experiment_id() + ")");
    int envs = opt_.envs > 0 ? opt_.envs : cfg.worker().envs_per_worker();
    // A spec off the bus sizes this worker's batches: bounded before anything is allocated.
    if (s.steps_per_batch() < 1 || s.steps_per_batch() > uint32_t(kMaxStepsPerBatch) ||
        (long long)s.steps_per_batch() * envs > kMaxBatchTransitions)
      throw std::runtime_error("spec's steps_per_batch " + std::to_string(s.steps_per_batch()) + " x " +
                               std::to_string(envs) + " envs is outside 1.." + std::to_string(kMaxStepsPerBatch) +
                               " steps and " + std::to_string(kMaxBatchTransitions) + " transitions per batch");
    std::shared_ptr<const robots::Task> task = robots::make_task(cfg.task());
    const int eval_max = std::max(cfg.eval().episodes(), cfg.eval().final_episodes());
    if (task->spec().obs_dim != int(s.obs_dim()) || task->spec().act_dim != int(s.act_dim()))
      throw std::runtime_error("task '" + cfg.task().name() + "' shapes differ from the spec");
    // Sequence numbers restart only with a new session, so no learner counts them duplicate.
    if (sequence_ > 0) session_ = farm::dds::random_session_id();
    uint64_t seed = s.seed() ^ fnv1a(opt_.id);
    rollout_ = std::make_unique<Rollout>(task, envs, opt_.threads, seed);
    task_ = task;
    eval_max_episodes_ = eval_max;
    if (experiment_.empty()) {
      std::lock_guard<std::mutex> lk(in_mu_);  // the weights listener reads experiment_
      experiment_ = s.experiment_id();
    }
    split_at_ = {};
    spec_ = s;
    sequence_ = 0;
    have_policy_ = false;
    batches_on_version_ = 0;
    batch_quota_ = 0;
    last_error_.clear();
    log("joined experiment '" + s.experiment_id() + "': task " + cfg.task().name() + ", " + std::to_string(envs) +
        " envs on " + std::to_string(opt_.threads) + " threads, " + std::to_string(s.steps_per_batch()) +
        " steps per batch");
  } catch (const std::exception& e) {
    last_error_ = e.what();
    state_ = "error";
    log(std::string("cannot run this experiment: ") + e.what());
    rollout_.reset();
    heartbeat(true);
  }
}

void WorkerApp::note_foreign(const std::string& experiment_id) {
  if (foreign_.size() >= kMaxForeignNoted || !foreign_.insert(experiment_id).second) return;
  log("ignores experiment '" + experiment_id + "' on the bus: this worker's experiment is '" + experiment_ + "'" +
      (opt_.experiment.empty() ? " (the first one it joined; --experiment chooses)" : ""));
}

void WorkerApp::poll_weights() {
  farm::msg::PolicyWeights w;
  {
    std::lock_guard<std::mutex> lk(in_mu_);
    for (const auto& [id, _] : weights_in_by_)
      if (id != experiment_) note_foreign(id);
    auto it = weights_in_by_.find(experiment_);
    if (it == weights_in_by_.end()) return;
    w = std::move(it->second);
    weights_in_by_.erase(it);
  }
  if (have_policy_ && w.version() == rollout_->policy_version()) {
    batch_quota_ = w.batch_quota();  // the same version re-sent: a topped-up quota
    return;
  }
  try {
    PolicyParams p = farm::dds::from_wire(w);
    rollout_->set_policy(p);
    have_policy_ = true;
    batches_on_version_ = 0;
    batch_quota_ = w.batch_quota();
  } catch (const std::exception& e) {
    last_error_ = std::string("bad PolicyWeights: ") + e.what();
    log(last_error_);
  }
}

int WorkerApp::next_free_buffer(double wait) {
  const int b = next_buffer_;
  std::unique_lock<std::mutex> lk(send_mu_);
  if (!buffer_with_sender_[b]) return b;
  const double t0 = now_seconds();
  const bool free = free_cv_.wait_for(lk, std::chrono::duration<double>(wait), [&] { return !buffer_with_sender_[b]; });
  backpressure_s_ += now_seconds() - t0;
  return free ? b : -1;
}

void WorkerApp::hand_to_sender(int buffer) {
  Outgoing o;
  o.buffer = buffer;
  o.experiment_id = spec_.experiment_id();
  o.session = session_;
  {
    std::lock_guard<std::mutex> lk(send_mu_);
    buffer_with_sender_[buffer] = true;
    send_q_.push_back(std::move(o));
  }
  send_cv_.notify_one();
  next_buffer_ = (buffer + 1) % kBuffers;
}

void WorkerApp::drain_sender(bool stop_sender) {
  if (!sender_.joinable()) return;
  std::unique_lock<std::mutex> lk(send_mu_);
  if (stop_sender) sender_stop_ = true;
  send_cv_.notify_one();
  while (!send_q_.empty()) {
    free_cv_.wait_for(lk, std::chrono::milliseconds(100));
    lk.unlock();
    heartbeat();
    lk.lock();
  }
  lk.unlock();
  if (stop_sender) sender_.join();
}

// The sender thread: writes the batches handed over, in order, each under the next sequence number,
// and frees its buffer once written. It ends when told to and nothing is left.
void WorkerApp::sender_main() {
  for (;;) {
    Outgoing o;
    {
      std::unique_lock<std::mutex> lk(send_mu_);
      send_cv_.wait(lk, [this] { return sender_stop_ || !send_q_.empty(); });
      if (send_q_.empty()) return;
      o = send_q_.front();
      publishing_since_ = now_seconds();
    }
    publish_batch(o);
    {
      std::lock_guard<std::mutex> lk(send_mu_);
      publish_s_ += now_seconds() - publishing_since_;
      publishing_since_ = 0;
      send_q_.pop_front();
      if (o.buffer >= 0) buffer_with_sender_[o.buffer] = false;
    }
    free_cv_.notify_all();
  }
}

bool WorkerApp::publish_batch(const Outgoing& o) {
  const uint64_t seq = sequence_;
  const bool end_of_stream = o.buffer < 0;
  const std::string what = end_of_stream ? "the end of stream" : "batch " + std::to_string(seq);
  auto give_up = [&](const std::string& why) {
    sender_give_up_ = true;  // and every batch after it: the stream ends here
    sender_blocked_ = false;
    log("gave up sending " + what + " at shutdown (" + why + ")");
    return false;
  };
  if (sender_give_up_) return give_up("sending has stopped");
  // Nobody would receive the batch: hold on rather than lose it (at shutdown there is nobody to wait for).
  while (batches_out_.matched() == 0) {
    if (stop_ || finishing_ || sender_give_up_) return give_up("no learner matched");
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  farm::msg::TransitionBatch eos;
  farm::msg::TransitionBatch& b = end_of_stream ? eos : wire_;
  b.experiment_id(o.experiment_id);
  b.worker_id(opt_.id);
  b.worker_session(o.session);
  b.sequence_number(seq);
  b.end_of_stream(end_of_stream);
  if (!end_of_stream) {
    to_wire(buffers_[o.buffer], b);
    if (int64_t(seq) == opt_.inject_nan_batch && !b.observations().empty()) {
      b.observations()[0] = std::nanf("");
      log("fault injection: batch " + std::to_string(seq) + " carries a NaN");
    }
  } else {
    b.obs_dim(uint32_t(o.obs_dim));
    b.act_dim(uint32_t(o.act_dim));
    b.policy_version(o.policy_version);
  }
  if (opt_.inject_publish_delay_ms > 0) {  // fault injection: a slow write (the batch waits, nothing else)
    const double until = now_seconds() + 1e-3 * opt_.inject_publish_delay_ms;
    while (now_seconds() < until && !sender_give_up_) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  // A full reliable history makes write() time out: retry, never drop.
  const double first_try = now_seconds();
  while (!batches_out_.write(b)) {
    if (sender_give_up_ || (now_seconds() - first_try > kShutdownSendGiveUpS && (stop_ || finishing_)))
      return give_up("no learner acknowledges");
    sender_blocked_ = true;
  }
  sender_blocked_ = false;
  ++sequence_;
  return true;
}

void WorkerApp::end_stream() {
  if (!rollout_ || batches_out_.matched() == 0) {
    drain_sender(true);
    return;
  }
  // The end of stream goes through the sender's queue, after the last batch, under the next number.
  Outgoing eos;
  eos.experiment_id = spec_.experiment_id();
  eos.session = session_;
  eos.obs_dim = spec_.obs_dim();
  eos.act_dim = spec_.act_dim();
  eos.policy_version = rollout_->policy_version();
  {
    std::lock_guard<std::mutex> lk(send_mu_);
    send_q_.push_back(std::move(eos));
  }
  drain_sender(true);
  if (!batches_out_.wait_for_acks(10.0)) log("learner did not acknowledge every batch within 10 s");
}

void WorkerApp::finish() {
  finishing_ = true;
  stop_eval_thread();
  end_stream();
  state_ = "finished";
  heartbeat(true);
  const uint64_t sent = sequence_;
  log("finished: " + std::to_string(sent) + " batches sent (sequence 0.." + std::to_string(sent ? sent - 1 : 0) +
      "), " + std::to_string(steps_.total()) + " env steps, mean " + std::to_string(int64_t(steps_.mean_rate())) +
      " steps/s");
}

void WorkerApp::heartbeat(bool force) {
  double t = now_seconds();
  if (!force && t - last_status_ < 1.0) return;
  double rate = steps_.rate();
  last_status_ = t;
  // A worker whose collect loop waits for its quota while the sender still retries a full history
  // is not idle: its batches are on their way.
  const std::string state = sender_blocked_ && state_ == "throttled" ? "backpressure" : state_;
  farm::msg::WorkerStatus s;
  s.worker_id(opt_.id);
  s.worker_session(session_);
  s.host(farm::dds::hostname());
  s.experiment_id(experiment_);
  s.envs(rollout_ ? rollout_->num_envs() : 0);
  s.threads(opt_.threads);
  s.steps_per_second(rate);
  s.env_steps(steps_.total());
  s.batches_sent(sequence_);
  s.policy_version(rollout_ ? rollout_->policy_version() : 0);
  s.state(state);
  s.last_error(last_error_);
  status_out_.write(s);
  if (t - last_log_ >= opt_.log_every && rollout_) {
    // Steps/s over the same interval as the time split (the heartbeat's rate covers the last second).
    if (last_log_ > 0) rate = double(steps_.total() - log_steps_) / (t - last_log_);
    const uint64_t sent = sequence_;  // then the steps: collected ahead of what was sent, never behind
    log(state + ": " + std::to_string(int64_t(rate)) + " steps/s" + time_split(t) + ", " + std::to_string(sent) +
        " batches sent, " + std::to_string(steps_.total()) + " env steps, policy v" +
        std::to_string(rollout_->policy_version()));
    last_log_ = t;
    log_steps_ = steps_.total();
  }
}

// Where the wall time since the last log line went. The collect loop: simulation and policy
// inference (thread time over the rollout's threads, so with one thread the share of wall time the
// worker simulated), waiting for a free buffer (back-pressure: both with the sender) and waiting on
// the learner (throttled: quota spent, no weights or no learner); the rest is bookkeeping. The
// sender thread, beside it: serializing and writing batches, retries on a full history included.
std::string WorkerApp::time_split(double t) {
  const Rollout::Timing now = rollout_->timing();
  const double wall = t - last_log_, k = rollout_->num_threads();
  double publish_s = 0;  // the sender's time in publish_batch() so far, the write in progress included
  {
    std::lock_guard<std::mutex> lk(send_mu_);
    publish_s = publish_s_ + (publishing_since_ > 0 ? t - publishing_since_ : 0.0);
  }
  std::string s;
  if (last_log_ > 0 && wall > 0) {
    auto pct = [&](double x) { return std::to_string(int(std::lround(100.0 * x / wall))) + "%"; };
    s = " (collect: simulate " + pct((now.simulate_s - split_at_.simulate_s) / k) + ", infer " +
        pct((now.infer_s - split_at_.infer_s) / k) + ", backpressure " + pct(backpressure_s_ - split_backpressure_s_) +
        ", throttled " + pct(throttled_s_ - split_throttled_s_) + "; sender: publish " +
        pct(publish_s - split_publish_s_) + ")";
  }
  split_at_ = now;
  split_publish_s_ = publish_s;
  split_backpressure_s_ = backpressure_s_;
  split_throttled_s_ = throttled_s_;
  return s;
}

WorkerApp::~WorkerApp() {
  stop_eval_thread();
  if (sender_.joinable()) {  // run() did not finish (an exception): what is queued is dropped
    sender_give_up_ = true;
    {
      std::lock_guard<std::mutex> lk(send_mu_);
      sender_stop_ = true;
    }
    send_cv_.notify_all();
    sender_.join();
  }
}

// Requests addressed to this worker (the listener kept only those): of its experiment, sized within
// what the experiment asks, with a policy that fits the task. Each good one becomes a job for the
// evaluation thread; a bad one is answered with what was wrong (the learner counts it invalid).
void WorkerApp::poll_eval_requests() {
  std::deque<farm::msg::EvaluationRequest> got;
  {
    std::lock_guard<std::mutex> lk(in_mu_);
    got.swap(eval_in_q_);
  }
  for (auto& q : got) {
    if (!rollout_ || q.experiment_id() != experiment_) continue;  // not (yet) this worker's experiment
    log("evaluation request " + std::to_string(q.request_id()) + ": " + std::to_string(q.episodes()) +
        " episodes of policy v" + std::to_string(q.policy_version()));
    if (q.episodes() < 1 || q.episodes() > uint32_t(eval_max_episodes_)) {
      answer_error(q, "episodes " + std::to_string(q.episodes()) + " outside 1.." + std::to_string(eval_max_episodes_) +
                          " (the experiment's eval.episodes / final_episodes)");
      continue;
    }
    if (q.policy().experiment_id() != experiment_ || q.policy().version() != q.policy_version()) {
      answer_error(q, "the policy carried is v" + std::to_string(q.policy().version()) + " of '" +
                          q.policy().experiment_id().substr(0, 64) + "', not v" + std::to_string(q.policy_version()));
      continue;
    }
    EvalJob job;
    try {
      job.policy = farm::dds::from_wire(q.policy());  // its fit to the task: evaluate_policy checks it
    } catch (const std::exception& e) {
      answer_error(q, std::string("bad policy: ") + e.what());
      continue;
    }
    job.task = task_;
    job.worker_session = session_;
    {
      std::lock_guard<std::mutex> lk(eval_mu_);
      if (eval_jobs_.size() >= kMaxEvalQueue) {
        answer_error(q, "busy: " + std::to_string(eval_jobs_.size()) + " evaluations waiting already");
        continue;
      }
      job.request = std::move(q);
      eval_jobs_.push_back(std::move(job));
    }
    if (!eval_thread_.joinable()) eval_thread_ = std::thread([this] { eval_thread_main(); });
    eval_cv_.notify_one();
  }
}

farm::msg::EvaluationAnswer WorkerApp::answer_to(const farm::msg::EvaluationRequest& q, uint64_t session) const {
  farm::msg::EvaluationAnswer a;
  a.experiment_id(q.experiment_id());
  a.learner_session(q.learner_session());
  a.request_id(q.request_id());
  a.worker_id(opt_.id);
  a.worker_session(session);
  a.policy_version(q.policy_version());
  return a;
}

void WorkerApp::answer_error(const farm::msg::EvaluationRequest& q, const std::string& why) {
  log("evaluation request " + std::to_string(q.request_id()) + " refused: " + why);
  farm::msg::EvaluationAnswer a = answer_to(q, session_);
  a.error(why.substr(0, farm::dds::kMaxEvalTextBytes));
  eval_out_.write(a);
}

// The evaluation thread: one job at a time, on evaluation envs made for it (evaluate_policy: one env
// per episode, reset from the request's seed), never the training envs.
void WorkerApp::eval_thread_main() {
  while (true) {
    EvalJob job;
    {
      std::unique_lock<std::mutex> lk(eval_mu_);
      eval_cv_.wait(lk, [this] { return eval_stop_ || !eval_jobs_.empty(); });
      if (eval_stop_) return;
      job = std::move(eval_jobs_.front());
      eval_jobs_.pop_front();
    }
    const auto& q = job.request;
    farm::msg::EvaluationAnswer a = answer_to(q, job.worker_session);
    const double t0 = now_seconds();
    try {
      const auto recs = evaluate_policy(job.task, job.policy, int(q.episodes()), q.seed(), &eval_stop_);
      if (eval_stop_) return;
      std::vector<farm::msg::EvaluationEpisode> eps(recs.size());
      for (size_t i = 0; i < recs.size(); ++i) {
        eps[i].episode_return(recs[i].episode_return);
        eps[i].length(uint32_t(recs[i].length));
        eps[i].terminated(recs[i].terminated);
        eps[i].metrics(recs[i].metrics);
      }
      a.episodes(std::move(eps));
    } catch (const std::exception& e) {
      a.error(std::string(e.what()).substr(0, farm::dds::kMaxEvalTextBytes));
    }
    a.seconds(now_seconds() - t0);
    double sum = 0;
    for (const auto& e : a.episodes()) sum += e.episode_return();
    // A full reliable history makes write() time out: retry while the worker runs.
    while (!eval_out_.write(a) && !eval_stop_) {
    }
    char figures[96];
    std::snprintf(figures, sizeof figures, ": mean return %.1f over %zu episodes (%.1f s)",
                  a.episodes().empty() ? 0.0 : sum / double(a.episodes().size()), a.episodes().size(), a.seconds());
    log("evaluation " + std::to_string(q.request_id()) + " answered" +
        (a.error().empty() ? std::string(figures) : " with an error: " + a.error()));
  }
}

void WorkerApp::stop_eval_thread() {
  {
    std::lock_guard<std::mutex> lk(eval_mu_);
    eval_stop_ = true;
  }
  eval_cv_.notify_all();
  if (eval_thread_.joinable()) eval_thread_.join();
}

}  // namespace farm
