// Waiting in tests for something another thread or process does.
#pragma once

#include <chrono>
#include <thread>

namespace farm::testing {

// Polls done() every poll_ms until it holds; false after timeout_s. done() is not called again once
// it held (it may take what it found).
template <class Done>
inline bool wait_until(Done done, double timeout_s, int poll_ms = 200) {
  const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (std::chrono::steady_clock::now() < until) {
    if (done()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(poll_ms));
  }
  return done();
}

}  // namespace farm::testing
