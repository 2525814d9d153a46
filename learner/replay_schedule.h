// The replay pacing's decision for one pass of the learner's loop (replay_pacing.cpp), as a function
// of counts and clocks alone: how many updates to run now, whether to publish a new version after
// them, whether to ask an evaluation, and how long the runner may wait for data. It reads no
// algorithm, bus or clock and changes nothing; the pacing takes the snapshot and carries the
// decision out.
#pragma once

#include <algorithm>
#include <cstdint>

#include "samples_per_insert.h"

namespace farm {

// Where the run is at the start of a pass.
struct ReplaySnapshot {
  int64_t updates = 0;     // the algorithm's updates so far
  int64_t rows = 0;        // rows held in the replay buffer
  uint64_t env_steps = 0;  // env steps received
  int64_t ready = 0;       // updates the algorithm has the data for now
  int updates_since_publish = 0, batches_since_publish = 0;
  bool got_data = false;  // whether the runner took anything in this pass
  double since_eval = 0;  // seconds since the last evaluation was asked (or since the start)
};

struct ReplayDecision {
  int updates = 0;        // to run now, as one group
  bool publish = false;   // a new version after them
  bool evaluate = false;  // an evaluation asked after them
  double wait = 0;        // seconds the runner may wait for data
};

struct ReplaySchedule {
  SamplesPerInsert limiter;  // what the data received allows
  int group = 8;             // most updates a pass (one Algorithm::update group)
  int publish_every = 1;     // updates between published versions
  double eval_every = 0;     // seconds between evaluations

  // Updates: as many as the limiter allows, up to a group. Publishing: every publish_every updates,
  // and whenever no update runs but updates or batches came since the last version (starved: the
  // workers' throttle lets go with a new version, so neither side waits for the other). An
  // evaluation every eval_every seconds once an update has run. A pass with no update and no data
  // lets the runner wait 10 ms.
  ReplayDecision decide(const ReplaySnapshot& s) const {
    ReplayDecision d;
    d.updates = limiter.allowed(s.updates, s.rows, s.env_steps, int(std::min<int64_t>(s.ready, group)));
    const int since = s.updates_since_publish + d.updates;
    d.publish = since >= publish_every || (d.updates == 0 && (since > 0 || s.batches_since_publish > 0));
    d.evaluate = s.since_eval >= eval_every && s.updates + d.updates > 0;
    d.wait = d.updates == 0 && !s.got_data ? 0.01 : 0.0;
    return d;
  }
};

}  // namespace farm
