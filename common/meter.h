// Throughput over a sliding window: rate() is events/s since the previous call.
#pragma once

#include <chrono>
#include <cstdint>

namespace farm {

inline double now_seconds() {
  using namespace std::chrono;
  return duration<double>(steady_clock::now().time_since_epoch()).count();
}

class Meter {
 public:
  Meter() : t0_(now_seconds()), last_t_(t0_) {}
  void add(uint64_t n) { total_ += n; }
  uint64_t total() const { return total_; }
  // Rate since the previous call to rate() (or construction).
  double rate() {
    double t = now_seconds();
    double dt = t - last_t_;
    double r = dt > 0 ? double(total_ - last_total_) / dt : 0.0;
    last_t_ = t;
    last_total_ = total_;
    return r;
  }
  double mean_rate() const {
    double dt = now_seconds() - t0_;
    return dt > 0 ? double(total_) / dt : 0.0;
  }

 private:
  double t0_, last_t_;
  uint64_t total_ = 0, last_total_ = 0;
};

}  // namespace farm
