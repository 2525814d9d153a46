#include "mclari/mclari_task.h"

#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>

#include "check.h"
#include "config.h"
#include "embedded_mjcf.h"
#include "mclari/mclari_spec.h"
#include "mclari/phase_groups.h"
#include "mclari/terrain.h"

namespace farm::robots {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr char kXml[] = "mclari/mclari.xml";
// g mm^2 / s^3 (MMGS power) in W.
constexpr double kPowerToWatt = 1e-9;

// The counts the loader bounds the config's lists and indices with (common/config.h).
static_assert(mclari::kNumGroups == kMclariPhaseGroups);
static_assert(mclari::kNumTerrains == kMclariTerrains);

void replace_all(std::string& s, const std::string& from, const std::string& to) {
  for (size_t p = s.find(from); p != std::string::npos; p = s.find(from, p + to.size())) s.replace(p, from.size(), to);
}

struct VfsDeleter {
  void operator()(mjVFS* v) const {
    mj_deleteVFS(v);
    delete v;
  }
};

// The embedded MJCF with the config's height-field resolution and ground size filled in.
mjModel* load_model(const config::MclariConfig& cfg) {
  std::string text;
  for (const auto& f : embedded_mjcf())
    if (std::strcmp(f.path, kXml) == 0) text = f.text;
  if (text.empty()) throw std::runtime_error(std::string("MJCF '") + kXml + "' is not embedded");
  replace_all(text, "HFIELD_N", std::to_string(cfg.hfield_size()));
  char half[64];
  std::snprintf(half, sizeof half, "%.17g", cfg.ground_half_size());
  replace_all(text, "GROUND_HALF", half);

  std::unique_ptr<mjVFS, VfsDeleter> vfs(new mjVFS);
  mj_defaultVFS(vfs.get());
  const char* name = "mclari.xml";
  if (mj_makeEmptyFileVFS(vfs.get(), name, int(text.size())) != 0)
    throw std::runtime_error(std::string(kXml) + ": could not add it to MuJoCo's VFS");
  std::memcpy(vfs->filedata[mj_findFileVFS(vfs.get(), name)], text.data(), text.size());
  char err[1000] = "";
  mjModel* m = mj_loadXML(name, vfs.get(), err, sizeof err);
  if (!m) throw std::runtime_error(std::string(kXml) + ": " + (err[0] ? err : "load failed"));
  return m;
}

int id_of(const mjModel* m, int type, const char* name) {
  const int id = mj_name2id(m, type, name);
  if (id < 0) throw std::runtime_error(std::string(kXml) + ": no '" + name + "'");
  return id;
}

McLariState& as_state(TaskState& s) { return static_cast<McLariState&>(s); }
const McLariState& as_state(const TaskState& s) { return static_cast<const McLariState&>(s); }

bool finite_state(const mjModel* m, const mjData* d) {
  for (int i = 0; i < m->nq; ++i)
    if (!std::isfinite(d->qpos[i])) return false;
  for (int i = 0; i < m->nv; ++i)
    if (!std::isfinite(d->qvel[i])) return false;
  return true;
}

}  // namespace

McLariState::~McLariState() {
  if (model) mj_deleteModel(model);
}

