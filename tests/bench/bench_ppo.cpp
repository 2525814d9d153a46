// PPO fit time at the MushroomRL paper's sizes: 98,304 steps per fit, 5 epochs, mini-batches of 6,144 (A1
// column) and 3,072 (Honey / Silver Badger column), for an A1-sized problem (48 observations,
// 12 actions, as in the MushroomRL paper §3.3) and networks of 512-256-128 (Rudin et al.'s, which the MushroomRL
// paper's A1 setup follows). The fit goes through the learner's own path: the steps sit in the rollout storage as
// 16-step batches, GAE runs with the critic's values, then Ppo::fit.
//   bench_ppo [--device cpu|cuda[:N]] [--threads N] [--fits K] [--steps S] [--hidden 512,256,128]
// "Preparing" is the share of a fit's time spent before the gradient steps (the critic's values
// for GAE, the returns and advantages, the copy to the device): the learner's own overhead per fit.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "bench_options.h"
#include "compute.h"
#include "ppo.h"
#include "rollout_storage.h"

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

}  // namespace

int main(int argc, char** argv) {
  std::string device = "cpu";
  int threads = 1, fits = 2;
  int64_t steps = 98304;  // MushroomRL paper appendix: steps per fit
  std::vector<int> hidden{512, 256, 128};
  farm::cli::App app("bench_ppo");
  app.description("PPO fit time on random A1-sized data (MushroomRL paper appendix).");
  bench::add_device(app, device);
  bench::add_threads(app, threads);
  app.add_option("--fits", fits, "Fits measured after one warm-up fit")
      ->check(CLI::Range(1, 1 << 20))
      ->capture_default_str();
  app.add_option("--steps", steps, "Steps per fit")->capture_default_str();
  bench::add_hidden(app, hidden);
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  if (fits < 1 || steps < 16 || threads < 1) {
    std::fprintf(stderr, "bench_ppo: --fits >= 1, --steps >= 16 and --threads >= 1 expected\n");
    return 2;
  }
  farm::configure_compute(threads);
  constexpr int kObs = 48, kAct = 12, kT = 16;  // A1: observation and action sizes (MushroomRL paper §3.3)
  const int64_t envs = steps / kT;
  std::mt19937_64 rng(1);
  std::normal_distribution<float> g;
  std::vector<float> obs(kT * envs * kObs), act(kT * envs * kAct), rew(kT * envs), lp(kT * envs),
      next(kT * envs * kObs);
  for (auto* v : {&obs, &rew, &lp, &next})
    for (float& x : *v) x = g(rng);
  for (float& x : act) x = std::tanh(g(rng));
  std::vector<uint8_t> term(kT * envs, 0), trunc(kT * envs, 0);
  for (size_t i = 0; i < term.size(); i += 97) term[i] = 1;

  for (int mb : {6144, 3072}) {  // MushroomRL paper appendix: mini-batch size, A1 and Badger columns
    farm::config::PpoConfig c;
    c.set_mini_batch_size(mb);
    c.set_steps_per_fit(steps);
    c.set_device(device);
    for (int h : hidden) c.add_hidden(h);
    farm::Ppo ppo(c, kObs, kAct, 1);
    farm::RolloutStorage storage(kObs, kAct);
    double prep_total = 0, fit_total = 0;
    for (int f = 0; f <= fits; ++f) {  // fit 0 warms up (allocations, Adam state, CUDA context)
      storage.add(kT, int(envs), obs.data(), act.data(), rew.data(), term.data(), trunc.data(), lp.data(), next.data(),
                  f);
      const auto t0 = Clock::now();
      farm::PpoSamples s;
      storage.take(
          steps, [&](const float* o, int64_t n) { return ppo.values(o, n); }, c.gamma(), c.gae_lambda(), f, s);
      const double prep = seconds_since(t0);
      const auto t1 = Clock::now();
      const farm::PpoStats st = ppo.fit(s);
      const double fit = seconds_since(t1);
      if (f == 0) continue;
      prep_total += prep;
      fit_total += fit;
      if (f == fits)
        std::printf(
            "ppo fit (%d-[%s]-%d, %lld steps, mini-batch %d, %d epochs, %lld grad steps, %s, %d thread%s): "
            "%.2f s per fit (preparing %.2f s = %.1f%%, gradient steps %.2f s), %.0f samples/s, kl %.4f\n",
            kObs,
            [&] {
              std::string h;
              for (size_t i = 0; i < hidden.size(); ++i) h += (i ? "," : "") + std::to_string(hidden[i]);
              return h;
            }()
                .c_str(),
            kAct, (long long)steps, mb, c.epochs(), (long long)st.minibatches, device.c_str(), threads,
            threads == 1 ? "" : "s", (prep_total + fit_total) / fits, prep_total / fits,
            100.0 * prep_total / (prep_total + fit_total), fit_total / fits,
            double(steps) * c.epochs() * fits / fit_total, st.kl);
    }
    std::fflush(stdout);
  }
  return 0;
}
