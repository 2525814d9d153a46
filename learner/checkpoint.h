// Checkpoints: what the algorithm saves (networks, optimizers, a replay buffer) and a Protobuf
// manifest with counters and per-worker sequence accounting. Written to a fresh folder and swapped in
// with renames, so a crash mid-write never leaves a half checkpoint behind.
#pragma once

#include <functional>
#include <string>

#include "farm_config.pb.h"
#include "ingest_accounts.h"
#include "paths.h"  // remove_tree

namespace farm {

bool checkpoint_exists(const std::string& dir);

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

}  // namespace farm
