// Checkpoints: networks and optimizers (Sac::save), the replay buffer, and a Protobuf manifest
// with counters and per-worker sequence accounting. Written to a fresh folder and swapped in
// with renames, so a crash mid-write never leaves a half checkpoint behind.
#pragma once

#include <functional>
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

// The networks alone, written by save_nets into DIR/name (DIR/<algo.name()>): the layout a
// checkpoint has, so a folder of networks and a manifest reads like a checkpoint.
void save_networks(const std::string& dir, const std::string& name,
                   const std::function<void(const std::string& folder)>& save_nets);
void save_networks(const std::string& dir, const OffPolicy& algo);

// The atomic write every checkpoint goes through: write_parts fills a fresh folder, the manifest is
// added, and the folder is renamed over DIR (the previous one is kept as DIR.old until then).
void write_checkpoint(const std::string& dir, const config::CheckpointManifest& manifest,
                      const std::function<void(const std::string& tmp_dir)>& write_parts);
// DIR, or DIR.old where a crash between the two renames of a save left only that.
std::string usable_checkpoint(const std::string& dir);
// The manifest of the usable checkpoint in DIR; throws std::runtime_error naming the file when it
// is missing, unreadable or of another experiment.
config::CheckpointManifest read_manifest(const std::string& dir, const std::string& experiment_id);
// A non-empty run directory is renamed RUN.<unix time>, never overwritten; returns the new name
// ("" when there was nothing to move).
std::string move_run_dir_aside(const std::string& run_dir);

void accounts_to_manifest(const Ingest& ingest, config::CheckpointManifest& m);
void accounts_from_manifest(const config::CheckpointManifest& m, Ingest& ingest);

}  // namespace farm