McLariTask::McLariTask(const config::MclariConfig& cfg) : cfg_(cfg) {
  // The loader has checked a config read from a file; this one may have been built in code.
  check_config(cfg);
  farm::require(mclari::reduced_groups().size() == size_t(kMclariReducedGroups),
                "mclari: the reduced group set has " + std::to_string(mclari::reduced_groups().size()) +
                    " groups, the config's ranges expect " + std::to_string(kMclariReducedGroups));

  if (cfg.groups_size() > 0) {
    groups_.assign(cfg.groups().begin(), cfg.groups().end());
  } else if (cfg.reduced_groups()) {
    groups_ = mclari::reduced_groups();
  } else {
    for (int g = 0; g < mclari::kNumGroups; ++g) groups_.push_back(g);
  }
  frequencies_.assign(cfg.frequencies().begin(), cfg.frequencies().end());
  terrains_.assign(cfg.terrains().begin(), cfg.terrains().end());
  if (terrains_.empty())
    for (int t = 0; t < mclari::kNumTerrains; ++t) terrains_.push_back(t);
  for (int t : terrains_)
    if (std::find(eval_terrains_.begin(), eval_terrains_.end(), t) == eval_terrains_.end()) eval_terrains_.push_back(t);

  hfield_ = mclari::rough_height_field(cfg.hfield_size(), cfg.hfield_sigma(), cfg.hfield_filter(), cfg.hfield_seed());
  if (cfg.has_hfield_png()) mclari::write_height_png(cfg.hfield_png(), hfield_, cfg.hfield_size());

  mjModel* base = load_model(cfg);
  try {
    if (base->nu != 8 || base->nhfield != 1 || base->ntendon != 2)
      throw std::runtime_error(std::string(kXml) + ": expected 8 motors, 1 height field, 2 tendons");
    body_ = id_of(base, mjOBJ_BODY, "body");
    for (int k = 0; k < 8; ++k) act_dof_[k] = base->jnt_dofadr[base->actuator_trnid[2 * k]];
    std::copy(hfield_.begin(), hfield_.end(), base->hfield_data);
    base->hfield_size[2] = cfg.hfield_height();
    mass_g_ = base->body_subtreemass[body_];
    const int plane = id_of(base, mjOBJ_GEOM, "plane"), rough = id_of(base, mjOBJ_GEOM, "rough");
    const double friction[3][3] = {
        {cfg.friction_normal_sliding(), cfg.friction_normal_torsional(), cfg.friction_normal_rolling()},
        {cfg.friction_wet_sliding(), cfg.friction_wet_torsional(), cfg.friction_wet_rolling()},
        {cfg.friction_dry_sliding(), cfg.friction_dry_torsional(), cfg.friction_dry_rolling()}};
    for (int t = 0; t < mclari::kNumTerrains; ++t) {
      mjModel* m = mj_copyModel(nullptr, base);
      terrain_models_.push_back(m);
      const double* fr = friction[mclari::terrain_slipperiness(t)];
      for (int g : {plane, rough})
        for (int i = 0; i < 3; ++i) m->geom_friction[3 * g + i] = fr[i];
      if (!mclari::terrain_is_rough(t)) {
        m->geom_contype[rough] = 0;
        m->geom_conaffinity[rough] = 0;
        m->geom_rgba[4 * rough + 3] = 0;
      }
    }
  } catch (...) {
    mj_deleteModel(base);
    for (auto* m : terrain_models_) mj_deleteModel(m);
    throw;
  }
  mj_deleteModel(base);

  spec_.name = "mclari";
  spec_.obs_dim = 4 + (cfg.observe_gait() ? 2 : 0) + (cfg.observe_terrain() ? 3 : 0);
  spec_.act_dim = 2;
  spec_.max_episode_steps = cfg.max_episode_steps();
  spec_.metric_names = {"efficiency", "fell", "reached", "terrain", "mean_frequency", "final_distance", "share"};
}

McLariTask::~McLariTask() {
  for (auto* m : terrain_models_) mj_deleteModel(m);
}

const mjModel* McLariTask::model_of(const TaskState& s) const { return static_cast<const McLariState&>(s).model; }

std::unique_ptr<TaskState> McLariTask::make_state() const {
  auto s = std::make_unique<McLariState>();
  s->model = mj_copyModel(nullptr, terrain_models_[0]);
  s->data = mj_makeData(s->model);
  if (!s->model || !s->data) throw std::runtime_error("mclari: could not allocate model/data");
  return s;
}

double McLariTask::ground_height(double x, double y, int terrain) const {
  if (!mclari::terrain_is_rough(terrain)) return 0.0;
  const int n = cfg_.hfield_size();
  const double half = cfg_.ground_half_size();
  // MuJoCo lays row 0 at -y and column 0 at -x.
  const int c = std::clamp(int(std::lround((x + half) / (2 * half) * (n - 1))), 0, n - 1);
  const int r = std::clamp(int(std::lround((y + half) / (2 * half) * (n - 1))), 0, n - 1);
  return hfield_[size_t(r) * n + c] * cfg_.hfield_height();
}

