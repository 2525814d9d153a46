#include "config.h"
#include "config_validator.h"
#include "task_spec.h"
#include "terms/mjcf_bundle.h"
#include "terms/terms_check.h"

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

// sac.max_step_scale at most: a batch 64 times the seed's 256 is past what helps on any host here.
constexpr int kMaxSacStepScale = 64;

// Task sections: the ranges their tasks (robots/) can run with.

void check_pendulum(const Section& s, const config::PendulumConfig& p) {
  for (auto [f, x] : {std::pair<const char*, double>{"gravity", p.gravity()},
                      {"mass", p.mass()},
                      {"length", p.length()},
                      {"dt", p.dt()},
                      {"max_speed", p.max_speed()},
                      {"max_torque", p.max_torque()}})
    s.finite_positive(f, x);
  s.finite_non_negative("velocity_cost", p.velocity_cost());
  s.finite_non_negative("torque_cost", p.torque_cost());
  s.finite_non_negative("init_max_speed", p.init_max_speed());
  s.positive("max_episode_steps", p.max_episode_steps());
}

void check_cartpole(const Section& s, const config::CartpoleConfig& c) {
  s.finite_positive("physics_dt", c.physics_dt());
  s.finite_positive("max_force", c.max_force());
  s.finite_positive("gear", c.gear());
  s.finite_positive("rail_limit", c.rail_limit());
  s.positive("control_substeps", c.control_substeps());
  s.positive("max_episode_steps", c.max_episode_steps());
  s.non_negative("init_noise", c.init_noise());
}

// The arena and its obstacle map (robots/mobile/obstacle_map.h). Whether the robot fits the arena
// depends on its model too: MapGenerator checks that.
void check_scene(const Section& s, const config::MobileSceneConfig& c) {
  s.check(c.lidar_rays() >= 1 && c.lidar_rays() <= 1024, "lidar_rays",
          "expected in [1, 1024], got " + num(c.lidar_rays()));
  s.positive("lidar_range", c.lidar_range());
  s.check(c.lidar_fov_deg() > 0 && c.lidar_fov_deg() <= 360, "lidar_fov_deg",
          "expected in (0, 360], got " + num(c.lidar_fov_deg()));
  s.positive("arena_half_size", c.arena_half_size());
  s.positive("wall_height", c.wall_height());
  s.non_negative("min_obstacles", c.min_obstacles());
  s.check(c.max_obstacles() >= c.min_obstacles(), "max_obstacles",
          "expected >= min_obstacles (" + num(c.min_obstacles()) + "), got " + num(c.max_obstacles()));
  // One MuJoCo body per obstacle slot.
  s.check(c.max_obstacles() <= 256, "max_obstacles", "expected <= 256, got " + num(c.max_obstacles()));
  s.positive("obstacle_min_half_size", c.obstacle_min_half_size());
  s.check(c.obstacle_max_half_size() >= c.obstacle_min_half_size(), "obstacle_max_half_size",
          "expected >= obstacle_min_half_size (" + num(c.obstacle_min_half_size()) + "), got " +
              num(c.obstacle_max_half_size()));
  s.check(c.obstacle_max_half_size() < c.arena_half_size(), "obstacle_max_half_size",
          "expected < arena_half_size (" + num(c.arena_half_size()) + "), got " + num(c.obstacle_max_half_size()));
  s.non_negative("clearance", c.clearance());
  s.non_negative("min_start_goal_distance", c.min_start_goal_distance());
  s.positive("goal_radius", c.goal_radius());
  s.positive("max_episode_steps", c.max_episode_steps());
  s.check(c.physics_dt() > 0 && c.physics_dt() <= 0.05, "physics_dt",
          "expected in (0, 0.05], got " + num(c.physics_dt()));
  s.at_least("control_substeps", c.control_substeps(), 1);
  s.non_negative("distance_weight", c.distance_weight());
  s.check(c.collision_penalty() >= 0, "collision_penalty",
          "expected >= 0 (it is subtracted), got " + num(c.collision_penalty()));
  s.at_least("max_reset_tries", c.max_reset_tries(), 1);
}

// JetbotConfig and KayaConfig: the same fields around the same scene.
template <typename Robot>
void check_mobile(const Section& s, const Robot& r) {
  s.finite_positive("max_linear_speed", r.max_linear_speed());
  s.finite_positive("max_angular_speed", r.max_angular_speed());
  s.finite_positive("wheel_kv", r.wheel_kv());
  s.finite_positive("wheel_max_torque", r.wheel_max_torque());
  check_scene(s.nest("scene", r.scene()), r.scene());
}

