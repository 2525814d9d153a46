// farm-export: writes a trained run's policy (RUN/checkpoint or RUN/best) as an ONNX model
// (tools/onnx_policy.*) with the task's observation and action layout in its metadata, checked by
// onnx's checker; --record steps the real task with the worker's Eigen policy and writes the
// observations it saw and the actions it took, the reference another runtime is compared with.
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "cli.h"
#include "onnx_policy.h"
#include "run_policy.h"
#include "task.h"

using namespace farm;
namespace fs = std::filesystem;

namespace {

struct Options {
  std::string run_dir, out, which = "checkpoint";
  std::pair<long, std::string> record{0, ""};  // --record N FILE.csv; N 0: none
  uint64_t seed = 1;
};

// Bound on --record N: 10 million rows is already a CSV of gigabytes.
constexpr long kMaxRecordSteps = 10'000'000;

// Declares the options into o; --run-dir and --out are required.
void add_options(CLI::App& app, Options& o) {
  app.description(
      "Writes the policy of RUN/checkpoint (with --best: RUN/best, the networks of the learner's best\n"
      "evaluation) as an ONNX model: input \"obs\" [N, obs_dim], output \"action\" (SAC, PPO: the\n"
      "deterministic action in [-1, 1]; DQN: the argmax index, and \"q_values\"), the observation\n"
      "normalizer included, the task's layout in the model's metadata.");
  app.add_option("--run-dir", o.run_dir, "The run folder")->required();
  app.add_flag_callback(
      "--best", [&o] { o.which = "best"; }, "RUN/best, the networks of the learner's best evaluation");
  app.add_option("--out", o.out, "The ONNX model to write")->required();
  app.add_option("--record", o.record,
                 "N FILE.csv: also steps the task for N steps (episodes from --seed) with the worker's own "
                 "policy, deterministic, and writes each observation and its action (DQN: and its Q values) as "
                 "a CSV row")
      ->check(CLI::Range(1L, kMaxRecordSteps).application_index(0));
  app.add_option("--seed", o.seed, "Reset seed of the first recorded episode")
      ->check(farm::cli::whole_number())
      ->capture_default_str();
}

struct Layout {
  std::string obs_names, obs_layout, action;
};

// What each task's observation entries and actions mean (from the task headers in robots/).
Layout task_layout(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  const std::string& t = spec.name;
  const bool discrete = spec.num_actions > 0;
  if (t == "pendulum") return {"cos_th,sin_th,thdot", "", "torque / task.pendulum.max_torque"};
  if (t == "cartpole") return {"x,cos_th,sin_th,xdot,thdot", "", "cart force / task.cartpole.max_force"};
  if (t == "jetbot" || t == "kaya") {
    const std::string base = t == "jetbot" ? "(V, W)" : "(Vx, Vy, W)";
    return {"",
            "lidar distances / range (one per ray), base velocity in the base frame (Vx, Vy, W) over the top "
            "speeds, wheel speeds over the top wheel speed, distance to the goal / arena_half_size, cos and sin "
            "of the heading error to the goal",
            discrete ? "index of the task's discrete base command " + base + ", in [0, " +
                           std::to_string(spec.num_actions) + ")"
                     : "base command " + base + " over the top speeds"};
  }
  if (t == "mclari")
    return {"",
            "sum of mean |P_i|, mean speed of the centre of mass over the step, x error, y error to the target, "
            "each divided by its task.mclari scale" +
                std::string(cfg.task().mclari().observe_gait()
                                ? ", frequency / max_frequency, phase-group index / (groups - 1)"
                                : "") +
                std::string(cfg.task().mclari().observe_terrain() ? ", rough, wet, extra-dry (0 or 1 each)" : ""),
            "a0: frequency change (f <- f + a0 df), a1: inter-leg phase group, scaled to an index"};
  if (t == "a1" || t == "honey_badger" || t == "silver_badger")
    return {"",
            "base_lin_vel (3, base frame), base_ang_vel (3), projected_gravity (3), command_lin (2), command_yaw "
            "(1), dof_pos (n, minus the default pose), dof_vel (n), last_action (n)" +
                std::string(t == "a1" ? "" : ", base_height (1), dynamics (16, each mapped to [-1, 1])"),
            "one target per actuated joint: default pose + action_scale * action_range * a"};
  return {"", "", ""};
}

std::vector<std::pair<std::string, std::string>> metadata(const config::ExperimentConfig& cfg,
                                                          const config::CheckpointManifest& m,
                                                          const robots::TaskSpec& spec, const PolicyParams& p,
                                                          const std::string& which) {
  const Layout l = task_layout(cfg, spec);
  std::vector<std::pair<std::string, std::string>> md = {
      {"task", spec.name},
      {"observation_size", std::to_string(spec.obs_dim)},
  };
  if (!l.obs_names.empty()) md.emplace_back("observation_names", l.obs_names);
  if (!l.obs_layout.empty()) md.emplace_back("observation_layout", l.obs_layout);
  md.emplace_back("observation_normalizer",
                  p.obs_mean.empty() ? "none" : "(obs - obs_mean) / obs_std, the running statistics, no clipping");
  md.emplace_back("action_size", std::to_string(spec.act_dim));
  if (spec.num_actions > 0) {
    md.emplace_back("num_actions", std::to_string(spec.num_actions));
    md.emplace_back("action_head", "argmax of q_values (the first of equal maxima), int64 [N, 1]");
  } else {
    md.emplace_back("action_head", p.head == PolicyHead::kGaussian
                                       ? "the Gaussian's mean clipped to [-1, 1]"
                                       : "tanh of the squashed Gaussian's mean, in [-1, 1]");
  }
  if (!l.action.empty()) md.emplace_back("action_meaning", l.action);
  md.emplace_back("algorithm", cfg.algorithm());
  md.emplace_back("network", p.layout.describe());
  md.emplace_back("policy_version", std::to_string(m.policy_version()));
  md.emplace_back("experiment_id", cfg.experiment_id());
  md.emplace_back("source", which);
  md.emplace_back("updates", std::to_string(m.updates()));
  md.emplace_back("env_steps", std::to_string(m.env_steps()));
  if (m.has_best_eval_return()) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.6g", m.best_eval_return());
    md.emplace_back("best_eval_return", buf);
  }
  md.emplace_back("experiment_config", m.config_text());
  return md;
}

