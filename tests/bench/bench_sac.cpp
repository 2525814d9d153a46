// SAC learner throughput, by default on the pendulum shapes (obs 3, act 1; 64-64 and 256-256
// networks). The learner's update rate bounds the whole farm, so this is the number to watch when
// touching sac.cpp or the replay buffer.
//   bench_sac [--seconds S] [--threads N[,N...]] [--batch B] [--device cpu|cuda[:N]] [--check N] [--tf32|--no-tf32]
//             [--actor-on-previous-critic] [--obs N --act N --hidden H[,H...]]
//             [--batches B[,B...] [--hidden-sets "H,H;H,H,H"] [--dtypes float32,bfloat16]]
// --batches measures the learner's path only (CUDA graph, 8 queued replays, batches drawn on the
// GPU; on the CPU one update per sampled batch) at each batch size, for each network of
// --hidden-sets (default: --hidden, else 256-256 and 512-512-512), and prints one table:
// updates/s, samples/s (batch x updates/s) and each row's samples/s over the first batch's, same
// network, same run; with --dtypes each network at each sac.matmul_dtype listed, and the ratio
// is over the best samples/s at the first batch, same network, whatever its dtype.
// --obs/--act/--hidden measure one other shape instead (Kaya: --obs 21 --act 6 --hidden 128,128).
// The share of time the update loop waits for data is the replay sampling (and, on a GPU, the
// host-to-device copy inside the update is counted as update time).
// On CUDA each size is measured four times in the same run: eager (sac.cuda_graph false), as
// CUDA graph replays one update at a time of torch's ops (sac.cuda_fused_kernels false) and with
// the fused kernels (the default), and as the learner runs them: groups of kUpdatesPerGroup queued
// replays (Sac::update_n), each returning without waiting for its last replays. Before that a check runs N updates
// (default 200) of both paths from the same start on the same batches and compares figures and parameters; a mismatch
// beyond float tolerance makes the exit status 1. Run with OMP_WAIT_POLICY=PASSIVE when measuring more than one thread
// on a shared machine (see configure_compute in compute.h).
#include <algorithm>
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
#include "device_replay.h"
#include "pacing.h"  // kUpdatesPerGroup
#include "replay_buffer.h"
#include "sac.h"