// A1, Honey Badger and Silver Badger (robots/quadruped). The Badger defaults the task applies to
// unset fields (kp 40, kd 1) lie in these ranges too.
void check_legged(const Section& s, const config::LeggedConfig& c) {
  s.at_least("decimation", c.decimation(), 1);
  s.check(c.physics_dt() > 0 && c.physics_dt() <= 0.05, "physics_dt",
          "expected in (0, 0.05], got " + num(c.physics_dt()));
  s.positive("kp", c.kp());
  s.non_negative("kd", c.kd());
  s.positive("action_scale", c.action_scale());
  s.positive("action_range", c.action_range());
  s.at_least("max_episode_steps", c.max_episode_steps(), 1);
  s.check(c.command_resample_prob() >= 0 && c.command_resample_prob() <= 1, "command_resample_prob",
          "expected in [0, 1], got " + num(c.command_resample_prob()));
  s.non_negative("lin_vel_x_max", c.lin_vel_x_max());
  s.non_negative("lin_vel_y_max", c.lin_vel_y_max());
  s.non_negative("ang_vel_max", c.ang_vel_max());
  s.positive("tracking_sigma", c.tracking_sigma());
  s.in_unit("soft_dof_pos_limit", c.soft_dof_pos_limit());
  s.check(c.friction_min() > 0 && c.friction_min() <= c.friction_max(), "friction_min",
          "expected 0 < friction_min <= friction_max (" + num(c.friction_max()) + "), got " + num(c.friction_min()));
  s.check(
      c.init_joint_scale_min() <= c.init_joint_scale_max(), "init_joint_scale_min",
      "expected <= init_joint_scale_max (" + num(c.init_joint_scale_max()) + "), got " + num(c.init_joint_scale_min()));
  s.check(c.push_interval_s() >= 0, "push_interval_s", "expected >= 0 (0: no pushes), got " + num(c.push_interval_s()));
  s.non_negative("noise_level", c.noise_level());
  // Relative randomization ranges +-x around the model's value: the value keeps its sign.
  for (auto [f, x] : {std::pair<const char*, double>{"trunk_mass_rel", c.trunk_mass_rel()},
                      {"torque_limit_rel", c.torque_limit_rel()},
                      {"velocity_limit_rel", c.velocity_limit_rel()},
                      {"foot_size_rel", c.foot_size_rel()},
                      {"kp_rel", c.kp_rel()},
                      {"kd_rel", c.kd_rel()},
                      {"action_scale_rel", c.action_scale_rel()},
                      {"torque_multiplier_rel", c.torque_multiplier_rel()}})
    s.check(x >= 0 && x < 1, f, "expected in [0, 1), got " + num(x));
  s.positive("velocity_limit", c.velocity_limit());
  s.check(c.armature_max() >= 0.005, "armature_max",
          "expected >= 0.005 (the lower end of its range), got " + num(c.armature_max()));
}

