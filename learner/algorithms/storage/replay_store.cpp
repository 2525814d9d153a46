#include "replay_store.h"

#include <filesystem>

#include "rng_state.h"

namespace farm {

namespace {
std::string replay_file(const std::string& dir) { return (std::filesystem::path(dir) / "replay.pt").string(); }
}  // namespace

ReplayStore::ReplayStore(int64_t capacity, int obs_dim, int act_dim, double gamma, int n_step, uint64_t seed,
                         std::optional<torch::Device> device)
    : host_(capacity, obs_dim, act_dim), rng_(seed * 7919 + 17), gamma_(gamma), n_step_(n_step) {
  if (device) device_ = std::make_unique<DeviceReplay>(capacity, obs_dim, act_dim, *device, gamma);
}

void ReplayStore::insert(const Batch& b) {
  Transitions& rows = *b.rows;
  if (rows.n == 0) return;
  fold_n_step(b.num_steps, b.num_envs, b.truncated, rows, gamma_, n_step_);
  host_.add_n(rows.n, rows.obs.data(), rows.actions.data(), rows.rewards.data(), rows.terminated.data(),
              rows.next_obs.data(), rows.horizon.data());
  if (device_)
    device_->add_n(rows.n, rows.obs.data(), rows.actions.data(), rows.rewards.data(), rows.terminated.data(),
                   rows.next_obs.data(), rows.horizon.data());
}

void ReplayStore::save(const std::string& dir) const { host_.save(replay_file(dir)); }

void ReplayStore::load(const std::string& dir) {
  host_.load(replay_file(dir));
  if (device_) device_->load_from(host_);
}

bool ReplayStore::has_saved(const std::string& dir) { return std::filesystem::exists(replay_file(dir)); }

void ReplayStore::to_manifest(config::CheckpointManifest& m) const { rng_to_manifest(&rng_, m); }

void ReplayStore::from_manifest(const config::CheckpointManifest& m) { rng_from_manifest(m, &rng_); }

}  // namespace farm
