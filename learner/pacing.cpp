#include "pacing.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "divergence.h"
#include "registry.h"

namespace farm {

std::string fmt(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

std::string best_eval_line(const FarmFigures& f) {
  std::string label = "best eval " + f.best_measure;
  label.resize(std::max<size_t>(label.size() + 1, 18), ' ');  // the summary's value column
  return label + fmt(f.best_measure == "return" ? "%.1f" : "%.4f", f.best_eval);
}

Pacing::Pacing(std::unique_ptr<Algorithm> algo, const config::ExperimentConfig& cfg, const robots::TaskSpec& spec)
    : algo_(std::move(algo)), cfg_(cfg), spec_(spec) {}

double Pacing::latest(const std::string& name) const {
  const double v = last_.get(name);
  return std::isnan(v) ? 0.0 : v;
}

void Pacing::warm_up(Farm& farm) {
  if (const std::string did = algo_->warm_up(); !did.empty()) farm.log(did);
}

void Pacing::check(const std::vector<UpdateFigures>& figures) const {
  try {
    for (const UpdateFigures& u : figures) require_finite_update(algo_->name(), u.update, u.values);
  } catch (const std::runtime_error& e) {
    diverged_ = e.what();
    throw;
  }
  if (!figures.empty()) last_ = figures.back();
}

void Pacing::settle() const {
  if (!diverged_.empty()) throw std::runtime_error(diverged_);
  check(algo_->finish());
}

void Pacing::save_networks(const std::string& dir) const {
  settle();
  algo_->save_networks(dir);
}

PolicyParams Pacing::policy() const {
  settle();
  return algo_->policy(version());
}

void Pacing::save(const std::string& dir) const {
  settle();
  algo_->save(dir);
}

std::string Pacing::resumed(const config::CheckpointManifest& m, uint64_t env_steps) {
  version_ = m.policy_version() + 1 + kResumeVersionSkip;
  counts_from_manifest(m);
  // The algorithm learns the number its networks go out as, for the steps it stored.
  config::CheckpointManifest as_resumed = m;
  as_resumed.set_resumed_version(version_);
  const std::string own = algo_->from_manifest(as_resumed);  // after the algorithm's constructor seeded LibTorch
  return "(next policy v" + std::to_string(version_) + ", " + std::to_string(env_steps) + " env steps): " + own;
}

std::unique_ptr<Pacing> make_pacing(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  const AlgorithmRegistration& a = find_algorithm(cfg.algorithm());
  auto algo = a.make(cfg, spec);
  return a.on_policy ? make_round_pacing(std::move(algo), cfg, spec) : make_replay_pacing(std::move(algo), cfg, spec);
}

int next_step_scale(int current, double r, int most) {
  int cap = 1;  // the largest power of 2 at most `most`
  while (cap <= most / 2) cap *= 2;
  // The power of 2 nearest r on a log scale (s for r from s / sqrt(2) to s * sqrt(2)), within cap:
  // a floor would take x2 where r is 3-4, which leaves half of what a step of x4 would use.
  int fit = 1;
  while (fit < cap && 2.0 * fit <= M_SQRT2 * r) fit *= 2;
  current = std::clamp(current, 1, cap);
  if (fit > current) return fit;
  if (r < 0.8 * current / M_SQRT2) return fit;  // down only past a margin below the step's band
  return current;
}

}  // namespace farm