// mCLARI (robots/mclari), its gaits and its terrains.
void check_mclari(const Section& s, const config::MclariConfig& c) {
  for (auto [f, x] : {std::pair<const char*, double>{"voltage", c.voltage()},
                      {"frequency_step", c.frequency_step()},
                      {"step_seconds", c.step_seconds()},
                      {"power_sample_seconds", c.power_sample_seconds()},
                      {"gravity_si", c.gravity_si()},
                      {"target_radius", c.target_radius()},
                      {"ground_half_size", c.ground_half_size()},
                      {"hfield_height", c.hfield_height()},
                      {"obs_power_scale", c.obs_power_scale()},
                      {"obs_speed_scale", c.obs_speed_scale()},
                      {"obs_distance_scale", c.obs_distance_scale()}})
    s.finite_positive(f, x);
  const int fmin = c.min_frequency(), fmax = c.max_frequency();
  const std::string frange = "[min_frequency, max_frequency] = [" + num(fmin) + ", " + num(fmax) + "]";
  s.at_least("min_frequency", fmin, 1);
  s.check(fmax >= fmin, "max_frequency", "expected >= min_frequency (" + num(fmin) + "), got " + num(fmax));
  s.check(c.initial_frequency() >= fmin && c.initial_frequency() <= fmax, "initial_frequency",
          "expected in " + frange + ", got " + num(c.initial_frequency()));
  s.at_least("steps_per_period", c.steps_per_period(), 1);
  s.check(c.max_timestep() >= 0 && std::isfinite(c.max_timestep()), "max_timestep",
          "expected >= 0 (0: no cap), got " + num(c.max_timestep()));
  s.at_least("max_episode_steps", c.max_episode_steps(), 1);
  s.non_negative("target_min_distance", c.target_min_distance());
  s.check(
      c.target_max_distance() >= c.target_min_distance(), "target_max_distance",
      "expected >= target_min_distance (" + num(c.target_min_distance()) + "), got " + num(c.target_max_distance()));
  s.check(c.target_max_distance() < c.ground_half_size(), "target_max_distance",
          "expected inside the ground, < ground_half_size (" + num(c.ground_half_size()) + "), got " +
              num(c.target_max_distance()));
  s.non_negative("tendon_rest_length", c.tendon_rest_length());
  s.non_negative("tendon_stiffness", c.tendon_stiffness());
  s.check(c.fixed_frequency() >= 0 && c.fixed_frequency() <= fmax, "fixed_frequency",
          "expected 0 (off) or in [1, max_frequency] = [1, " + num(fmax) + "], got " + num(c.fixed_frequency()));
  s.check(c.fixed_group() >= 0 && c.fixed_group() < kMclariPhaseGroups, "fixed_group",
          "expected in [0, " + num(kMclariPhaseGroups) + "), got " + num(c.fixed_group()));
  // Gaits the agent chooses from.
  if (c.groups_size() > 0 && c.reduced_groups()) s.fail("groups", "set groups or reduced_groups, not both");
  s.distinct_in_range("groups", c.groups(), 0, kMclariPhaseGroups - 1, "[0, " + num(kMclariPhaseGroups) + ")",
                      [](int g) { return "group " + num(g); });
  s.distinct_in_range("frequencies", c.frequencies(), fmin, fmax, frange, [](int f) { return num(f) + " Hz"; });
  const int groups = c.groups_size() > 0  ? c.groups_size()
                     : c.reduced_groups() ? kMclariReducedGroups
                                          : kMclariPhaseGroups;
  s.check(c.initial_group() >= 0 && c.initial_group() < groups, "initial_group",
          "expected an index into the " + num(groups) + " active groups, got " + num(c.initial_group()));
  // Terrains, their reward references and the rough ground's height field.
  // A terrain may be listed more than once: it is then drawn more often.
  for (int i = 0; i < c.terrains_size(); ++i)
    if (c.terrains(i) < 0 || c.terrains(i) >= kMclariTerrains)
      s.fail("terrains", "entries must be in [0, " + num(kMclariTerrains) + "), got " + num(c.terrains(i)), i);
  // One finite value > 0 per terrain, or none.
  const auto per_terrain = [&s](const char* field, const pb::RepeatedField<double>& values) {
    if (!values.empty() && values.size() != kMclariTerrains)
      s.fail(field, "expected one value per terrain (" + num(kMclariTerrains) + ") or none, got " + num(values.size()));
    for (int t = 0; t < values.size(); ++t)
      if (!(values.Get(t) > 0) || !std::isfinite(values.Get(t)))
        s.fail(field, "expected finite values > 0, got " + num(values.Get(t)) + " for terrain " + num(t), t);
  };
  per_terrain("reference_efficiency", c.reference_efficiency());
  per_terrain("goal_efficiency", c.goal_efficiency());
  s.at_least("hfield_size", c.hfield_size(), 2);
  s.positive("hfield_sigma", c.hfield_sigma());
  s.check(c.hfield_filter() >= 1 && c.hfield_filter() % 2 == 1, "hfield_filter",
          "expected odd and >= 1, got " + num(c.hfield_filter()));
}

// The section of the task that runs; the others are never read.
void check_task(const Section& s, const config::TaskConfig& t) {
  const std::string& n = t.name();
  if (n == "pendulum") check_pendulum(s.nest(n, t.pendulum()), t.pendulum());
  if (n == "cartpole") check_cartpole(s.nest(n, t.cartpole()), t.cartpole());
  if (n == "jetbot") check_mobile(s.nest(n, t.jetbot()), t.jetbot());
  if (n == "kaya") check_mobile(s.nest(n, t.kaya()), t.kaya());
  if (n == "mclari") check_mclari(s.nest(n, t.mclari()), t.mclari());
  if (n == "a1") check_legged(s.nest(n, t.a1()), t.a1());
  if (n == "honey_badger") check_legged(s.nest(n, t.honey_badger()), t.honey_badger());
  if (n == "silver_badger") check_legged(s.nest(n, t.silver_badger()), t.silver_badger());
  if (n == "terms") robots::terms::check_terms(s.nest(n, t.terms()), t.terms());
}

