// The farm-worker service (worker_app.h): the experiment it follows, the policy it runs and the
// heartbeats it beats; the batches it streams are sent by worker_sender.cpp, the evaluations it
// answers run in worker_evals.cpp.
#include "worker_app.h"

#include <sys/resource.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <memory>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "config.h"
#include "printable.h"
#include "task.h"

namespace farm {

namespace {

constexpr size_t kMaxForeignNoted = 16;

uint64_t fnv1a(const std::string& s) {
  uint64_t h = 1469598103934665603ull;
  for (unsigned char c : s) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return h;
}

}  // namespace

WorkerApp::WorkerApp(const WorkerOptions& o, const std::atomic<bool>& stop)
    : opt_(o),
      stop_(stop),
      bus_(o.bus, "farm-worker " + o.id),
      // Each reader refuses samples larger than any experiment allows before taking memory for them.
      spec_in_(bus_, farm::dds::kSpecTopic, "latest_reader", farm::dds::kMaxSpecBytes,
               [this](eprosima::fastdds::dds::DataReader* r) {
                 SpecIn in;
                 eprosima::fastdds::dds::SampleInfo info;
                 while (decltype(spec_in_)::take_from(r, in.spec, info)) {
                   in.writer = info.sample_identity.writer_guid();
                   std::lock_guard<std::mutex> lk(in_mu_);
                   if (specs_in_.size() >= kMaxSpecsIn) specs_in_.pop_front();
                   specs_in_.push_back(in);
                 }
               }),
      weights_in_(bus_, farm::dds::kWeightsTopic, "latest_reader", farm::dds::kMaxPolicyBytes,
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
      eval_in_(bus_, farm::dds::kEvalRequestTopic, "batch_reader", farm::dds::kMaxEvalRequestBytes,
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
  log("started: session " + std::to_string(session_) + ", domain " + std::to_string(bus_.domain()) + " (" +
      bus_.participant_label() + ")" + (experiment_.empty() ? "" : ", experiment '" + experiment_ + "'") +
      ", DDS profiles " + bus_.profiles_file() +
      (bus_.security_dir().empty() ? "" : ", DDS Security from " + bus_.security_dir()));
  sender_ = std::thread([this] { sender_main(); });
  beat_thread_ = std::thread([this] { beat_main(); });
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
  // Lines quote what came from the bus (experiment ids, config errors): made printable and cut, so
  // no escape sequence a participant sends reaches the operator's terminal.
  std::printf("[worker %s] %s\n", opt_.id.c_str(), printable(s, 8192, false).c_str());
  std::fflush(stdout);
}

void WorkerApp::poll_spec() {
  std::deque<SpecIn> got;
  {
    std::lock_guard<std::mutex> lk(in_mu_);
    got.swap(specs_in_);
  }
  for (const auto& s : got) {
    on_spec(s);
    if (finished_) return;
  }
  // The joined learner has left the bus (its lease ran out, or it ended without a last word): the
  // latest spec of another writer is the experiment's learner now, a restarted one.
  if (pending_spec_ && rollout_ && !spec_in_.writer_matched(learner_writer_)) {
    SpecIn next = std::move(*pending_spec_);
    pending_spec_.reset();
    const std::string why = check_spec_update(next.spec);
    if (!why.empty()) return refuse_spec(why);
    if (next.spec.learner_session() != spec_.learner_session()) log("learner restarted; carrying on");
    learner_writer_ = next.writer;
    spec_ = next.spec;
  }
}

void WorkerApp::refuse_spec(const std::string& why) {
  ++specs_refused_;
  // What a participant sends is not for it to fill this worker's log: one line per 10 s at most.
  const auto now = std::chrono::steady_clock::now();
  if (now - last_refusal_log_ < std::chrono::seconds(10)) return;
  last_refusal_log_ = now;
  log("refused a spec of experiment '" + experiment_ + "' (" + std::to_string(specs_refused_) + " so far): " + why);
}

std::string WorkerApp::check_spec_update(const farm::msg::ExperimentSpec& s) const {
  // The learner republishes its spec every few seconds with the same config text: that text was
  // checked when the running spec came, and is parsed again only when it changed.
  if (s.config_text() != spec_.config_text()) {
    config::ExperimentConfig cfg;
    try {
      cfg = parse_config_from_bus(s.config_text(), "ExperimentSpec(" + s.experiment_id() + ")");
    } catch (const std::exception& e) {
      return e.what();
    }
    if (cfg.task().SerializeAsString() != joined_task_) return "its task section differs from the one this worker runs";
  }
  if (s.steps_per_batch() < 1 || s.steps_per_batch() > uint32_t(kMaxStepsPerBatch) ||
      (long long)s.steps_per_batch() * envs_ > kMaxBatchTransitions)
    return "steps_per_batch " + std::to_string(s.steps_per_batch()) + " x " + std::to_string(envs_) +
           " envs is outside 1.." + std::to_string(kMaxStepsPerBatch) + " steps and " +
           std::to_string(kMaxBatchTransitions) + " transitions per batch";
  if (s.max_batches_per_version() < 1) return "max_batches_per_version 0: no batch could be sent";
  if (int(s.obs_dim()) != task_->spec().obs_dim || int(s.act_dim()) != task_->spec().act_dim)
    return "its obs_dim " + std::to_string(s.obs_dim()) + " / act_dim " + std::to_string(s.act_dim()) +
           " are not the task's " + std::to_string(task_->spec().obs_dim) + " / " +
           std::to_string(task_->spec().act_dim);
  return "";
}

void WorkerApp::on_spec(const SpecIn& in) {
  const farm::msg::ExperimentSpec& s = in.spec;
  if (experiment_.empty()) {
    // Without --experiment the first experiment this worker can run binds it (join); one that is
    // over is no one's to join, and one it cannot run (a forged or broken spec) must not keep it
    // from the next.
    if (!s.finished()) join(in);
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
  if (!rollout_) {
    if (!s.finished()) join(in);
    return;
  }
  // Joined: only the learner joined speaks for the experiment. Another writer's spec (an impostor,
  // or a restarted learner while the old one is still on the bus) waits until that learner has
  // left; another writer's end of the experiment is not believed at all.
  if (in.writer != learner_writer_) {
    if (s.finished()) return refuse_spec("an end of the experiment from a participant other than its learner");
    pending_spec_ = in;
    return;
  }
  if (s.finished()) {
    log("learner finished experiment '" + s.experiment_id() + "'");
    finished_ = true;
    return;
  }
  // Checked every time, as at join: a spec that would size batches past their bounds, stall the
  // worker or change its task is refused, and the worker runs on with the spec it has.
  const std::string why = check_spec_update(s);
  if (!why.empty()) return refuse_spec(why);
  if (s.learner_session() != spec_.learner_session()) log("learner restarted; carrying on");
  spec_ = s;
}

namespace {

// worker.nice: every thread this process has now (the rollout's, the bus's, the heartbeat's) goes
// to at least that nice value; threads made later inherit it from the thread that makes them.
// Linux keeps a nice value per thread, so one setpriority() call would lower the calling thread
// alone. Returns what the join line says of it; a thread that cannot be lowered is named there.
std::string lower_priority(int nice) {
  if (nice <= 0) return "";
  namespace fs = std::filesystem;
  int lowered = 0, kept = 0;
  std::string failed;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator("/proc/self/task", ec)) {
    const id_t tid = id_t(std::strtoul(e.path().filename().c_str(), nullptr, 10));
    errno = 0;
    const int now = getpriority(PRIO_PROCESS, tid);
    if (errno != 0) continue;  // the thread ended meanwhile
    if (now >= nice) {
      ++kept;
      continue;
    }
    if (setpriority(PRIO_PROCESS, tid, nice) == 0)
      ++lowered;
    else if (errno != ESRCH && failed.empty())
      failed = "thread " + std::to_string(tid) + ": " + std::strerror(errno);
  }
  if (ec) return ", nice not set (/proc/self/task: " + ec.message() + ")";
  std::string note =
      ", nice " + std::to_string(nice) + " (worker.nice) on " + std::to_string(lowered + kept) + " threads";
  if (kept > 0) note += ", " + std::to_string(kept) + " of them already at it or above";
  if (!failed.empty()) note += "; not lowered: " + failed;
  return note;
}

}  // namespace

void WorkerApp::join(const SpecIn& in) {
  const farm::msg::ExperimentSpec& s = in.spec;
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
    if (s.max_batches_per_version() < 1)
      throw std::runtime_error("spec's max_batches_per_version 0: no batch could be sent");
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
    learner_writer_ = in.writer;
    pending_spec_.reset();
    joined_task_ = cfg.task().SerializeAsString();
    envs_ = envs;
    sequence_ = 0;
    have_policy_ = false;
    batches_on_version_ = 0;
    batch_quota_ = 0;
    last_error_.clear();
    const std::string nice_note = lower_priority(cfg.worker().nice());
    log("joined experiment '" + s.experiment_id() + "': task " + cfg.task().name() + ", " + std::to_string(envs) +
        " envs on " + std::to_string(opt_.threads) + " threads, " + std::to_string(s.steps_per_batch()) +
        " steps per batch" + nice_note);
    // Said now, not after the first collect: the beat thread re-sends the last status the loop
    // built, which was the one of a worker waiting for a spec, so a long first collect (mCLARI's:
    // 6-8 s) kept the learner from counting this worker until it ended.
    heartbeat(true);
  } catch (const std::exception& e) {
    // Named for the experiment: the learner reports it (WorkerRoster), this worker having joined none.
    last_error_ = "cannot run experiment '" + s.experiment_id() + "': " + e.what();
    state_ = "error";
    log(last_error_);
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

void WorkerApp::finish() {
  finishing_ = true;
  stop_eval_thread();  // both may take seconds (an evaluation step, the last batches): still beating
  end_stream();
  stop_beat_thread();  // no status of the loop's sent after the last one
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
  {
    // Under the lock with the write: the beat thread's copy of an older status never lands after it.
    std::lock_guard<std::mutex> lk(beat_mu_);
    beat_ = s;
    beat_built_ = beat_sent_ = t;
    status_out_.write(s);
  }
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

void WorkerApp::beat_main() {
  std::unique_lock<std::mutex> lk(beat_mu_);
  while (!beat_stop_) {
    beat_cv_.wait_for(lk, std::chrono::milliseconds(250), [this] { return beat_stop_; });
    const double t = now_seconds();
    // Only when the loop is late (its own beat is due each second), so the two do not both send.
    if (beat_stop_ || beat_built_ < 0 || t - beat_sent_ < 1.5 || t - beat_built_ > kMaxLoopSilenceS) continue;
    beat_sent_ = t;
    status_out_.write(beat_);
  }
}

void WorkerApp::stop_beat_thread() {
  {
    std::lock_guard<std::mutex> lk(beat_mu_);
    beat_stop_ = true;
  }
  beat_cv_.notify_all();
  if (beat_thread_.joinable()) beat_thread_.join();
}

WorkerApp::~WorkerApp() {
  stop_beat_thread();
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

}  // namespace farm
