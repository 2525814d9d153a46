#include "config.h"
#include "config_validator.h"

#include <google/protobuf/io/tokenizer.h>
#include <google/protobuf/text_format.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <functional>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace farm {

namespace pb = google::protobuf;
using namespace config_checks;  // Collector, Validator, Section, num

namespace {

// sac.max_step_scale and dqn.max_step_scale at most: a batch 64 times the configured one is past
// what helps on any host here.
constexpr int kMaxStepScale = 64;

// Algorithm sections.

// sac.lr_decay_* and dqn.lr_decay_*: a schedule's length and the fraction it ends at.
void check_lr_decay(const Section& s, int64_t updates, double to) {
  s.non_negative("lr_decay_updates", updates);
  s.check(to > 0 && to <= 1, "lr_decay_to", "expected a fraction in (0, 1] of the configured rates, got " + num(to));
}

// sac/dqn.samples_per_insert: 0 (off) or more, and not beside a step scale, which also sets the ratio.
void check_samples_per_insert(const Section& s, double samples_per_insert, int max_step_scale) {
  s.check(samples_per_insert >= 0, "samples_per_insert", "expected 0 (off) or more, got " + num(samples_per_insert));
  s.check(samples_per_insert == 0 || max_step_scale == 1, "samples_per_insert",
          "samples_per_insert and max_step_scale > 1 both set the update-to-data ratio: set one of them");
}

// sac/dqn.matmul_dtype: the products' type.
void check_matmul_dtype(const Section& s, const std::string& dtype) {
  s.check(dtype == "float32" || dtype == "bfloat16", "matmul_dtype",
          "expected \"float32\" or \"bfloat16\", got \"" + dtype + "\"");
}

void check_sac(const Section& s, const config::SacConfig& c) {
  s.positive("actor_lr", c.actor_lr());
  s.positive("critic_lr", c.critic_lr());
  s.positive("alpha_lr", c.alpha_lr());
  s.in_unit("gamma", c.gamma());
  s.in_unit("tau", c.tau());
  s.positive("batch_size", c.batch_size());
  if (c.buffer_size() < c.batch_size())
    s.fail("buffer_size", "expected >= sac.batch_size (" + num(c.batch_size()) + "), got " + num(c.buffer_size()));
  s.non_negative("learning_starts", c.learning_starts());
  s.check(c.learning_starts() <= c.buffer_size(), "learning_starts",
          "expected <= sac.buffer_size (" + num(c.buffer_size()) +
              "), since updates wait for this many rows in the replay buffer; got " + num(c.learning_starts()));
  s.layer_sizes("hidden", c.hidden());
  s.layer_sizes("critic_hidden", c.critic_hidden());
  s.positive("initial_alpha", c.initial_alpha());
  s.check(c.log_std_min() < c.log_std_max(), "log_std_min", "expected < sac.log_std_max");
  s.positive("max_updates_per_step", c.max_updates_per_step());
  s.positive("publish_every_updates", c.publish_every_updates());
  s.check(c.max_step_scale() >= 1 && c.max_step_scale() <= kMaxStepScale, "max_step_scale",
          "expected 1 to " + num(kMaxStepScale) + ", got " + num(c.max_step_scale()));
  s.at_least("n_step", c.n_step(), 1);
  check_lr_decay(s, c.lr_decay_updates(), c.lr_decay_to());
  s.check(valid_device_name(c.device()), "device",
          "expected \"cpu\", \"cuda\", \"cuda:N\" or \"auto\", got \"" + c.device() + "\"");
  s.check(c.activation() == "relu" || c.activation() == "tanh", "activation",
          "expected \"relu\" or \"tanh\", got \"" + c.activation() + "\"");
  check_samples_per_insert(s, c.samples_per_insert(), c.max_step_scale());
  check_matmul_dtype(s, c.matmul_dtype());
  s.check(c.policy_average_tau() >= 0 && c.policy_average_tau() <= 1, "policy_average_tau",
          "expected 0 (off) to 1, got " + num(c.policy_average_tau()));
}

void check_dqn(const Section& s, const config::DqnConfig& c) {
  s.positive("learning_rate", c.learning_rate());
  s.positive("batch_size", c.batch_size());
  if (c.buffer_size() < c.batch_size())
    s.fail("buffer_size", "expected >= dqn.batch_size (" + num(c.batch_size()) + "), got " + num(c.buffer_size()));
  s.in_unit("gamma", c.gamma());
  s.in_unit("exploration_fraction", c.exploration_fraction());
  s.in_unit("exploration_initial_eps", c.exploration_initial_eps());
  s.in_unit("exploration_final_eps", c.exploration_final_eps());
  s.positive("schedule_env_steps", c.schedule_env_steps());
  s.non_negative("learning_starts", c.learning_starts());
  s.check(c.learning_starts() <= c.buffer_size(), "learning_starts",
          "expected <= dqn.buffer_size (" + num(c.buffer_size()) +
              "), since updates wait for this many rows in the replay buffer; got " + num(c.learning_starts()));
  s.positive("target_update_updates", c.target_update_updates());
  s.positive("max_grad_norm", c.max_grad_norm());
  s.layer_sizes("hidden", c.hidden());
  s.positive("max_updates_per_step", c.max_updates_per_step());
  check_samples_per_insert(s, c.samples_per_insert(), c.max_step_scale());
  s.positive("publish_every_updates", c.publish_every_updates());
  s.at_least("n_step", c.n_step(), 1);
  s.check(valid_device_name(c.device()), "device",
          "expected \"cpu\", \"cuda\", \"cuda:N\" or \"auto\", got \"" + c.device() + "\"");
  s.check(c.max_step_scale() >= 1 && c.max_step_scale() <= kMaxStepScale, "max_step_scale",
          "expected 1 to " + num(kMaxStepScale) + ", got " + num(c.max_step_scale()));
  check_lr_decay(s, c.lr_decay_updates(), c.lr_decay_to());
  check_matmul_dtype(s, c.matmul_dtype());
  s.non_negative("lr_reference_batch", c.lr_reference_batch());
}

void check_td3(const Section& s, const config::Td3Config& c) {
  s.positive("actor_lr", c.actor_lr());
  s.positive("critic_lr", c.critic_lr());
  s.non_negative("weight_decay", c.weight_decay());
  s.in_unit("gamma", c.gamma());
  s.in_unit("tau", c.tau());
  s.positive("batch_size", c.batch_size());
  if (c.buffer_size() < c.batch_size())
    s.fail("buffer_size", "expected >= td3.batch_size (" + num(c.batch_size()) + "), got " + num(c.buffer_size()));
  s.non_negative("learning_starts", c.learning_starts());
  s.check(c.learning_starts() <= c.buffer_size(), "learning_starts",
          "expected <= td3.buffer_size (" + num(c.buffer_size()) +
              "), since updates wait for this many rows in the replay buffer; got " + num(c.learning_starts()));
  s.layer_sizes("hidden", c.hidden());
  s.layer_sizes("critic_hidden", c.critic_hidden());
  s.positive("init_scale", c.init_scale());
  s.at_least("num_atoms", c.num_atoms(), 2);
  s.check(std::isfinite(c.v_min()) && std::isfinite(c.v_max()) && c.v_min() < c.v_max(), "v_min",
          "expected finite td3.v_min < td3.v_max (" + num(c.v_max()) + "), got " + num(c.v_min()));
  s.non_negative("policy_noise", c.policy_noise());
  s.non_negative("noise_clip", c.noise_clip());
  s.at_least("policy_delay", c.policy_delay(), 1);
  s.positive("std_min", c.std_min());
  s.check(c.std_min() <= c.std_max(), "std_max",
          "expected >= td3.std_min (" + num(c.std_min()) + "), got " + num(c.std_max()));
  s.non_negative("max_grad_norm", c.max_grad_norm());
  s.at_least("n_step", c.n_step(), 1);
  s.positive("max_updates_per_step", c.max_updates_per_step());
  s.check(c.samples_per_insert() >= 0, "samples_per_insert",
          "expected 0 (off) or more, got " + num(c.samples_per_insert()));
  s.positive("publish_every_updates", c.publish_every_updates());
  s.check(valid_device_name(c.device()), "device",
          "expected \"cpu\", \"cuda\", \"cuda:N\" or \"auto\", got \"" + c.device() + "\"");
}

void check_fastsac(const Section& s, const config::FastSacConfig& c) {
  s.positive("actor_lr", c.actor_lr());
  s.positive("critic_lr", c.critic_lr());
  s.positive("alpha_lr", c.alpha_lr());
  s.non_negative("weight_decay", c.weight_decay());
  s.non_negative("alpha_weight_decay", c.alpha_weight_decay());
  s.check(c.adam_beta1() >= 0 && c.adam_beta1() < 1, "adam_beta1", "expected in [0, 1), got " + num(c.adam_beta1()));
  s.check(c.adam_beta2() >= 0 && c.adam_beta2() < 1, "adam_beta2", "expected in [0, 1), got " + num(c.adam_beta2()));
  s.in_unit("gamma", c.gamma());
  s.in_unit("tau", c.tau());
  s.positive("batch_size", c.batch_size());
  if (c.buffer_size() < c.batch_size())
    s.fail("buffer_size", "expected >= fastsac.batch_size (" + num(c.batch_size()) + "), got " + num(c.buffer_size()));
  s.non_negative("learning_starts", c.learning_starts());
  s.check(c.learning_starts() <= c.buffer_size(), "learning_starts",
          "expected <= fastsac.buffer_size (" + num(c.buffer_size()) +
              "), since updates wait for this many rows in the replay buffer; got " + num(c.learning_starts()));
  s.layer_sizes("hidden", c.hidden());
  s.layer_sizes("critic_hidden", c.critic_hidden());
  s.check(c.activation() == "relu" || c.activation() == "tanh" || c.activation() == "elu", "activation",
          "expected \"relu\", \"tanh\" or \"elu\", got \"" + c.activation() + "\"");
  s.at_least("num_atoms", c.num_atoms(), 2);
  s.check(std::isfinite(c.v_min()) && std::isfinite(c.v_max()) && c.v_min() < c.v_max(), "v_min",
          "expected finite fastsac.v_min < fastsac.v_max (" + num(c.v_max()) + "), got " + num(c.v_min()));
  s.at_least("policy_delay", c.policy_delay(), 1);
  s.check(std::isfinite(c.log_std_min()) && std::isfinite(c.log_std_max()) && c.log_std_min() < c.log_std_max(),
          "log_std_min",
          "expected finite fastsac.log_std_min < fastsac.log_std_max (" + num(c.log_std_max()) + "), got " +
              num(c.log_std_min()));
  s.finite_positive("initial_alpha", c.initial_alpha());
  s.check(std::isfinite(c.target_entropy_ratio()), "target_entropy_ratio",
          "expected a finite number, got " + num(c.target_entropy_ratio()));
  s.non_negative("max_grad_norm", c.max_grad_norm());
  s.at_least("n_step", c.n_step(), 1);
  s.positive("max_updates_per_step", c.max_updates_per_step());
  s.check(c.samples_per_insert() >= 0, "samples_per_insert",
          "expected 0 (off) or more, got " + num(c.samples_per_insert()));
  s.positive("publish_every_updates", c.publish_every_updates());
  s.check(valid_device_name(c.device()), "device",
          "expected \"cpu\", \"cuda\", \"cuda:N\" or \"auto\", got \"" + c.device() + "\"");
}

void check_ppo(const Section& s, const config::PpoConfig& c) {
  s.check(c.variant() == "clip_kl" || c.variant() == "plain", "variant",
          "expected \"clip_kl\" or \"plain\", got \"" + c.variant() + "\"");
  if (c.steps_per_fit() < 0 || c.episodes_per_fit() < 0 || (c.steps_per_fit() > 0) == (c.episodes_per_fit() > 0))
    s.fail("episodes_per_fit",
           "set exactly one of ppo.steps_per_fit and ppo.episodes_per_fit > 0 (steps_per_fit: 0 to fit by episodes)");
  s.positive("mini_batch_size", c.mini_batch_size());
  s.positive("learning_rate", c.learning_rate());
  s.in_unit("gamma", c.gamma());
  s.check(c.gae_lambda() >= 0 && c.gae_lambda() <= 1, "gae_lambda", "expected in [0, 1], got " + num(c.gae_lambda()));
  s.non_negative("entropy_coef", c.entropy_coef());
  s.positive("clip_epsilon", c.clip_epsilon());
  s.positive("epochs", c.epochs());
  s.positive("max_grad_norm", c.max_grad_norm());
  s.positive("desired_kl", c.desired_kl());
  // The KL-adaptive rate divides and multiplies by these: 1 would never move it.
  s.check(c.kl_band() > 1, "kl_band", "expected > 1, got " + num(c.kl_band()));
  s.check(c.lr_factor() > 1, "lr_factor", "expected > 1, got " + num(c.lr_factor()));
  s.check(c.lr_min() > 0 && c.lr_min() <= c.lr_max(), "lr_min",
          "expected 0 < lr_min <= lr_max (" + num(c.lr_max()) + "), got " + num(c.lr_min()));
  s.check(valid_device_name(c.device()), "device",
          "expected \"cpu\", \"cuda\", \"cuda:N\" or \"auto\", got \"" + c.device() + "\"");
  s.non_negative("value_loss_coef", c.value_loss_coef());
  s.layer_sizes("hidden", c.hidden());
  s.check(c.activation() == "tanh" || c.activation() == "relu" || c.activation() == "elu", "activation",
          "expected \"tanh\", \"relu\" or \"elu\", got \"" + c.activation() + "\"");
  s.check(c.log_std_min() < c.log_std_max(), "log_std_min", "expected < ppo.log_std_max");
  s.non_negative("max_policy_lag", c.max_policy_lag());
  s.positive("stalled_worker_seconds", c.stalled_worker_seconds());
  s.check(c.mode() == "sync" || c.mode() == "async", "mode",
          "expected \"sync\" or \"async\", got \"" + c.mode() + "\"");
  if (c.mode() == "async") {
    s.check(c.max_policy_lag() >= 1, "mode",
            "\"async\" fits data of recent versions: needs ppo.max_policy_lag >= 1, got " + num(c.max_policy_lag()));
    s.check(c.steps_per_fit() > 0, "mode", "\"async\" fits by steps: needs ppo.steps_per_fit > 0");
  }
  s.positive("vtrace_rho_bar", c.vtrace_rho_bar());
  s.positive("vtrace_c_bar", c.vtrace_c_bar());
  s.check(c.surrogate() == "behaviour" || c.surrogate() == "proximal", "surrogate",
          "expected \"behaviour\" or \"proximal\", got \"" + c.surrogate() + "\"");
  s.check(c.steps_per_run() >= 0, "steps_per_run", "expected >= 0 (0 = no limit)");
  s.check(c.episodes_per_run() >= 0, "episodes_per_run", "expected >= 0 (0 = no limit)");
  s.check(c.eval_every_fits() >= 0, "eval_every_fits",
          "expected >= 0 (0: only at the end), got " + num(c.eval_every_fits()));
}

void validate(const config::ExperimentConfig& c, Validator& v, const TaskKnowledge& tasks) {
  const Section root(v, c, "");
  if (!c.has_experiment_id() || c.experiment_id().empty())
    root.fail("experiment_id", "required: a name for the run, e.g. \"my_robot_sac\"");
  for (char ch : c.experiment_id()) {
    if (!(std::isalnum(static_cast<unsigned char>(ch)) || ch == '_' || ch == '-' || ch == '.'))
      root.fail("experiment_id", "expected letters, digits, '_', '-' or '.', got \"" + c.experiment_id() + "\"");
  }
  // It names the run folder (<run_root>/<experiment_id>): "." and ".." would name another one.
  if (c.experiment_id() == "." || c.experiment_id() == "..")
    root.fail("experiment_id", "\"" + c.experiment_id() + "\" is not a name for a run folder");
  const std::vector<std::string> algorithms = algorithm_sections();
  if (std::find(algorithms.begin(), algorithms.end(), c.algorithm()) == algorithms.end()) {
    std::string known;
    for (const auto& a : algorithms) known += (known.empty() ? "" : ", ") + a;
    root.fail("algorithm", "expected one of: " + known + "; got \"" + c.algorithm() + "\"");
  }

  tasks.check_section(root.nest("task", c.task()), c.task());
  check_sac(root.nest("sac", c.sac()), c.sac());
  if (c.algorithm() == "dqn") check_dqn(root.nest("dqn", c.dqn()), c.dqn());
  if (c.algorithm() == "ppo") check_ppo(root.nest("ppo", c.ppo()), c.ppo());
  if (c.algorithm() == "td3") check_td3(root.nest("td3", c.td3()), c.td3());
  if (c.algorithm() == "fastsac") check_fastsac(root.nest("fastsac", c.fastsac()), c.fastsac());

  const Section e = root.nest("eval", c.eval());
  e.positive("episodes", c.eval().episodes());
  e.positive("every_seconds", c.eval().every_seconds());
  e.check(c.eval().episodes() <= kMaxEvalEpisodes, "episodes",
          "expected at most " + std::to_string(kMaxEvalEpisodes) + ", got " + num(c.eval().episodes()));
  e.positive("final_episodes", c.eval().final_episodes());
  e.check(c.eval().final_episodes() <= kMaxEvalEpisodes, "final_episodes",
          "expected at most " + std::to_string(kMaxEvalEpisodes) + ", got " + num(c.eval().final_episodes()));
  e.finite_positive("answer_timeout_seconds", c.eval().answer_timeout_seconds());
  e.check(c.eval().min_episodes_per_worker() >= 0, "min_episodes_per_worker",
          "expected >= 0 (0 = every evaluation on one worker), got " + num(c.eval().min_episodes_per_worker()));
  e.check(c.eval().best_reduce() == "mean" || c.eval().best_reduce() == "min", "best_reduce",
          "expected \"mean\" or \"min\", got \"" + c.eval().best_reduce() + "\"");
  if (!c.eval().best_metric().empty()) {
    std::vector<std::string> metrics;
    try {
      metrics = tasks.metric_names(c.task());
    } catch (const std::invalid_argument& err) {
      e.fail("best_metric", std::string("names one of the task's metrics: ") + err.what());
    }
    std::string known;
    for (const auto& m : metrics) known += (known.empty() ? "" : ", ") + m;
    if (std::find(metrics.begin(), metrics.end(), c.eval().best_metric()) == metrics.end())
      e.fail("best_metric", "\"" + c.eval().best_metric() + "\" is not one of task '" + c.task().name() +
                                "': " + known + " (empty: the mean return)");
  }

  const auto& st = c.stop();
  const Section s = root.nest("stop", st);
  s.check(st.max_seconds() >= 0, "max_seconds", "expected >= 0 (0 = no limit), got " + num(st.max_seconds()));
  s.check(st.max_env_steps() >= 0, "max_env_steps", "expected >= 0 (0 = no limit)");
  s.check(st.max_updates() >= 0, "max_updates", "expected >= 0 (0 = no limit)");
  if (st.eval_goal_size() > 0) {
    // The task name is checked where a task is built (robots/task.cpp's registry); an unknown one
    // has no metrics to name.
    std::vector<std::string> metrics;
    try {
      metrics = tasks.metric_names(c.task());
    } catch (const std::invalid_argument& e) {
      s.fail("eval_goal", std::string("a goal names one of the task's metrics: ") + e.what(), 0);
    }
    std::string known;
    for (const auto& m : metrics) known += (known.empty() ? "" : ", ") + m;
    for (int i = 0; i < st.eval_goal_size(); ++i) {
      const auto& g = st.eval_goal(i);
      if (std::find(metrics.begin(), metrics.end(), g.metric()) == metrics.end())
        s.fail("eval_goal", "metric \"" + g.metric() + "\" is not one of task '" + c.task().name() + "': " + known, i);
      if (std::isnan(g.at_least()) && std::isnan(g.below()))
        s.fail("eval_goal", "metric \"" + g.metric() + "\": set at_least, below or both", i);
      if (std::isinf(g.at_least()) || std::isinf(g.below()))
        s.fail("eval_goal", "metric \"" + g.metric() + "\": bounds must be finite", i);
    }
  }

  const auto& w = c.worker();
  const Section ws = root.nest("worker", w);
  ws.check(w.envs_per_worker() > 0 && w.envs_per_worker() <= kMaxEnvsPerWorker, "envs_per_worker",
           "expected 1.." + std::to_string(kMaxEnvsPerWorker) + ", got " + num(w.envs_per_worker()));
  ws.check(w.steps_per_batch() > 0 && w.steps_per_batch() <= kMaxStepsPerBatch, "steps_per_batch",
           "expected 1.." + std::to_string(kMaxStepsPerBatch) + ", got " + num(w.steps_per_batch()));
  ws.positive("max_batches_per_version", w.max_batches_per_version());
  ws.check(w.nice() >= 0 && w.nice() <= 19, "nice",
           "expected 0..19 (a worker may lower its priority, not raise it), got " + num(w.nice()));
  ws.check(w.exploration_scale_min() > 0 && w.exploration_scale_min() <= w.exploration_scale_max() &&
               w.exploration_scale_max() <= 100,
           "exploration_scale_min",
           "expected 0 < exploration_scale_min <= exploration_scale_max <= 100, got " + num(w.exploration_scale_min()) +
               " and " + num(w.exploration_scale_max()));
  const bool scaled = w.exploration_scale_min() != 1 || w.exploration_scale_max() != 1;
  ws.check(!scaled || (c.algorithm() != "ppo" && c.algorithm() != "dqn"), "exploration_scale_min",
           "per-environment noise scales are for off-policy continuous actions; " + c.algorithm() +
               " needs the policy's own noise (keep exploration_scale_min and _max at 1)");

  root.check(!c.run_root().empty(), "run_root", "expected a directory path");
  root.positive("checkpoint_every_seconds", c.checkpoint_every_seconds());
  root.positive("torch_threads", c.torch_threads());
  root.positive("log_every_seconds", c.log_every_seconds());
  root.positive("worker_timeout_seconds", c.worker_timeout_seconds());
  root.positive("account_expiry_seconds", c.account_expiry_seconds());
  root.positive("ingest_queue_mib", c.ingest_queue_mib());
}

}  // namespace

