#include "batch_sender.h"

#include <chrono>
#include <cmath>
#include <string>
#include <thread>

#include "meter.h"

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

// At shutdown (stopped, or the experiment over), a batch whose write has been refused this long by a
// full history, or that has no learner to go to, is given up: nobody acknowledges it.
constexpr double kShutdownSendGiveUpS = 30.0;

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

BatchSender::BatchSender(farm::dds::Bus& bus, const std::string& worker_id, Faults faults,
                         const std::atomic<bool>& stop, Log log)
    : worker_id_(worker_id),
      faults_(faults),
      stop_(stop),
      log_(std::move(log)),
      out_(bus, farm::dds::kBatchTopic, "batch_writer") {}

BatchSender::~BatchSender() {
  if (!thread_.joinable()) return;
  give_up_ = true;
  {
    std::lock_guard<std::mutex> lk(mu_);
    stop_thread_ = true;
  }
  work_cv_.notify_all();
  thread_.join();
}

void BatchSender::start() {
  thread_ = std::thread([this] { main(); });
}

RolloutBatch* BatchSender::free_buffer(double wait) {
  const int b = next_;
  std::unique_lock<std::mutex> lk(mu_);
  if (!with_sender_[b]) return &buffers_[b];
  const double t0 = now_seconds();
  const bool free = free_cv_.wait_for(lk, std::chrono::duration<double>(wait), [&] { return !with_sender_[b]; });
  backpressure_s_ += now_seconds() - t0;
  return free ? &buffers_[b] : nullptr;
}

void BatchSender::hand_over(const Stream& stream) {
  Outgoing o;
  o.buffer = next_;
  o.stream = stream;
  {
    std::lock_guard<std::mutex> lk(mu_);
    with_sender_[next_] = true;
    queue_.push_back(std::move(o));
  }
  work_cv_.notify_one();
  next_ = (next_ + 1) % kBuffers;
}

void BatchSender::drain(bool stop, const std::function<void()>& meanwhile) {
  if (!thread_.joinable()) return;
  std::unique_lock<std::mutex> lk(mu_);
  if (stop) stop_thread_ = true;
  work_cv_.notify_one();
  while (!queue_.empty()) {
    free_cv_.wait_for(lk, std::chrono::milliseconds(100));
    lk.unlock();
    meanwhile();
    lk.lock();
  }
  lk.unlock();
  if (stop) thread_.join();
}

double BatchSender::publish_seconds(double now) {
  std::lock_guard<std::mutex> lk(mu_);
  return publish_s_ + (publishing_since_ > 0 ? now - publishing_since_ : 0.0);
}

// The thread: writes the batches handed over, in order, each under the next sequence number, and
// frees its buffer once written. It ends when told to and nothing is left.
void BatchSender::main() {
  for (;;) {
    Outgoing o;
    {
      std::unique_lock<std::mutex> lk(mu_);
      work_cv_.wait(lk, [this] { return stop_thread_ || !queue_.empty(); });
      if (queue_.empty()) return;
      o = queue_.front();
      publishing_since_ = now_seconds();
    }
    publish(o);
    {
      std::lock_guard<std::mutex> lk(mu_);
      publish_s_ += now_seconds() - publishing_since_;
      publishing_since_ = 0;
      queue_.pop_front();
      if (o.buffer >= 0) with_sender_[o.buffer] = false;
    }
    free_cv_.notify_all();
  }
}

bool BatchSender::publish(const Outgoing& o) {
  const uint64_t seq = sequence_;
  const bool end_of_stream = o.buffer < 0;
  const std::string what = end_of_stream ? "the end of stream" : "batch " + std::to_string(seq);
  auto give_up = [&](const std::string& why) {
    give_up_ = true;  // and every batch after it: the stream ends here
    blocked_ = false;
    log_("gave up sending " + what + " at shutdown (" + why + ")");
    return false;
  };
  if (give_up_) return give_up("sending has stopped");
  // Nobody would receive the batch: hold on rather than lose it (at shutdown there is nobody to wait for).
  while (out_.matched() == 0) {
    if (stop_ || finishing_ || give_up_) return give_up("no learner matched");
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  farm::msg::TransitionBatch eos;
  farm::msg::TransitionBatch& b = end_of_stream ? eos : wire_;
  b.experiment_id(o.stream.experiment_id);
  b.worker_id(worker_id_);
  b.worker_session(o.stream.session);
  b.sequence_number(seq);
  b.end_of_stream(end_of_stream);
  if (!end_of_stream) {
    to_wire(buffers_[o.buffer], b);
    if (int64_t(seq) == faults_.nan_batch && !b.observations().empty()) {
      b.observations()[0] = std::nanf("");
      log_("fault injection: batch " + std::to_string(seq) + " carries a NaN");
    }
  } else {
    b.obs_dim(uint32_t(o.obs_dim));
    b.act_dim(uint32_t(o.act_dim));
    b.policy_version(o.policy_version);
  }
  if (faults_.publish_delay_ms > 0) {  // fault injection: a slow write (the batch waits, nothing else)
    const double until = now_seconds() + 1e-3 * faults_.publish_delay_ms;
    while (now_seconds() < until && !give_up_) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  // A full reliable history makes write() time out: retry, never drop.
  const double first_try = now_seconds();
  while (!out_.write(b)) {
    if (give_up_ || (now_seconds() - first_try > kShutdownSendGiveUpS && (stop_ || finishing_)))
      return give_up("no learner acknowledges");
    blocked_ = true;
  }
  blocked_ = false;
  ++sequence_;
  return true;
}

void BatchSender::end_stream(const Stream& stream, uint64_t obs_dim, uint64_t act_dim, uint64_t policy_version,
                             const std::function<void()>& meanwhile) {
  if (out_.matched() == 0) {
    drain(true, meanwhile);
    return;
  }
  Outgoing eos;
  eos.stream = stream;
  eos.obs_dim = obs_dim;
  eos.act_dim = act_dim;
  eos.policy_version = policy_version;
  {
    std::lock_guard<std::mutex> lk(mu_);
    queue_.push_back(std::move(eos));
  }
  drain(true, meanwhile);
  if (!out_.wait_for_acks(10.0)) log_("learner did not acknowledge every batch within 10 s");
}

}  // namespace farm
