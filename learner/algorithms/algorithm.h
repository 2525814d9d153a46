// An algorithm as the learner runs it: it takes the workers' data, learns from it, and hands back
// the policy. Everything around that is the learner's (learner/farm_service.h): ingest, the pace
// of updates against the data (learner/pacing.h), publishing, evaluations, checkpoints, the log.
// SAC, DQN, PPO and TD3 implement this class; a new algorithm does too, and adds one line to registry.cpp.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "batch.h"
#include "farm_config.pb.h"
#include "mlp.h"

namespace farm {

// One finished update (a gradient step; PPO: a fit): its number and its figures, by name, in the
// order the log and the CSV take them. The learner stops the run on one that is not finite.
struct UpdateFigures {
  int64_t update = 0;
  std::vector<std::pair<std::string, double>> values;
  std::map<uint64_t, int64_t> steps_by_version;  // on-policy: the steps used, by the version that made them
  double get(const std::string& name) const;     // NaN when it has no such figure
};

// What an algorithm holds of the data, for the pacing.
struct Holding {
  int64_t rows = 0;              // rows (replay) or steps (rollout) held for updates
  int64_t capacity = 0;          // replay: its size; rollout: a fit's steps (0: by episodes)
  int64_t steps_wanted = -1;     // rollout: steps still to come for the next fit (-1: not by steps)
  int64_t episodes_wanted = -1;  // rollout: episodes still to end for it (-1: not by episodes)
  std::string run_done;          // the algorithm's own end ("run length 40000 steps"); "" while it runs
};

class Algorithm {
 public:
  virtual ~Algorithm() = default;
  virtual std::string name() const = 0;      // the config's `algorithm`, and its checkpoint sub-folder
  virtual std::string describe() const = 0;  // for the start line: "SAC 3-256-256-2 relu actor"
  // Before the run's clock starts (PPO on a GPU: one throwaway fit); what it did ("" for nothing).
  virtual std::string warm_up() { return ""; }

  // One batch that ingest accepted and the pacing let in (it has rows).
  virtual void insert(const Batch& batch) = 0;
  virtual Holding holding() const = 0;
  // Updates the data held allow now (replay: none before a minibatch; rollout: 1 when a fit is due).
  virtual int64_t ready() const = 0;
  // n updates; `version` is the policy being published, which rollout data are measured against.
  // Returns the figures of the updates finished, oldest first: on a GPU the last may still run, and
  // their figures come with a later call or with finish().
  virtual std::vector<UpdateFigures> update(int n, uint64_t version) = 0;
  virtual std::vector<UpdateFigures> finish() { return {}; }
  virtual int64_t updates() const = 0;
  // Rollout: drops data made by versions before `oldest`; returns the steps dropped.
  virtual int64_t forget_older_than(uint64_t /*oldest*/) { return 0; }
  // A larger step where the data outrun the updates (sac.max_step_scale): the most, and the scale
  // to take (batch x s, learning rates x sqrt(s)). 1 where the algorithm has none.
  virtual int max_step_scale() const { return 1; }
  virtual void set_step_scale(int /*s*/) {}

  // The policy in the workers' layout, numbered `version`.
  virtual PolicyParams policy(uint64_t version) const = 0;
  // The networks, in DIR/<name()>: the layout of RUN/best. save() adds what else a checkpoint holds
  // (a replay buffer); load() reads all that back, load_networks() the networks alone.
  virtual void save_networks(const std::string& dir) const = 0;
  virtual void save(const std::string& dir) const { save_networks(dir); }
  virtual void load_networks(const std::string& dir) = 0;
  virtual void load(const std::string& dir) { load_networks(dir); }
  // Random state and run counters, to and from a checkpoint's manifest; from_manifest returns what
  // the "resumed" log line says of the algorithm ("120 updates, buffer 4000").
  virtual void to_manifest(config::CheckpointManifest& m) const = 0;
  virtual std::string from_manifest(const config::CheckpointManifest& m) = 0;
};

}  // namespace farm
