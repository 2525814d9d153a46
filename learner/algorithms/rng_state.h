// The learner's random state in a checkpoint: the replay sampler's generator and LibTorch's CPU
// generator (network initialization, SAC's action noise on the CPU, PPO's mini-batch order), so
// that a resumed learner draws what the uninterrupted one would have drawn next.
#pragma once

#include <random>

#include "farm_config.pb.h"

namespace farm {

// sampler may be null (PPO has none).
void rng_to_manifest(const std::mt19937_64* sampler, config::CheckpointManifest& m);
// Restores what the manifest holds; a manifest without random state (written before it was
// recorded) leaves the generators as they are. Throws std::runtime_error on a malformed state.
void rng_from_manifest(const config::CheckpointManifest& m, std::mt19937_64* sampler);

}  // namespace farm
