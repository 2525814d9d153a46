// The term functions of the task of terms and how a config's entries bind to them. Each term is one
// function over the step's context; terms_catalogue.def registers it by name.
#pragma once

#include <vector>

#include "terms/terms_spec.h"
#include "terms/terms_task.h"

struct mjModel_;
struct mjData_;

namespace farm::robots::terms {

struct Ctx {
  const mjModel_* m;
  const mjData_* d;
  TermsState& s;
  const TermsTask& task;
};

struct ObsBinding;
struct RewardBinding;
struct TerminationBinding;
using ObsFn = void (*)(const Ctx&, const ObsBinding&, double* out);
using RewardFn = double (*)(const Ctx&, const RewardBinding&);
using TerminationFn = bool (*)(const Ctx&, const TerminationBinding&);

// A contact term's items (bodies, or geoms) as the geoms of each, and the geoms a contact must be
// with to count (empty: any geom not of the item).
struct ContactItems {
  std::vector<std::vector<int>> geoms;
  std::vector<int> other;
};

struct ObsBinding {
  const config::ObsTerm* cfg;
  ObsFn fn;
  std::vector<int> ids;  // joints, bodies, geoms or sensors selected by names (or geoms)
  int size = 0;
  ContactItems contacts;
};
struct RewardBinding {
  const config::RewardTerm* cfg;
  RewardFn fn;
  std::vector<int> ids;
  int slot = 0;  // index among the task's reward terms (its state slots)
  ContactItems contacts;
};
struct TerminationBinding {
  const config::TerminationTerm* cfg;
  TerminationFn fn;
  std::vector<int> ids;
  ContactItems contacts;
};

struct Bound {
  std::vector<int> targets;          // driven joints ("position") or actuators ("actuator")
  std::vector<int> target_dofs;      // "position": each joint's dof address
  std::vector<int> target_qpos;      // "position": each joint's qpos address
  std::vector<int> target_actuator;  // "position": the actuator driving each joint
  std::vector<ObsBinding> obs;
  std::vector<RewardBinding> rewards;
  std::vector<TerminationBinding> terminations;
  // What the step computes only for the terms that read it: MuJoCo's post-constraint quantities
  // (mj_rnePostConstraint after the physics steps: cfrc_ext, cacc, cfrc_int), and the model's
  // centre of mass before the physics steps (TermsState::com_before).
  bool rne_post_constraint = false;
  bool com_before = false;
};

// Binds the config's terms to the model: the functions by name, the names to ids. Throws
// std::invalid_argument for a name the library lacks.
void bind(const config::TermsConfig& cfg, const ModelInfo& info, const mjModel_* m, int root, Bound& out);

// Library helpers the terms share (public for tests). A body with a free joint (a floating robot's
// root) is read from qpos and qvel, the state after the step; other bodies from MuJoCo's kinematics
// of the step's last forward pass (xpos, xmat, cvel).
void body_rotation(const mjModel_* m, const mjData_* d, int body, double R[9]);  // body -> world, row-major
void body_velocity(const mjModel_* m, const mjData_* d, int body, bool local, double ang[3], double lin[3]);
double body_height(const mjModel_* m, const mjData_* d, int body);
void projected_gravity(const mjModel_* m, const mjData_* d, int body, double out[3]);
// Net contact force on a group of geoms (world frame, summed over the contacts of one of them with
// a geom outside the group, and in `other` where that is not empty).
void contact_force(const mjModel_* m, const mjData_* d, const std::vector<int>& geoms, const std::vector<int>& other,
                   double out[3]);
// True when a geom of the group touches a geom outside it (and in `other` where that is not empty).
bool touches(const mjData_* d, const std::vector<int>& geoms, const std::vector<int>& other);
// The model's centre of mass, Gymnasium's mass_center: the mass-weighted mean of every body's
// centre of mass (xipos), from the kinematics of the step's last forward pass.
void mass_center(const mjModel_* m, const mjData_* d, double out[3]);

}  // namespace farm::robots::terms
