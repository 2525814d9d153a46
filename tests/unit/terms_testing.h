// Helpers shared by the unit tests of the task of terms (test_terms*.cpp): the shipped configs' folder,
// a shipped config's task, the centre of mass as Gymnasium computes it, a varying action.
#pragma once

#include <google/protobuf/text_format.h>
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "config.h"
#include "task.h"
#include "task_specs.h"
#include "terms/terms_task.h"

namespace farm::robots::terms {

inline const std::string kConfigs = std::string(FARM_SOURCE_DIR) + "/deploy/configs";

// The HalfCheetah config's task reset with seed 7, with `extra_terms` (a TermsConfig's text) merged.
struct Cheetah {
  std::unique_ptr<TermsTask> task;
  std::unique_ptr<TaskState> state;
  std::vector<float> obs;
  explicit Cheetah(const std::string& extra_terms = "") {
    auto cfg = load_config_file(kConfigs + "/half_cheetah_sac.txtpb");
    if (!extra_terms.empty()) {
      config::TaskConfig more;
      EXPECT_TRUE(google::protobuf::TextFormat::ParseFromString(extra_terms, more.mutable_terms()));
      cfg.mutable_task()->mutable_terms()->MergeFrom(more.terms());
    }
    task = std::make_unique<TermsTask>(cfg.task().terms());
    state = task->make_state();
    obs.resize(task->spec().obs_dim);
    task->reset(*state, 7, obs.data());
  }
  TermsState& s() { return static_cast<TermsState&>(*state); }
};

// A shipped config's task of terms, with `extra` merged into its terms (repeated fields append).
struct Shipped {
  std::unique_ptr<TermsTask> task;
  std::unique_ptr<TaskState> state;
  std::vector<float> obs;
  explicit Shipped(const std::string& config, const std::string& extra = "", bool own_observations = false) {
    auto cfg = load_config_file(kConfigs + "/" + config);
    auto* terms = cfg.mutable_task()->mutable_terms();
    if (own_observations) terms->clear_observation();
    config::TermsConfig more;
    EXPECT_TRUE(google::protobuf::TextFormat::ParseFromString(extra, &more)) << extra;
    terms->MergeFrom(more);
    task = std::make_unique<TermsTask>(*terms);
    state = task->make_state();
    obs.resize(task->spec().obs_dim);
    task->reset(*state, 7, obs.data());
  }
  const mjModel* m() const { return task->model(); }
  const mjData* d() const { return state->data; }
  StepResult step(const std::vector<float>& a) { return task->step(*state, a.data(), obs.data()); }
};

// Gymnasium's mass_center: sum(body_mass * xipos) / sum(body_mass), over every body.
inline std::array<double, 3> mass_center_of(const mjModel* m, const mjData* d) {
  std::array<double, 3> c{};
  double mass = 0;
  for (int b = 0; b < m->nbody; ++b) {
    mass += m->body_mass[b];
    for (int k = 0; k < 3; ++k) c[k] += m->body_mass[b] * d->xipos[3 * b + k];
  }
  for (double& x : c) x /= mass;
  return c;
}

// An action that differs per entry and per step, nowhere 0.
inline std::vector<float> swing(int n, int t) {
  std::vector<float> a(n);
  for (int i = 0; i < n; ++i) a[i] = float(0.8 * std::sin(0.7 * t + 1.3 * i) + (i % 2 ? 0.15 : -0.15));
  return a;
}

// The largest |entry| of [qpos, qvel] from `skip` on.
inline double largest_state(const mjModel* m, const mjData* d, int skip) {
  double x = 0;
  for (int i = skip; i < m->nq + m->nv; ++i) x = std::max(x, std::abs(i < m->nq ? d->qpos[i] : d->qvel[i - m->nq]));
  return x;
}

}  // namespace farm::robots::terms