void McLariTask::reset(TaskState& s, uint64_t seed, float* obs) const {
  std::mt19937_64 rng(seed);
  const int terrain = terrains_[std::uniform_int_distribution<size_t>(0, terrains_.size() - 1)(rng)];
  reset_on(s, rng(), terrain, obs);
}

void McLariTask::reset_in_condition(TaskState& s, uint64_t seed, int condition, float* obs) const {
  reset_on(s, seed, eval_terrains_.at(size_t(condition) % eval_terrains_.size()), obs);
}

void McLariTask::reset_on(TaskState& base, uint64_t seed, int terrain, float* obs) const {
  McLariState& s = as_state(base);
  s.rng.seed(seed);
  s.terrain = terrain;
  mj_copyModel(s.model, terrain_models_.at(terrain));
  mjModel* m = s.model;
  mjData* d = s.data;
  mj_resetData(m, d);
  // Start with the feet just above the highest ground under the robot.
  double top = 0;
  for (double x = -12; x <= 12; x += 2)
    for (double y = -12; y <= 12; y += 2) top = std::max(top, ground_height(x, y, terrain));
  d->qpos[2] += top;
  mj_forward(m, d);

  std::uniform_real_distribution<double> angle(-kPi, kPi);
  std::uniform_real_distribution<double> dist(cfg_.target_min_distance(), cfg_.target_max_distance());
  const double a = angle(s.rng), r = dist(s.rng);
  const auto c = com(s);
  s.target[0] = c[0] + r * std::cos(a);
  s.target[1] = c[1] + r * std::sin(a);
  s.frequency = cfg_.initial_frequency();
  s.group_index = cfg_.initial_group();
  s.phase = 0;
  s.last = McLariStepFigures{};
  s.step = 0;
  s.episode_return = 0;
  s.efficiency_sum = s.frequency_sum = 0;
  s.measured_steps = 0;
  s.fell = s.reached = false;
  write_obs(s, obs);
}

std::array<double, 3> McLariTask::com(const TaskState& s) {
  const double* c = s.data->subtree_com + 3 * 1;  // body 1 is the robot's root
  return {c[0], c[1], c[2]};
}

void McLariTask::write_obs(const McLariState& s, float* obs) const {
  const auto c = com(s);
  obs[0] = float(s.last.power / cfg_.obs_power_scale());
  obs[1] = float(s.last.speed_mm_s / cfg_.obs_speed_scale());
  obs[2] = float((s.target[0] - c[0]) / cfg_.obs_distance_scale());
  obs[3] = float((s.target[1] - c[1]) / cfg_.obs_distance_scale());
  int k = 4;
  if (cfg_.observe_gait()) {
    obs[k++] = float(double(s.frequency) / cfg_.max_frequency());
    obs[k++] = groups_.size() > 1 ? float(double(s.group_index) / double(groups_.size() - 1)) : 0.f;
  }
  if (cfg_.observe_terrain()) {
    const int slip = mclari::terrain_slipperiness(s.terrain);
    obs[k++] = mclari::terrain_is_rough(s.terrain) ? 1.f : 0.f;
    obs[k++] = slip == 1 ? 1.f : 0.f;
    obs[k++] = slip == 2 ? 1.f : 0.f;
  }
}

int McLariTask::next_frequency(int f, float a0, double df, int fmin, int fmax) {
  const double a = std::isfinite(a0) ? std::clamp(double(a0), -1.0, 1.0) : 0.0;
  const long next = std::lround(f + a * df);
  return int(std::clamp<long>(next, fmin, fmax));
}

int McLariTask::group_index_from_action(float a1, int n) {
  const double a = std::isfinite(a1) ? std::clamp(double(a1), -1.0, 1.0) : 0.0;
  return std::clamp(int(std::floor((a + 1.0) * 0.5 * n)), 0, n - 1);
}

double McLariTask::efficiency(double mass_g, double g_si, double speed_mm_s, double power_w) {
  if (!(power_w > 0)) return 0.0;
  return (mass_g * 1e-3) * g_si * (speed_mm_s * 1e-3) / power_w;
}