// Algorithm sections.

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
  s.layer_sizes("hidden", c.hidden());
  s.layer_sizes("critic_hidden", c.critic_hidden());
  s.positive("initial_alpha", c.initial_alpha());
  s.check(c.log_std_min() < c.log_std_max(), "log_std_min", "expected < sac.log_std_max");
  s.positive("max_updates_per_step", c.max_updates_per_step());
  s.positive("publish_every_updates", c.publish_every_updates());
  s.check(c.max_step_scale() >= 1 && c.max_step_scale() <= kMaxSacStepScale, "max_step_scale",
          "expected 1 to " + num(kMaxSacStepScale) + ", got " + num(c.max_step_scale()));
  s.at_least("n_step", c.n_step(), 1);
  s.check(valid_device_name(c.device()), "device",
          "expected \"cpu\", \"cuda\", \"cuda:N\" or \"auto\", got \"" + c.device() + "\"");
  s.check(c.activation() == "relu" || c.activation() == "tanh", "activation",
          "expected \"relu\" or \"tanh\", got \"" + c.activation() + "\"");
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
  s.positive("target_update_updates", c.target_update_updates());
  s.positive("max_grad_norm", c.max_grad_norm());
  s.layer_sizes("hidden", c.hidden());
  s.positive("max_updates_per_step", c.max_updates_per_step());
  s.positive("publish_every_updates", c.publish_every_updates());
  s.at_least("n_step", c.n_step(), 1);
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

void validate(const config::ExperimentConfig& c, Validator& v) {
  const Section root(v, c, "");
  if (!c.has_experiment_id() || c.experiment_id().empty())
    root.fail("experiment_id", "required: a name for the run, e.g. \"pendulum_sac\"");
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

  check_task(root.nest("task", c.task()), c.task());
  check_sac(root.nest("sac", c.sac()), c.sac());
  if (c.algorithm() == "dqn") check_dqn(root.nest("dqn", c.dqn()), c.dqn());
  if (c.algorithm() == "ppo") check_ppo(root.nest("ppo", c.ppo()), c.ppo());

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
      metrics = robots::task_spec(c.task()).metric_names;
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
      metrics = robots::task_spec(c.task()).metric_names;
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

  root.check(!c.run_root().empty(), "run_root", "expected a directory path");
  root.positive("checkpoint_every_seconds", c.checkpoint_every_seconds());
  root.positive("torch_threads", c.torch_threads());
  root.positive("log_every_seconds", c.log_every_seconds());
  root.positive("worker_timeout_seconds", c.worker_timeout_seconds());
}

// A section checked in code: no file, errors name the path alone.
template <typename Msg, typename Check>
void check_in_code(const Msg& msg, const std::string& path, Check check) {
  Validator v;
  check(Section(v, msg, path), msg);
}

}  // namespace

config::ExperimentConfig parse_config_text(const std::string& text, const std::string& source,
                                           const std::string& folder) {
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
  // A task of terms names its model by a path relative to the config file (or an absolute one): the
  // model's files are read here, once, and travel in the config from then on.
  const auto& given = cfg.task().terms();
  if (!folder.empty() && cfg.task().name() == "terms" && given.model_files_size() == 0 && !given.model().empty()) {
    auto* terms = cfg.mutable_task()->mutable_terms();
    const Section t = Section(v, cfg, "").nest("task", cfg.task()).nest("terms", cfg.task().terms());
    try {
      const std::string& model = terms->model();
      robots::terms::read_model_folder(model[0] == '/' ? model : folder + "/" + model, terms);
    } catch (const robots::terms::ModelError& e) {
      t.fail("model", e.what());
    }
  }
  validate(cfg, v);
  return cfg;
}

config::ExperimentConfig parse_config_text(const std::string& text, const std::string& source) {
  return parse_config_text(text, source, "");
}

void check_config(const config::PendulumConfig& c) { check_in_code(c, "task.pendulum", check_pendulum); }
void check_config(const config::CartpoleConfig& c) { check_in_code(c, "task.cartpole", check_cartpole); }
void check_config(const config::JetbotConfig& c) {
  check_in_code(c, "task.jetbot", check_mobile<config::JetbotConfig>);
}
void check_config(const config::KayaConfig& c) { check_in_code(c, "task.kaya", check_mobile<config::KayaConfig>); }
void check_config(const config::MclariConfig& c) { check_in_code(c, "task.mclari", check_mclari); }
void check_config(const config::LeggedConfig& c, const std::string& task) {
  check_in_code(c, "task." + task, check_legged);
}
void check_config(const config::SacConfig& c) { check_in_code(c, "sac", check_sac); }
void check_config(const config::DqnConfig& c) { check_in_code(c, "dqn", check_dqn); }
void check_config(const config::PpoConfig& c) { check_in_code(c, "ppo", check_ppo); }

}  // namespace farm
