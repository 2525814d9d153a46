// Ingest's accounts in a checkpoint's manifest: each stream's sequence accounting, open or
// retired, and the run's batch counters, so that a resumed learner counts what was sent while it
// was away as lost, and nothing it already took as lost again.
#pragma once

#include "farm_config.pb.h"
#include "ingest.h"

namespace farm {

void accounts_to_manifest(const Ingest& ingest, config::CheckpointManifest& m);
// Restores them into `ingest`, every open stream as seen at `now` (the ingest clock of this
// process, common/meter.h's now_seconds), so none is retired as idle for the time the learner was
// away.
void accounts_from_manifest(const config::CheckpointManifest& m, Ingest& ingest, double now);

}  // namespace farm