config::ExperimentConfig parse_config_text(const std::string& text, const std::string& source,
                                           const std::string& folder, const TaskKnowledge& tasks) {
  config::ExperimentConfig cfg;
  pb::TextFormat::Parser parser;
  Collector errors(source);
  pb::TextFormat::ParseInfoTree tree;
  parser.RecordErrorsTo(&errors);
  parser.WriteLocationsTo(&tree);
  if (!parser.ParseFromString(text, &cfg)) {
    throw ConfigError(errors.first().empty() ? source + ": cannot parse config" : errors.first());
  }
  Validator v(source, &tree);
  // A task may name files by a path relative to the config file (or an absolute one): they are
  // read here, once, and travel in the config from then on.
  if (!folder.empty()) tasks.read_files(cfg.mutable_task(), folder, Section(v, cfg, "").nest("task", cfg.task()));
  validate(cfg, v, tasks);
  return cfg;
}

std::string resume_change(const config::ExperimentConfig& was, const config::ExperimentConfig& now) {
  if (was.algorithm() != now.algorithm())
    return "the checkpoint is of algorithm \"" + was.algorithm() + "\", this config's is \"" + now.algorithm() + "\"";
  // Rows carry their horizon, so n_step may change; a row of several rewards holds their discount.
  const auto rows = [](const std::string& sec, int n, double g0, double g1) -> std::string {
    if (n <= 1 || g0 == g1) return "";
    return "the checkpoint's replay rows sum up to " + num(n) + " rewards (" + sec + ".n_step) discounted with " + sec +
           ".gamma " + num(g0) + ", this config's gamma is " + num(g1) +
           ": the rows would mix two discounts (resume with gamma " + num(g0) + ", or start a new run)";
  };
  if (now.algorithm() == "sac") return rows("sac", was.sac().n_step(), was.sac().gamma(), now.sac().gamma());
  if (now.algorithm() == "dqn") return rows("dqn", was.dqn().n_step(), was.dqn().gamma(), now.dqn().gamma());
  if (now.algorithm() == "td3") return rows("td3", was.td3().n_step(), was.td3().gamma(), now.td3().gamma());
  if (now.algorithm() == "fastsac")
    return rows("fastsac", was.fastsac().n_step(), was.fastsac().gamma(), now.fastsac().gamma());
  return "";
}

void check_config(const config::SacConfig& c) { check_in_code(c, "sac", check_sac); }
void check_config(const config::DqnConfig& c) { check_in_code(c, "dqn", check_dqn); }
void check_config(const config::PpoConfig& c) { check_in_code(c, "ppo", check_ppo); }
void check_config(const config::Td3Config& c) { check_in_code(c, "td3", check_td3); }
void check_config(const config::FastSacConfig& c) { check_in_code(c, "fastsac", check_fastsac); }

}  // namespace farm
