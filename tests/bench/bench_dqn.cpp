// DQN learner throughput, by default on Jetbot's shapes (20 observations, 7 discrete actions,
// 128-128 Q network, batch 256, 3-step horizons): updates/s on the CPU and, with --device cuda,
// eagerly on the GPU and as CUDA graph replays (dqn.cuda_graph), in the same run.
//   bench_dqn [--seconds S] [--threads N] [--batch B] [--device cpu|cuda[:N]] [--obs N --actions N --hidden H[,H...]]
// The share of time spent sampling the replay buffer is printed as "waiting for data" (on a GPU
// the host-to-device copy counts as update time).
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "bench_options.h"
#include "compute.h"
#include "dqn.h"
#include "replay_buffer.h"

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

struct Rate {
  int64_t n = 0;
  double elapsed = 0, sample_s = 0;
  double per_second() const { return n / elapsed; }
};

Rate measure(farm::Dqn& dqn, farm::ReplayBuffer& buf, int batch, double seconds, std::mt19937_64& rng) {
  Rate r;
  auto one = [&] {
    const auto ts = Clock::now();
    const auto b = buf.sample(batch, rng);
    r.sample_s += seconds_since(ts);
    dqn.update(b);
  };
  const auto warm = Clock::now();
  while (seconds_since(warm) < std::min(0.5, seconds / 4)) one();  // first allocations, the capture
  r = Rate{};
  const auto t0 = Clock::now();
  while (r.elapsed < seconds) {
    one();
    ++r.n;
    r.elapsed = seconds_since(t0);
  }
  return r;
}

void print_rate(const char* what, const std::string& net, int batch, const Rate& r) {
  std::printf(
      "dqn update (%s, batch %d, %s): %.0f updates/s (%.1f us/update, of which sampling %.1f us = %.1f%% "
      "waiting for data)\n",
      net.c_str(), batch, what, r.per_second(), 1e6 * r.elapsed / r.n, 1e6 * r.sample_s / r.n,
      100.0 * r.sample_s / r.elapsed);
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  double seconds = 3.0;
  int batch = 256, threads = 1, obs = 20, actions = 7;
  std::vector<int> hidden{128, 128};
  std::string device = "cpu";
  farm::cli::App app("bench_dqn");
  app.description(
      "DQN learner throughput, by default on Jetbot's shapes: updates/s on the CPU and, with --device "
      "cuda, eagerly on the GPU and as CUDA graph replays.");
  bench::add_seconds(app, seconds);
  bench::add_threads(app, threads);
  bench::add_batch(app, batch);
  bench::add_device(app, device);
  app.add_option("--obs", obs, "Observation size")->check(CLI::Range(1, 1 << 20))->capture_default_str();
  app.add_option("--actions", actions, "Number of discrete actions")
      ->check(CLI::Range(2, 1 << 20))
      ->capture_default_str();
  bench::add_hidden(app, hidden);
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;

  farm::configure_compute(threads);
  farm::ReplayBuffer buf(100000, obs, 1);
  std::mt19937_64 rng(1);
  {
    std::normal_distribution<float> g;
    std::uniform_int_distribution<int> pick(0, actions - 1), steps(1, 3);
    const int64_t n = buf.capacity();
    std::vector<float> o(n * obs), a(n), r(n), next(n * obs), h(n);
    std::vector<uint8_t> term(n, 0);
    for (auto* v : {&o, &r, &next})
      for (float& x : *v) x = g(rng);
    for (float& x : a) x = float(pick(rng));
    for (float& x : h) x = float(steps(rng));
    buf.add_n(n, o.data(), a.data(), r.data(), term.data(), next.data(), h.data());
  }
  std::ostringstream net;
  net << obs << "-[";
  for (size_t i = 0; i < hidden.size(); ++i) net << (i ? "," : "") << hidden[i];
  net << "]-" << actions;

  farm::config::DqnConfig cfg;
  for (int h : hidden) cfg.add_hidden(h);
  cfg.set_batch_size(batch);
  cfg.set_device(device);
  const bool cuda = device.rfind("cuda", 0) == 0;
  cfg.set_cuda_graph(false);
  farm::Dqn eager(cfg, obs, actions, 1);
  const Rate e = measure(eager, buf, batch, seconds, rng);
  print_rate(cuda ? (device + " eager").c_str() : (device + ", " + std::to_string(threads) + " thread(s)").c_str(),
             net.str(), batch, e);
  if (!cuda) return 0;
  cfg.set_cuda_graph(true);
  farm::Dqn graph(cfg, obs, actions, 1);
  if (!graph.uses_cuda_graph()) {
    std::printf("dqn update (%s, %s cuda graph): not in this build (CPU LibTorch)\n", net.str().c_str(),
                device.c_str());
    return 0;
  }
  const Rate g = measure(graph, buf, batch, seconds, rng);
  print_rate((device + " cuda graph").c_str(), net.str(), batch, g);
  std::printf("dqn update (%s, batch %d, %s): cuda graph / eager = %.2fx\n", net.str().c_str(), batch, device.c_str(),
              g.per_second() / e.per_second());
  return 0;
}