double McLariTask::mean_abs_power_w(const double* torque, const double* omega, int samples) {
  if (samples <= 0) return 0.0;
  double sum = 0;
  for (int k = 0; k < samples; ++k) sum += std::abs(torque[k] * omega[k]);
  return sum / samples * kPowerToWatt;
}

void McLariTask::apply_tendon_springs(const mjModel* m, mjData* d) const {
  mju_zero(d->qfrc_applied, m->nv);
  for (int t = 0; t < m->ntendon; ++t) {
    const double gap = cfg_.tendon_rest_length() - d->ten_length[t];
    if (gap <= 0) continue;
    // Pushes towards a longer tendon: generalized force = J^T F (J is dense or sparse by model size).
    const double force = cfg_.tendon_stiffness() * gap;
    if (mj_isSparse(m)) {
      const int adr = d->ten_J_rowadr[t];
      for (int i = 0; i < d->ten_J_rownnz[t]; ++i)
        d->qfrc_applied[d->ten_J_colind[adr + i]] += d->ten_J[adr + i] * force;
    } else {
      mju_addToScl(d->qfrc_applied, d->ten_J + size_t(t) * m->nv, force, m->nv);
    }
  }
}

StepResult McLariTask::step(TaskState& base, const float* action, float* obs) const {
  McLariState& s = as_state(base);
  mjModel* m = s.model;
  mjData* d = s.data;
  int group;
  if (cfg_.fixed_frequency() > 0) {
    s.frequency = cfg_.fixed_frequency();
    group = cfg_.fixed_group();
  } else {
    s.frequency = frequencies_.empty() ? next_frequency(s.frequency, action[0], cfg_.frequency_step(),
                                                        cfg_.min_frequency(), cfg_.max_frequency())
                                       : frequencies_[group_index_from_action(action[0], int(frequencies_.size()))];
    s.group_index = group_index_from_action(action[1], int(groups_.size()));
    group = groups_[s.group_index];
  }
  const double f = s.frequency;
  double dt = 1.0 / (cfg_.steps_per_period() * f);
  if (cfg_.max_timestep() > 0) dt = std::min(dt, cfg_.max_timestep());
  m->opt.timestep = dt;
  const int n = std::max(1, int(std::lround(cfg_.step_seconds() / dt)));
  const int sample_every = std::max(1, int(std::lround(cfg_.power_sample_seconds() / dt)));
  const auto ph = mclari::group_phases(group);
  const double leg_phase[4] = {0.0, ph[0], ph[1], ph[2]};
  const double v = cfg_.voltage(), intra = cfg_.intra_leg_phase(), dphase = 2 * kPi * f * dt;

  const auto c0 = com(s);
  double abs_power[8] = {};
  int samples = 0;
  const int warnings0 = d->warning[mjWARN_BADQACC].number;
  bool unstable = false;
  for (int k = 0; k < n; ++k) {
    for (int leg = 0; leg < 4; ++leg) {
      d->ctrl[2 * leg] = v * std::sin(s.phase + leg_phase[leg]);
      d->ctrl[2 * leg + 1] = v * std::sin(s.phase + leg_phase[leg] + intra);
    }
    apply_tendon_springs(m, d);
    mj_step(m, d);
    s.phase = std::fmod(s.phase + dphase, 2 * kPi);
    if (s.after_physics_step) s.after_physics_step();
    // actuator_force and actuator_velocity come from the same state (the one this step began at).
    if ((k + 1) % sample_every == 0) {
      for (int a = 0; a < 8; ++a) abs_power[a] += std::abs(d->actuator_force[a] * d->actuator_velocity[a]);
      ++samples;
    }
    if (d->warning[mjWARN_BADQACC].number != warnings0 || !finite_state(m, d)) {
      unstable = true;
      break;
    }
  }
  const auto c1 = com(s);

  McLariStepFigures& fig = s.last;
  fig = McLariStepFigures{};
  fig.frequency = s.frequency;
  fig.group = group;
  fig.physics_steps = n;
  fig.power_samples = samples;
  fig.unstable = unstable;
  for (int a = 0; a < 8; ++a) {
    fig.mean_abs_power[a] = samples > 0 ? abs_power[a] / samples * kPowerToWatt : 0.0;
    fig.power += fig.mean_abs_power[a];
  }
  const double elapsed = unstable ? cfg_.step_seconds() : n * dt;
  fig.speed_mm_s = unstable ? 0.0 : std::hypot(c1[0] - c0[0], c1[1] - c0[1]) / elapsed;
  fig.efficiency = efficiency(mass_g_, cfg_.gravity_si(), fig.speed_mm_s, fig.power);

  // Fall: tilted over, body down on the ground, a diverged simulation; leaving the ground: off
  // the edge of the 1 m x 1 m ground or up in the air.
  const double* x = d->xpos + 3 * body_;
  const double up_z = d->xmat[9 * body_ + 8];
  const double ground = ground_height(x[0], x[1], s.terrain);
  const double edge = cfg_.ground_half_size() - 10.0;
  const bool fell = unstable || !(up_z >= cfg_.fall_min_up()) || x[2] - ground < cfg_.fall_min_body_height() ||
                    x[2] - ground > cfg_.leave_max_height() || std::abs(x[0]) > edge || std::abs(x[1]) > edge;
  StepResult r;
  s.step += 1;
  if (fell) {
    r.reward = float(-cfg_.fall_penalty());
    r.terminated = true;
    s.fell = true;
    if (unstable) mj_resetData(m, d);  // keep NaN out of the observation
  } else {
    double reward = fig.efficiency;
    if (cfg_.reference_efficiency_size() > 0) reward /= cfg_.reference_efficiency(s.terrain);
    s.efficiency_sum += fig.efficiency;
    s.frequency_sum += f;
    s.measured_steps += 1;
    if (std::hypot(s.target[0] - c1[0], s.target[1] - c1[1]) <= cfg_.target_radius()) {
      reward += cfg_.target_reward();
      r.terminated = true;
      s.reached = true;
    }
    r.reward = float(reward);
  }
  s.episode_return += r.reward;
  r.truncated = !r.terminated && s.step >= cfg_.max_episode_steps();
  write_obs(s, obs);
  return r;
}

