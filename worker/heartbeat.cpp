#include "heartbeat.h"

#include <chrono>

#include "meter.h"

namespace farm {

Heartbeat::Heartbeat(farm::dds::Bus& bus) : out_(bus, farm::dds::kWorkerStatusTopic, "status_writer") {}

void Heartbeat::start() {
  thread_ = std::thread([this] { main(); });
}

void Heartbeat::send(const farm::msg::WorkerStatus& s) {
  // Under the lock with the write: the thread's copy of an older status never lands after it.
  std::lock_guard<std::mutex> lk(mu_);
  last_ = s;
  built_ = sent_ = now_seconds();
  out_.write(last_);
}

void Heartbeat::main() {
  std::unique_lock<std::mutex> lk(mu_);
  while (!stop_) {
    cv_.wait_for(lk, std::chrono::milliseconds(250), [this] { return stop_; });
    const double t = now_seconds();
    // Only when the loop is late (its own beat is due each second), so the two do not both send.
    if (stop_ || built_ < 0 || t - sent_ < 1.5 || t - built_ > kMaxLoopSilenceS) continue;
    sent_ = t;
    out_.write(last_);
  }
}

void Heartbeat::stop() {
  {
    std::lock_guard<std::mutex> lk(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

}  // namespace farm