namespace {

using Clock = std::chrono::steady_clock;

// sac.cuda_tf32 for every SAC of the run (--tf32 / --no-tf32; default: the config's default).
bool g_tf32 = farm::config::SacConfig().cuda_tf32();
// sac.actor_on_previous_critic for every SAC of the run (--actor-on-previous-critic): on CUDA the
// actor's and the critics' steps as parallel branches of the graph.
bool g_beside = farm::config::SacConfig().actor_on_previous_critic();
// The shapes measured: observation and action sizes, and the hidden layers of each network.
int g_obs = 3, g_act = 1;
std::vector<std::vector<int>> g_hidden{{64, 64}, {256, 256}};

// The SAC config every measurement of the run uses: --tf32, --actor-on-previous-critic, the
// network's hidden layers and the device.
farm::config::SacConfig sac_config(const std::vector<int>& hidden, const std::string& device) {
  farm::config::SacConfig cfg;
  cfg.set_cuda_tf32(g_tf32);
  cfg.set_actor_on_previous_critic(g_beside);
  for (int h : hidden) cfg.add_hidden(h);
  cfg.set_device(device);
  return cfg;
}

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

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

struct Rate {
  int64_t n = 0;
  double elapsed = 0, sample_s = 0;
};

// group 0: one update() per sampled batch. group G > 0: update_n(G, sampler), as the learner's
// replay driver calls it (8 updates per group); on a CUDA graph the G replays are queued and each
// next batch is sampled while the GPU runs the ones before it, so "sampling" is then host time
// that the GPU need not wait for. With `drawn_on` (a DeviceReplay on the GPU) the groups are
// update_n_from's: each replay draws its own batch there, and the host samples nothing.
Rate measure(farm::Sac& sac, farm::ReplayBuffer& buf, int batch, double seconds, std::mt19937_64& rng, int group = 0,
             const farm::DeviceReplay* drawn_on = nullptr) {
  Rate r;
  auto sampler = [&] {
    const auto ts = Clock::now();
    auto b = buf.sample(batch, rng);
    r.sample_s += seconds_since(ts);
    return b;
  };
  auto run = [&] {
    if (group > 0 && drawn_on) {
      sac.update_n_from(group, batch, *drawn_on);
      return int64_t(group);
    }
    if (group > 0) {
      sac.update_n(group, sampler);  // may return while its last replays run: counted when queued
      return int64_t(group);
    }
    sac.update(sampler());
    return int64_t(1);
  };
  // Warm-up: first-touch allocations, Adam's state creation and the graph capture are not the
  // steady state.
  const auto warm = Clock::now();
  while (seconds_since(warm) < std::min(0.5, seconds / 4)) run();
  sac.finish_updates();
  r = Rate{};
  const auto t0 = Clock::now();
  while (r.elapsed < seconds) {
    r.n += run();
    r.elapsed = seconds_since(t0);
  }
  sac.finish_updates();  // the queued ones too have run
  r.elapsed = seconds_since(t0);
  return r;
}

void print_rate(const char* what, const std::string& net, int batch, const std::string& device, int n_threads,
                const Rate& r) {
  std::printf(
      "sac update (%s, batch %d, %s%s, %d thread%s): %.0f updates/s "
      "(%.1f us/update, of which sampling %.1f us = %.1f%% waiting for data)\n",
      net.c_str(), batch, device.c_str(), what, n_threads, n_threads == 1 ? "" : "s", r.n / r.elapsed,
      1e6 * r.elapsed / r.n, 1e6 * r.sample_s / r.n, 100.0 * r.sample_s / r.elapsed);
  std::fflush(stdout);
}

double rel_diff(const std::vector<torch::Tensor>& a, const std::vector<torch::Tensor>& b) {
  double num = 0, den = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    num += (a[i] - b[i]).to(torch::kDouble).square().sum().item<double>();
    den += b[i].to(torch::kDouble).square().sum().item<double>();
  }
  return std::sqrt(num / std::max(den, 1e-30));
}

double figure_diff(const farm::SacStats& g, const farm::SacStats& e, const char** which) {
  const std::pair<const char*, std::pair<double, double>> figs[] = {{"critic_loss", {g.critic_loss, e.critic_loss}},
                                                                    {"actor_loss", {g.actor_loss, e.actor_loss}},
                                                                    {"alpha_loss", {g.alpha_loss, e.alpha_loss}},
                                                                    {"alpha", {g.alpha, e.alpha}},
                                                                    {"entropy", {g.entropy, e.entropy}},
                                                                    {"q_mean", {g.q_mean, e.q_mean}}};
  double worst = 0;
  for (const auto& [name, v] : figs) {
    const double d = std::abs(v.first - v.second) / std::max(1.0, std::abs(v.second));
    if (!(d <= worst)) {  // NaN counts as worst
      worst = std::isnan(d) ? INFINITY : d;
      *which = name;
    }
  }
  return worst;
}

