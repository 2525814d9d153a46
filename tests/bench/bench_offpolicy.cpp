// The off-policy learners' throughput from small to large batches, through the interface the
// learner runs them by (learner/algorithms/algorithm.h): for each algorithm, network and batch
// size, the registry builds a fresh algorithm from a config, its replay is filled with random
// transitions through insert(), and update(8, version) runs as the replay pacing calls it, for
// --seconds after a warm-up; finish() is inside the timing. One table at the end: updates/s,
// samples/s (batch x updates/s) and each row's samples/s over the best at the first batch, same
// algorithm, same network, same run.
//   bench_offpolicy [--algorithms sac,td3,dqn] [--batches 256,4096,32768]
//                   [--hidden-sets "256,256;512,512,512"] [--device cuda] [--seconds S]
//                   [--obs 17 --act 6 --actions 5] [--variant 'sac:matmul_dtype: "bfloat16"' ...]
// Continuous algorithms get a task of --obs observations and --act actions (HalfCheetah's by
// default), discrete ones --actions actions. A network is every hidden list the section has
// (hidden, and critic_hidden where the section has one). --variant ALG:TEXT adds config text to
// ALG's section, one measured variant per --variant; an algorithm without one runs its defaults.
#include <google/protobuf/descriptor.h>
#include <google/protobuf/text_format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "bench_options.h"
#include "compute.h"
#include "pacing.h"  // kUpdatesPerGroup
#include "registry.h"

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

std::string join(const std::vector<int>& v, const char* sep) {
  std::string s;
  for (size_t i = 0; i < v.size(); ++i) s += (i ? sep : "") + std::to_string(v[i]);
  return s;
}

// The config of one measurement, as a user would write it.
farm::config::ExperimentConfig make_config(const std::string& algorithm, int batch, const std::vector<int>& hidden,
                                           const std::string& device, int64_t buffer, const std::string& extra) {
  const auto* section = farm::config::ExperimentConfig::descriptor()->FindFieldByName(algorithm);
  if (!section || !section->message_type())
    throw std::invalid_argument("no config section '" + algorithm + "' in farm_config.proto");
  const std::string net = "[" + join(hidden, ", ") + "]";
  std::string text = "experiment_id: \"bench_offpolicy\"\nalgorithm: \"" + algorithm + "\"\n" + algorithm +
                     " {\n  batch_size: " + std::to_string(batch) + "\n  hidden: " + net + "\n  device: \"" + device +
                     "\"\n  buffer_size: " + std::to_string(buffer) + "\n  learning_starts: 0\n";
  if (section->message_type()->FindFieldByName("critic_hidden")) text += "  critic_hidden: " + net + "\n";
  text += "  " + extra + "\n}\n";
  farm::config::ExperimentConfig cfg;
  if (!google::protobuf::TextFormat::ParseFromString(text, &cfg))
    throw std::invalid_argument("bench_offpolicy: config text of " + algorithm + " does not parse:\n" + text);
  return cfg;
}

// Random transitions in batches of 1,000 rows, as ingest hands them over.
void fill(farm::Algorithm& algo, const farm::robots::TaskSpec& spec, int64_t rows, std::mt19937_64& rng) {
  constexpr int kRows = 1000;
  std::normal_distribution<float> g;
  std::uniform_int_distribution<int> pick(0, std::max(spec.num_actions, 1) - 1);
  farm::Transitions t;
  std::vector<uint8_t> truncated(kRows, 0);
  for (int64_t done = 0; done < rows; done += kRows) {
    t.clear();
    t.n = kRows;
    for (int i = 0; i < kRows * spec.obs_dim; ++i) {
      t.obs.push_back(g(rng));
      t.next_obs.push_back(g(rng));
    }
    for (int i = 0; i < kRows * spec.act_dim; ++i)
      t.actions.push_back(spec.num_actions > 0 ? float(pick(rng)) : std::tanh(g(rng)));
    for (int i = 0; i < kRows; ++i) {
      t.rewards.push_back(g(rng));
      t.terminated.push_back(i % 97 == 0);
    }
    farm::Batch b;
    b.worker_id = "bench";
    b.num_steps = 1;
    b.num_envs = kRows;
    b.truncated = truncated.data();
    b.rows = &t;
    algo.insert(b);
  }
}

struct Row {
  std::string algorithm, net, variant;
  int batch = 0;
  double updates = 0, samples = 0, ratio = 0;
};

}  // namespace

