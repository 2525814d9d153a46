// Lines about what other participants send, said at most once per period, so that a participant
// cannot fill the worker's log with them.
#pragma once

#include <chrono>

namespace farm {

class OncePer {
 public:
  explicit OncePer(std::chrono::seconds period) : period_(period) {}
  // True at most once per period: the caller says its line then.
  bool due() {
    const auto now = std::chrono::steady_clock::now();
    if (said_ && now - last_ < period_) return false;
    said_ = true;
    last_ = now;
    return true;
  }

 private:
  std::chrono::seconds period_;
  std::chrono::steady_clock::time_point last_{};
  bool said_ = false;
};

}  // namespace farm