// Graph against eager: `updates` updates from one seed on the same batches, the policy's noise
// from the same CUDA generator state. They differ by float rounding only (the temperature as a
// float tensor, the fused Adam kernel), which compounds over updates: the figures of the first 10
// updates (3 warm-ups, the capture, 6 replays) must agree within 1e-4 (|graph - eager| /
// max(1, |eager|)), and those of all updates within 1e-2; the parameters' drift is printed.
bool check_graph(const std::vector<int>& hidden, int batch, const std::string& device, int updates,
                 farm::ReplayBuffer& buf, std::mt19937_64& rng) {
  const int kObs = g_obs, kAct = g_act;
  std::vector<farm::SampledBatch> batches;
  for (int i = 0; i < updates; ++i) batches.push_back(buf.sample(batch, rng));
  farm::config::SacConfig cfg = sac_config(hidden, device);
  cfg.set_cuda_graph(false);
  std::vector<farm::SacStats> eager_stats;
  farm::Sac eager(cfg, kObs, kAct, 7);  // constructing seeds the CPU and CUDA generators
  for (const auto& b : batches) eager_stats.push_back(eager.update(b));
  cfg.set_cuda_graph(true);
  farm::Sac graph(cfg, kObs, kAct, 7);
  if (!graph.uses_cuda_graph()) {
    std::printf("graph vs eager check: this build has no CUDA graph path (CPU LibTorch)\n");
    return true;
  }
  constexpr int kEarly = 10;
  double early = 0, drift = 0;
  int drift_at = 0;
  const char *early_name = "", *drift_name = "";
  for (int i = 0; i < updates; ++i) {
    const char* name = "";
    const double d = figure_diff(graph.update(batches[i]), eager_stats[i], &name);
    if (i < kEarly && !(d <= early)) {
      early = std::isnan(d) ? INFINITY : d;
      early_name = name;
    }
    if (!(d <= drift)) {
      drift = std::isnan(d) ? INFINITY : d;
      drift_at = i + 1;
      drift_name = name;
    }
  }
  const double actor = rel_diff(graph.actor_parameters(), eager.actor_parameters());
  const double critic = rel_diff(graph.critic_parameters(), eager.critic_parameters());
  const bool ok = early <= 1e-4 && drift <= 1e-2 && updates >= kEarly;
  std::printf(
      "graph vs eager check (%s, batch %d, %s, one seed, same batches): figures of updates 1-%d differ "
      "by at most %.1e (%s); over %d updates by %.1e (%s, update %d); parameters after them by %.1e "
      "actor, %.1e critics (relative norm): %s\n",
      describe(kObs, hidden, kAct).c_str(), batch, device.c_str(), kEarly, early, early_name, updates, drift,
      drift_name, drift_at, actor, critic, ok ? "PASS" : "FAIL");
  std::fflush(stdout);
  return ok;
}

