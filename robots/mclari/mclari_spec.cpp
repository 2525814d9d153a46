#include "mclari/mclari_spec.h"

#include "config_validator.h"

#include <cmath>
#include <string>
#include <utility>

#include "task_spec.h"

namespace farm {

namespace {

namespace pb = google::protobuf;
using namespace config_checks;

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

}  // namespace

void check_config(const config::MclariConfig& c) { check_in_code(c, "task.mclari", check_mclari); }

namespace robots::mclari {

TaskSpec mclari_spec(const config::TaskConfig& cfg) {
  const auto& m = cfg.mclari();
  TaskSpec s;
  s.name = "mclari";
  // Power, speed, x and y error to the target; with observe_gait and observe_terrain, those too.
  s.obs_dim = 4 + (m.observe_gait() ? 2 : 0) + (m.observe_terrain() ? 3 : 0);
  s.act_dim = 2;
  s.max_episode_steps = m.max_episode_steps();
  s.metric_names = {"efficiency", "fell", "reached", "terrain", "mean_frequency", "final_distance", "share"};
  return s;
}

void check_mclari(const config_checks::Section& task, const config::TaskConfig& t) {
  farm::check_mclari(task.nest("mclari", t.mclari()), t.mclari());
}

}  // namespace robots::mclari

}  // namespace farm
