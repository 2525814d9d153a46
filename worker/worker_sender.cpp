// The worker's batch sender (worker_app.h): the collect loop hands finished batches over, the
// sender thread serializes and writes them in order, and the end of the stream follows the last.
#include <chrono>
#include <cmath>
#include <string>
#include <thread>

#include "worker_app.h"

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

}  // namespace farm