// The large-batch series: the learner's own path at each batch size, one table per run.
void series(const std::vector<std::vector<int>>& nets, const std::vector<int>& batches,
            const std::vector<std::string>& dtypes, const std::string& device, double seconds, farm::ReplayBuffer& buf,
            std::mt19937_64& rng) {
  const bool cuda = device.rfind("cuda", 0) == 0;
  struct Row {
    std::string net, dtype;
    int batch;
    double updates, samples, ratio;
  };
  std::vector<Row> rows;
  for (const auto& hidden : nets) {
    const std::string net = describe(g_obs, hidden, g_act);
    const size_t first_row = rows.size();
    double first = 0;  // the best samples/s at the first batch, this network
    for (const std::string& dtype : dtypes)
      for (int batch : batches) {
        farm::config::SacConfig cfg = sac_config(hidden, device);
        cfg.set_matmul_dtype(dtype);
        farm::Sac sac(cfg, g_obs, g_act, 1);
        Rate r;
        if (cuda && sac.uses_cuda_graph()) {
          farm::DeviceReplay on_gpu(buf.capacity(), g_obs, g_act, sac.device(), cfg.gamma());
          on_gpu.load_from(buf);
          r = measure(sac, buf, batch, seconds, rng, farm::kUpdatesPerGroup, &on_gpu);
        } else {
          r = measure(sac, buf, batch, seconds, rng);
        }
        const double ups = r.n / r.elapsed, sps = ups * batch;
        if (batch == batches.front()) first = std::max(first, sps);
        rows.push_back({net, dtype, batch, ups, sps, 0});
        print_rate((std::string(cuda ? " learner's path, " : " ") + dtype).c_str(), net, batch, device, 1, r);
      }
    for (size_t i = first_row; i < rows.size(); ++i) rows[i].ratio = rows[i].samples / first;
  }
  std::printf("\n%-22s %-9s %8s %12s %14s %s\n", "network", "matmuls", "batch", "updates/s", "samples/s",
              "samples/s over the best at the first batch, same network");
  for (const Row& r : rows)
    std::printf("%-22s %-9s %8d %12.0f %14.0f %.1fx\n", r.net.c_str(), r.dtype.c_str(), r.batch, r.updates, r.samples,
                r.ratio);
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  double seconds = 3.0;
  int batch = 256;
  std::vector<int> threads{1, 2};
  std::string device = "cpu";
  int check_updates = 200;
  std::vector<int> hidden;   // --hidden: one network size instead of the two of g_hidden
  std::vector<int> batches;  // --batches: the large-batch series instead
  std::string hidden_sets;
  std::vector<std::string> dtypes{"float32"};
  farm::cli::App app("bench_sac");
  app.description(
      "SAC learner throughput, by default on the pendulum shapes (obs 3, act 1; 64-64 and 256-256 "
      "networks); --obs/--act/--hidden measure one other shape instead.");
  bench::add_seconds(app, seconds);
  bench::add_list(app, "--threads", threads, "Torch thread counts to measure")->check(CLI::Range(1, 4096));
  bench::add_batch(app, batch);
  bench::add_device(app, device);
  app.add_option("--check", check_updates, "On CUDA: updates of the graph checked against eager ones (0: none)")
      ->capture_default_str();
  // sac.cuda_tf32 for every SAC of the run, eager and graph alike (default: the config's).
  app.add_flag("--tf32,!--no-tf32", g_tf32, "Matrix products in TF32 on CUDA (default: the config's sac.cuda_tf32)");
  app.add_flag("--actor-on-previous-critic", g_beside,
               "The actor's step beside the critics' (against them before their step)");
  app.add_option("--obs", g_obs, "Observation size")->check(CLI::Range(1, 1 << 20))->capture_default_str();
  app.add_option("--act", g_act, "Action size")->check(CLI::Range(1, 1 << 20))->capture_default_str();
  bench::add_hidden(app, hidden)->description("Hidden layer sizes, comma-separated (default: 64,64 and 256,256)");
  bench::add_list(app, "--batches", batches, "Batch sizes of the large-batch series (the learner's path only)")
      ->check(CLI::Range(1, 1 << 30));
  app.add_option("--hidden-sets", hidden_sets,
                 "Networks of the series, ';' between networks, ',' between layers (default: 256,256;512,512,512)");
  bench::add_list(app, "--dtypes", dtypes, "sac.matmul_dtype values of the series (float32, bfloat16)")
      ->check(CLI::IsMember({"float32", "bfloat16"}));
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  if (!hidden.empty()) g_hidden = {hidden};

  const int kObs = g_obs, kAct = g_act;
  farm::ReplayBuffer buf(100000, kObs, kAct);
  std::mt19937_64 rng(1);
  fill(buf, buf.capacity(), rng);
  const bool cuda = device.rfind("cuda", 0) == 0;
  bool ok = true;
  if (!batches.empty()) {
    std::vector<std::vector<int>> nets = hidden.empty() ? std::vector<std::vector<int>>{{256, 256}, {512, 512, 512}}
                                                        : std::vector<std::vector<int>>{hidden};
    if (!hidden_sets.empty()) nets = bench::parse_hidden_sets(hidden_sets);
    if (nets.empty()) {
      std::fprintf(stderr, "bench_sac: --hidden-sets '%s' is not layer sizes like 256,256;512,512,512\n",
                   hidden_sets.c_str());
      return 2;
    }
    farm::configure_compute(threads.empty() ? 1 : threads[0]);
    series(nets, batches, dtypes, device, seconds, buf, rng);
    return 0;
  }
  if (cuda)
    std::printf("sac.cuda_tf32 %s: matrix products in %s, eager and graph alike\n", g_tf32 ? "true" : "false",
                g_tf32 ? "TF32 (cuBLAS)" : "full FP32");
  std::printf("sac.actor_on_previous_critic %s: the actor's step %s\n", g_beside ? "true" : "false",
              g_beside ? "beside the critics' (against them before their step)" : "after the critics'");
  if (cuda && check_updates > 0) {
    farm::configure_compute(threads.empty() ? 1 : threads[0]);
    ok = check_graph(g_hidden.back(), batch, device, check_updates, buf, rng);
  }

  for (const std::vector<int>& hidden : g_hidden) {
    for (int n_threads : threads) {
      farm::configure_compute(n_threads);
      farm::config::SacConfig cfg = sac_config(hidden, device);
      const std::string net = describe(kObs, hidden, kAct);
      if (!cuda) {
        farm::Sac sac(cfg, kObs, kAct, 1);
        print_rate("", net, batch, device, n_threads, measure(sac, buf, batch, seconds, rng));
        continue;
      }
      // Both CUDA paths in the same process, one after the other.
      cfg.set_cuda_graph(false);
      Rate eager, graph;
      {
        farm::Sac sac(cfg, kObs, kAct, 1);
        eager = measure(sac, buf, batch, seconds, rng);
        print_rate(" eager", net, batch, device, n_threads, eager);
      }
      cfg.set_cuda_graph(true);
      cfg.set_cuda_fused_kernels(false);
      Rate torch_ops;
      {
        farm::Sac sac(cfg, kObs, kAct, 1);
        if (!sac.uses_cuda_graph()) {
          std::printf("sac update (%s, %s cuda graph): not in this build (CPU LibTorch)\n", net.c_str(),
                      device.c_str());
          continue;
        }
        torch_ops = measure(sac, buf, batch, seconds, rng);
        print_rate(" cuda graph of torch's ops", net, batch, device, n_threads, torch_ops);
      }
      cfg.set_cuda_fused_kernels(true);
      farm::Sac sac(cfg, kObs, kAct, 1);
      if (!sac.uses_fused_kernels()) {
        std::printf("sac update (%s, %s): no fused kernels in this build (no CUDA compiler)\n", net.c_str(),
                    device.c_str());
        continue;
      }
      graph = measure(sac, buf, batch, seconds, rng);
      print_rate(" cuda graph", net, batch, device, n_threads, graph);
      std::printf("sac update (%s, batch %d, %s): cuda graph / eager = %.2fx, fused kernels / torch's ops = %.2fx\n",
                  net.c_str(), batch, device.c_str(), (graph.n / graph.elapsed) / (eager.n / eager.elapsed),
                  (graph.n / graph.elapsed) / (torch_ops.n / torch_ops.elapsed));
      // The learner's path: groups of queued replays (replay_pacing.cpp), a fresh SAC.
      farm::Sac grouped(cfg, kObs, kAct, 1);
      const Rate queued = measure(grouped, buf, batch, seconds, rng, farm::kUpdatesPerGroup);
      print_rate(" cuda graph, 8 queued", net, batch, device, n_threads, queued);
      std::printf("sac update (%s, batch %d, %s): cuda graph 8 queued / eager = %.2fx, / one at a time = %.2fx\n",
                  net.c_str(), batch, device.c_str(), (queued.n / queued.elapsed) / (eager.n / eager.elapsed),
                  (queued.n / queued.elapsed) / (graph.n / graph.elapsed));
      // The same with the batches drawn on the GPU inside the graph (sac.replay_on_device).
      farm::DeviceReplay on_gpu(buf.capacity(), kObs, kAct, grouped.device(), cfg.gamma());
      on_gpu.load_from(buf);
      farm::Sac drawing(cfg, kObs, kAct, 1);
      const Rate drawn = measure(drawing, buf, batch, seconds, rng, farm::kUpdatesPerGroup, &on_gpu);
      print_rate(" cuda graph, 8 queued, batches drawn on the GPU", net, batch, device, n_threads, drawn);
      std::printf("sac update (%s, batch %d, %s): drawn on the GPU / sampled on the host (8 queued) = %.2fx\n",
                  net.c_str(), batch, device.c_str(), (drawn.n / drawn.elapsed) / (queued.n / queued.elapsed));
      std::fflush(stdout);
    }
  }
  return ok ? 0 : 1;
}