void McLariTask::episode_metrics(const TaskState& base, float* out) const {
  const McLariState& s = as_state(base);
  const auto c = com(s);
  out[0] = s.measured_steps > 0 ? float(s.efficiency_sum / s.measured_steps) : 0.f;
  out[1] = s.fell ? 1.f : 0.f;
  out[2] = s.reached ? 1.f : 0.f;
  out[3] = float(s.terrain);
  out[4] = s.measured_steps > 0 ? float(s.frequency_sum / s.measured_steps) : 0.f;
  out[5] = float(std::hypot(s.target[0] - c[0], s.target[1] - c[1]));
  const auto& goal = cfg_.goal_efficiency_size() > 0 ? cfg_.goal_efficiency() : cfg_.reference_efficiency();
  out[6] = s.fell ? 0.f : goal.empty() ? out[0] : float(out[0] / goal.Get(s.terrain));
}

std::unique_ptr<Task> mclari::make_mclari_task(const config::TaskConfig& cfg) {
  return std::make_unique<McLariTask>(cfg.mclari());
}

void McLariTask::view(const TaskState& base, const mjData*, int, TaskView& out) const {
  const auto& s = static_cast<const McLariState&>(base);
  out.elevation = -35;
  ViewMarker target;
  const double z = ground_height(s.target[0], s.target[1], s.terrain);
  target.pos[0] = s.target[0];
  target.pos[1] = s.target[1];
  target.pos[2] = z + 0.1;
  target.radius = cfg_.target_radius();
  target.half_height = 0.1;
  out.markers.push_back(target);
  out.rows.push_back({"terrain", mclari::terrain_name(s.terrain)});
  out.rows.push_back({"gait", s.last.frequency == 0
                                  ? std::string("-")  // before the first step
                                  : std::to_string(s.last.frequency) + " Hz, " + mclari::group_name(s.last.group)});
}

}  // namespace farm::robots