int main(int argc, char** argv) {
  double seconds = 3.0;
  std::string device = "cpu", hidden_sets = "256,256;512,512,512";
  std::vector<std::string> algorithms{"sac", "td3", "dqn"}, variants;
  std::vector<int> batches{256, 4096, 32768};
  int obs = 17, act = 6, actions = 5, threads = 1;
  farm::cli::App app("bench_offpolicy");
  app.description(
      "Off-policy learners' updates/s and samples/s at each batch size, through the algorithm interface the learner "
      "runs them by.");
  bench::add_seconds(app, seconds);
  bench::add_device(app, device);
  bench::add_threads(app, threads);
  bench::add_list(app, "--algorithms", algorithms, "Registered off-policy algorithms");
  bench::add_list(app, "--batches", batches, "Batch sizes")->check(CLI::Range(1, 1 << 30));
  app.add_option("--hidden-sets", hidden_sets, "Networks, ';' between networks, ',' between layers")
      ->capture_default_str();
  app.add_option("--obs", obs, "Observation size")->check(CLI::Range(1, 1 << 20))->capture_default_str();
  app.add_option("--act", act, "Continuous action size")->check(CLI::Range(1, 1 << 20))->capture_default_str();
  app.add_option("--actions", actions, "Discrete actions (dqn)")->check(CLI::Range(2, 1 << 20))->capture_default_str();
  app.add_option("--variant", variants,
                 "ALG:TEXT, config text added to ALG's section: one measured variant each (e.g. 'sac:matmul_dtype: "
                 "\"bfloat16\"')");
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  const auto nets = bench::parse_hidden_sets(hidden_sets);
  if (nets.empty()) {
    std::fprintf(stderr, "bench_offpolicy: --hidden-sets '%s' is not layer sizes like 256,256;512,512,512\n",
                 hidden_sets.c_str());
    return 2;
  }
  std::map<std::string, std::vector<std::string>> extra;
  for (const std::string& v : variants) {
    const size_t colon = v.find(':');
    if (colon == std::string::npos || colon == 0) {
      std::fprintf(stderr, "bench_offpolicy: --variant '%s' is not ALG:TEXT\n", v.c_str());
      return 2;
    }
    extra[v.substr(0, colon)].push_back(v.substr(colon + 1));
  }
  for (const std::string& a : algorithms) {
    try {
      if (farm::find_algorithm(a).on_policy) {
        std::fprintf(stderr, "bench_offpolicy: '%s' is an on-policy algorithm\n", a.c_str());
        return 2;
      }
    } catch (const std::exception& e) {
      std::fprintf(stderr, "bench_offpolicy: %s\n", e.what());
      return 2;
    }
    if (extra[a].empty()) extra[a].push_back("");
  }
  farm::configure_compute(threads);
  const int largest = *std::max_element(batches.begin(), batches.end());
  const int64_t buffer = std::max<int64_t>(100000, 4 * int64_t(largest));
  std::vector<Row> rows;
  for (const std::string& a : algorithms) {
    for (const auto& hidden : nets) {
      const size_t first_row = rows.size();
      double first = 0;  // the best samples/s at the first batch: this algorithm, this network
      for (const std::string& variant : extra[a]) {
        for (int batch : batches) {
          farm::robots::TaskSpec spec;
          spec.name = "bench";
          spec.obs_dim = obs;
          spec.act_dim = act;
          spec.max_episode_steps = 1000;
          const bool discrete = a == "dqn";
          if (discrete) {
            spec.act_dim = 1;
            spec.num_actions = actions;
          }
          std::mt19937_64 rng(1);
          auto algo = farm::make_algorithm(make_config(a, batch, hidden, device, buffer, variant), spec);
          fill(*algo, spec, std::max<int64_t>(20000, 2 * int64_t(batch)), rng);
          uint64_t version = 1;
          auto run = [&] { return algo->update(farm::kUpdatesPerGroup, version++); };
          // Warm-up: allocations, optimizer state, graph captures are not the steady state.
          const auto warm = Clock::now();
          while (seconds_since(warm) < std::min(1.0, seconds / 3)) run();
          algo->finish();
          const int64_t before = algo->updates();
          double last_figure = NAN;
          const auto t0 = Clock::now();
          while (seconds_since(t0) < seconds) {
            const auto figs = run();
            if (!figs.empty() && !figs.back().values.empty()) last_figure = figs.back().values.front().second;
          }
          for (const auto& f : algo->finish())
            if (!f.values.empty()) last_figure = f.values.front().second;
          const double elapsed = seconds_since(t0);
          const double ups = double(algo->updates() - before) / elapsed, sps = ups * batch;
          if (!std::isfinite(last_figure)) {
            std::fprintf(stderr, "bench_offpolicy: %s batch %d gave a figure that is not finite\n", a.c_str(), batch);
            return 1;
          }
          const std::string net =
              std::to_string(obs) + "-[" + join(hidden, ",") + "]-" + std::to_string(discrete ? actions : act);
          std::printf("%s update (%s, batch %d, %s%s%s): %.0f updates/s, %.0f samples/s\n", a.c_str(), net.c_str(),
                      batch, device.c_str(), variant.empty() ? "" : ", ", variant.c_str(), ups, sps);
          std::fflush(stdout);
          if (batch == batches.front()) first = std::max(first, sps);
          rows.push_back({a, net, variant.empty() ? "defaults" : variant, batch, ups, sps, 0});
        }
      }
      for (size_t i = first_row; i < rows.size(); ++i) rows[i].ratio = rows[i].samples / first;
    }
  }
  std::printf("\n%-5s %-20s %-28s %8s %10s %13s %s\n", "algo", "network", "variant", "batch", "updates/s", "samples/s",
              "samples/s over the best at the first batch, same algorithm and network");
  for (const Row& r : rows)
    std::printf("%-5s %-20s %-28s %8d %10.0f %13.0f %.1fx\n", r.algorithm.c_str(), r.net.c_str(), r.variant.c_str(),
                r.batch, r.updates, r.samples, r.ratio);
  return 0;
}
