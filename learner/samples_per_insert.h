// The replay pacing's rate limiter, after Reverb's SampleToInsertRatio: updates may run once
// `min_rows` rows are held, while the updates made stay within `per_step` times the env steps
// received (plus one, so that the first update needs no more than min_rows), and never past
// `max_updates` (0: no limit). It reads counts only; what it holds back waits for the next pass.
#pragma once

#include <cstdint>

namespace farm {

class SamplesPerInsert {
 public:
  SamplesPerInsert(int64_t min_rows, double per_step, int64_t max_updates)
      : min_rows_(min_rows), per_step_(per_step), max_updates_(max_updates) {}

  // How many of `most` more updates may run now, after `done` updates, with `rows` rows held and
  // `env_steps` env steps received.
  int allowed(int64_t done, int64_t rows, uint64_t env_steps, int most) const {
    if (rows < min_rows_) return 0;
    int n = 0;
    while (n < most && may_run(done + n, env_steps)) ++n;
    return n;
  }

 private:
  bool may_run(int64_t done, uint64_t env_steps) const {
    if (max_updates_ > 0 && done >= max_updates_) return false;
    return double(done) < per_step_ * double(env_steps) + 1;
  }

  int64_t min_rows_;
  double per_step_;
  int64_t max_updates_;
};

}  // namespace farm
