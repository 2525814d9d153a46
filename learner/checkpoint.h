// Checkpoints: networks and optimizers (Sac::save), the replay buffer, and a Protobuf manifest
// with counters and per-worker sequence accounting. Written to a fresh folder and swapped in
// with renames, so a crash mid-write never leaves a half checkpoint behind.
#pragma once

#include <string>

#include "farm_config.pb.h"
#include "ingest.h"
#include "off_policy.h"
#include "replay_buffer.h"
#include "sac.h"

namespace farm {

void save_checkpoint(const std::string& dir, const config::CheckpointManifest& manifest, const Sac& sac,
                     const ReplayBuffer& replay);
bool checkpoint_exists(const std::string& dir);
// Throws std::runtime_error naming the file and what did not match.
config::CheckpointManifest load_checkpoint(const std::string& dir, const std::string& experiment_id, Sac& sac,
                                           ReplayBuffer& replay);

// The same for any off-policy algorithm; its networks go to the sub-folder named algo.name().
void save_checkpoint(const std::string& dir, const config::CheckpointManifest& manifest,
                     const OffPolicy& algo, const ReplayBuffer& replay);
config::CheckpointManifest load_checkpoint(const std::string& dir, const std::string& experiment_id,
                                           OffPolicy& algo, ReplayBuffer& replay);

void accounts_to_manifest(const Ingest& ingest, config::CheckpointManifest& m);
void accounts_from_manifest(const config::CheckpointManifest& m, Ingest& ingest);

}  // namespace farm