void write_model(const onnx::ModelProto& model, const std::string& path) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) throw std::runtime_error("cannot write " + tmp);
    if (!model.SerializeToOstream(&out)) throw std::runtime_error("cannot serialize the model to " + tmp);
    out.close();
    if (!out) throw std::runtime_error("write failed: " + tmp);
  }
  fs::rename(tmp, path);
}

// N steps of the real task with the worker's Policy (deterministic, one row at a time, as the
// learner's evaluation runs it), episodes from seed, seed + 1, ...; one CSV row per step: the
// observation the policy saw and the action it took, for DQN also the Q values it chose from.
void record(const robots::Task& task, const PolicyParams& params, long steps, uint64_t seed, const std::string& path) {
  const robots::TaskSpec& spec = task.spec();
  Policy policy(params);
  EigenMlp q_net(params.layout, params.params);
  const bool discrete = params.head == PolicyHead::kDiscreteQ;
  const int n_q = discrete ? params.layout.sizes.back() : 0;
  std::ofstream out(path);
  if (!out) throw std::runtime_error("cannot write " + path);
  for (int i = 0; i < spec.obs_dim; ++i) out << (i ? "," : "") << "obs_" << i;
  for (int i = 0; i < spec.act_dim; ++i) out << ",action_" << i;
  for (int i = 0; i < n_q; ++i) out << ",q_" << i;
  out << "\n";
  std::vector<float> obs(size_t(spec.obs_dim)), act(size_t(spec.act_dim)), normed(obs.size()),
      q(static_cast<size_t>(n_q));
  std::mt19937_64 unused_rng;  // deterministic: no noise is drawn
  auto state = task.make_state();
  task.reset(*state, seed, obs.data());
  long episodes = 1;
  char buf[32];
  auto put = [&](float v, bool first) {
    std::snprintf(buf, sizeof buf, "%s%.9g", first ? "" : ",", double(v));  // 9 digits: the float exactly
    out << buf;
  };
  for (long k = 0; k < steps; ++k) {
    policy.act(obs.data(), 1, unused_rng, true, act.data(), nullptr);
    for (int i = 0; i < spec.obs_dim; ++i) put(obs[size_t(i)], i == 0);
    for (float a : act) put(a, false);
    if (discrete) {
      const float* x = obs.data();
      if (!params.obs_mean.empty()) {
        for (size_t i = 0; i < obs.size(); ++i) normed[i] = (obs[i] - params.obs_mean[i]) / params.obs_std[i];
        x = normed.data();
      }
      q_net.forward(x, 1, q.data());
      for (float v : q) put(v, false);
    }
    out << "\n";
    const auto r = task.step(*state, act.data(), obs.data());
    if (r.terminated || r.truncated) {
      task.reset(*state, seed + uint64_t(episodes), obs.data());
      ++episodes;
    }
  }
  out.close();
  if (!out) throw std::runtime_error("write failed: " + path);
  std::printf("recorded          %ld steps of %ld episodes (seeds %llu..) in %s\n", steps, episodes,
              (unsigned long long)seed, path.c_str());
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  farm::cli::App app("farm-export");
  add_options(app, o);
  // Every refusal of farm-export, bad usage included, exits 1 (tests/integration/test_export.sh).
  if (const int rc = farm::cli::parse(app, argc, argv, 1); rc >= 0) return rc;
  try {
    const tools::RunPolicy rp = tools::load_run_policy(tools::run_policy_dir(o.run_dir, o.which == "best"));
    const config::CheckpointManifest& m = rp.manifest;
    const config::ExperimentConfig& cfg = rp.config;
    const robots::Task& task = *rp.task;
    const robots::TaskSpec& spec = task.spec();
    const PolicyParams& params = rp.policy;

    const std::string doc = "Policy v" + std::to_string(m.policy_version()) + " of experiment '" + cfg.experiment_id() +
                            "' (" + cfg.algorithm() + ", task " + spec.name + "): obs [N, " +
                            std::to_string(spec.obs_dim) + "] -> the worker's deterministic action.";
    const onnx::ModelProto model = tools::policy_to_onnx(params, metadata(cfg, m, spec, params, o.which), doc);
    tools::check_onnx_model(model);
    write_model(model, o.out);
    std::printf("%s: %s policy v%llu (%s, %lld updates, %llu env steps) of task %s from %s\n",
                cfg.experiment_id().c_str(), cfg.algorithm().c_str(), (unsigned long long)m.policy_version(),
                params.layout.describe().c_str(), (long long)m.updates(), (unsigned long long)m.env_steps(),
                spec.name.c_str(), rp.dir.c_str());
    std::printf("wrote             %s (%zu bytes, ONNX opset %d; onnx checker: accepted)\n", o.out.c_str(),
                model.ByteSizeLong(), tools::kOnnxOpset);
    if (o.record.first > 0) record(task, params, o.record.first, o.seed, o.record.second);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-export: %s\n", e.what());
    return 1;
  }
}
