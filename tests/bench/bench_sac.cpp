// SAC learner throughput on the pendulum shapes (obs 3, act 1). The learner's update rate bounds
// the whole farm, so this is the number to watch when touching sac.cpp or the replay buffer.
//   bench_sac [--seconds S] [--threads N[,N...]] [--batch B] [--device cpu|cuda[:N]]
// The share of time the update loop waits for data is the replay sampling (and, on a GPU, the
// host-to-device copy inside the update is counted as update time).
// Run with OMP_WAIT_POLICY=PASSIVE when measuring more than one thread on a shared machine (see
// configure_compute in compute.h).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "replay_buffer.h"
#include "compute.h"
#include "sac.h"

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

void fill(farm::ReplayBuffer& buf, int64_t n, std::mt19937_64& rng) {
  std::normal_distribution<float> g;
  const int o = buf.obs_dim(), a = buf.act_dim();
  std::vector<float> obs(n * o), act(n * a), rew(n), next(n * o);
  std::vector<uint8_t> term(n, 0);
  for (auto* v : {&obs, &act, &rew, &next})
    for (float& x : *v) x = g(rng);
  buf.add_n(n, obs.data(), act.data(), rew.data(), term.data(), next.data());
}

std::string describe(int obs, const std::vector<int>& hidden, int act) {
  std::ostringstream s;
  s << obs << "-[";
  for (size_t i = 0; i < hidden.size(); ++i) s << (i ? "," : "") << hidden[i];
  s << "]-" << act;
  return s.str();
}

}  // namespace

int main(int argc, char** argv) {
  double seconds = 3.0;
  int batch = 256;
  std::vector<int> threads{1, 2};
  std::string device = "cpu";
  for (int i = 1; i < argc; ++i) {
    const bool has_value = i + 1 < argc;
    if (!std::strcmp(argv[i], "--seconds") && has_value) {
      seconds = std::atof(argv[++i]);
    } else if (!std::strcmp(argv[i], "--device") && has_value) {
      device = argv[++i];
    } else if (!std::strcmp(argv[i], "--batch") && has_value) {
      batch = std::atoi(argv[++i]);
    } else if (!std::strcmp(argv[i], "--threads") && has_value) {
      threads.clear();
      std::stringstream list(argv[++i]);
      for (std::string t; std::getline(list, t, ',');) threads.push_back(std::atoi(t.c_str()));
    } else {
      std::fprintf(stderr,
                   "usage: %s [--seconds S] [--threads N[,N...]] [--batch B] "
                   "[--device cpu|cuda[:N]]\n",
                   argv[0]);
      return 2;
    }
  }

  constexpr int kObs = 3, kAct = 1;
  farm::ReplayBuffer buf(100000, kObs, kAct);
  std::mt19937_64 rng(1);
  fill(buf, buf.capacity(), rng);

  for (const std::vector<int>& hidden : {std::vector<int>{64, 64}, std::vector<int>{256, 256}}) {
    for (int n_threads : threads) {
      farm::configure_compute(n_threads);
      farm::config::SacConfig cfg;
      for (int h : hidden) cfg.add_hidden(h);
      cfg.set_device(device);
      farm::Sac sac(cfg, kObs, kAct, 1);
      // Warm-up: first-touch allocations and Adam's state creation are not the steady state.
      const auto warm = Clock::now();
      while (seconds_since(warm) < std::min(0.5, seconds / 4)) sac.update(buf.sample(batch, rng));

      int64_t n = 0;
      double sample_s = 0;
      const auto t0 = Clock::now();
      double elapsed = 0;
      while (elapsed < seconds) {
        const auto ts = Clock::now();
        const auto b = buf.sample(batch, rng);
        sample_s += seconds_since(ts);
        sac.update(b);
        ++n;
        elapsed = seconds_since(t0);
      }
      std::printf("sac update (%s, batch %d, %s, %d thread%s): %.0f updates/s "
                  "(%.1f us/update, of which sampling %.1f us = %.1f%% waiting for data)\n",
                  describe(kObs, hidden, kAct).c_str(), batch, device.c_str(), n_threads,
                  n_threads == 1 ? "" : "s", n / elapsed, 1e6 * elapsed / n, 1e6 * sample_s / n,
                  100.0 * sample_s / elapsed);
      std::fflush(stdout);
    }
  }
  return 0;
}
