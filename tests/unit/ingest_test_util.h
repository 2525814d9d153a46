// What the Ingest unit tests share (test_ingest.cpp, test_ingest_streams.cpp): a valid batch of
// T=3 steps x N=2 envs and a fixture that hands batches to one Ingest.
#pragma once

#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "ingest.h"

namespace ingest_test {

using farm::FinishedEpisode;
using farm::Ingest;
using farm::Transitions;

constexpr int kObs = 2, kAct = 1;

// T=3 steps x N=2 envs; env 1 ends an episode at t=1 (truncated).
inline farm::msg::TransitionBatch make_batch(uint64_t seq, const std::string& exp = "exp") {
  farm::msg::TransitionBatch b;
  b.experiment_id(exp);
  b.worker_id("w1");
  b.worker_session(7);
  b.sequence_number(seq);
  b.policy_version(3);
  const int T = 3, N = 2;
  b.num_steps(T);
  b.num_envs(N);
  b.obs_dim(kObs);
  b.act_dim(kAct);
  std::vector<float> obs;
  for (int t = 0; t < T; ++t)
    for (int n = 0; n < N; ++n) {
      obs.push_back(10.f * t + n);
      obs.push_back(-(10.f * t + n));
    }
  b.observations(obs);
  b.actions({0.1f, -0.2f, 0.3f, -0.4f, 0.5f, -0.6f});
  b.rewards({1, 2, 3, 4, 5, 6});
  b.terminated({0, 0, 0, 0, 0, 0});
  b.truncated({0, 0, 0, 1, 0, 0});
  b.log_probs({0, 0, 0, 0, 0, 0});
  b.next_observations({30.f, -30.f, 31.f, -31.f});
  b.final_index({3});  // t=1, n=1
  b.final_observations({99.f, -99.f});
  farm::msg::EpisodeSummary e;
  e.env(1);
  e.episode_return(-123.f);
  e.length(200);
  b.episodes({e});
  return b;
}

struct Fixture : ::testing::Test {
  Ingest ingest{"exp", kObs, kAct, 0};
  Transitions out;
  std::vector<FinishedEpisode> eps;
  std::string take(const farm::msg::TransitionBatch& b) { return ingest.accept(b, 5, 0.0, out, eps); }
  // The batch of sequence number seq of session `session`, one second after the one before.
  double now = 0;
  std::string at(uint64_t session, uint64_t seq) {
    auto b = make_batch(seq);
    b.worker_session(session);
    return ingest.accept(b, 5, now += 1, out, eps);
  }
};

}  // namespace ingest_test
