// How long the ingest waits for the heartbeat that announces a worker session before it decides who
// may open that session's stream (Ingest::set_announcer). A worker's heartbeat reaches the learner
// at about the moment it reaches a participant that copies the session off it and writes a batch
// under it at once (a stream thief); on a loaded host the copy's batch can be taken a few
// milliseconds before the heartbeat it copied, and a stream whose announcement is not heard yet
// opens from its first writer. Waiting up to `most` seconds for the announcement closes that race;
// it is asked only for a participant that has opened no stream yet (Ingest::Announcer). Time spent
// waiting is a budget earned at `share` seconds a second (at most `saved` seconds kept), so first
// batches under invented sessions from ever new participants cost the ingest at most that share of
// its time; once the budget is spent a first batch is decided at once, as without the wait.
#pragma once

#include <algorithm>
#include <string>

namespace farm {

class AnnounceWait {
 public:
  explicit AnnounceWait(double most = 0.1, double share = 0.02, double saved = 0.2, double step = 0.002)
      : most_(most), share_(share), saved_(saved), step_(step), budget_(saved) {}

  // Asks announced() (the announcing participant, "" while none is known) until it names one or
  // the wait's time is spent; returns its last answer. now() gives seconds, sleep(s) waits s seconds.
  template <class Announced, class Now, class Sleep>
  std::string await(Announced announced, Now now, Sleep sleep) {
    std::string who = announced();
    const double t0 = now();
    if (last_ >= 0) budget_ = std::min(saved_, budget_ + share_ * std::max(0.0, t0 - last_));
    last_ = t0;
    const double limit = std::min(most_, budget_);
    double t = t0;
    while (who.empty() && t - t0 < limit) {
      sleep(step_);
      who = announced();
      t = now();
    }
    budget_ = std::max(0.0, budget_ - (t - t0));
    last_ = t;
    return who;
  }

  // Seconds of waiting the budget holds now (as of the last wait).
  double budget() const { return budget_; }

 private:
  double most_, share_, saved_, step_;
  double budget_;
  double last_ = -1;
};

}  // namespace farm
