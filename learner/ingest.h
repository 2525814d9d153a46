// Ingest: the learner's door. Every TransitionBatch is checked here (experiment, shapes, finite
// numbers, flags) and every per-worker sequence number is accounted (lost, duplicate, invalid).
// A bad batch is counted with its reason and never reaches a buffer.
#pragma once

#include <cmath>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "batch.h"
#include "farm.h"

namespace farm {

struct WorkerAccount {
  std::string worker_id;
  uint64_t session = 0;
  uint64_t next_sequence = 0;  // the next sequence number expected
  uint64_t received = 0;       // accepted batches
  uint64_t lost = 0;           // sequence numbers never seen (gaps)
  uint64_t duplicates = 0;
  uint64_t invalid = 0;
  uint64_t env_steps = 0;
  bool ended = false;             // end_of_stream seen
  double last_seen = 0.0;         // seconds on the learner's clock
  std::vector<uint64_t> missing;  // gap sequence numbers that may still arrive late
  // The participant whose batches opened the stream (its DDS GUID prefix): the stream takes
  // batches from it alone. Checkpointed, so that a resumed learner keeps the binding of a worker
  // that stayed up and no other participant can take the stream by writing first after the resume;
  // empty (a record without it): the next writer binds it.
  std::string writer;
};

struct IngestCounters {
  uint64_t ok = 0, lost = 0, duplicate = 0, invalid = 0;
  uint64_t foreign = 0;  // batches of another experiment on the domain: not used, not invalid
  uint64_t env_steps = 0;
  double lag_sum = 0.0;  // sum over accepted batches of (current version - batch version)
};

// fold_n_step (batch.h) for the rows that Ingest::accept appended for batch `b`.
void fold_n_step(const farm::msg::TransitionBatch& b, Transitions& rows, double gamma, int n_step);

class Ingest {
 public:
  // num_metrics: the task's metric count, which every episode summary carries.
  Ingest(std::string experiment_id, int obs_dim, int act_dim, int num_metrics);

  // Checks one batch. On success appends its transitions to `out`, its finished episodes to
  // `episodes`, and returns an empty string; otherwise returns why it was refused.
  // writer_name, with DDS Security: the certificate name of the authenticated participant that
  // wrote the batch ("" when unknown). A worker's id is its certificate's name, so a batch of this
  // experiment whose worker id is not that name is refused as invalid on no account: it is not the
  // worker it claims, and must neither train nor open or move that worker's stream. nullptr: no
  // security, no such check.
  // writer: the participant that wrote the batch (its GUID prefix, dds::participant_key); a stream
  // once opened takes batches only from the participant that opened it, and a batch of its
  // (worker id, session) from any other is refused as invalid without touching the account. ""
  // binds nothing.
  std::string accept(const farm::msg::TransitionBatch& b, uint64_t current_version, double now, Transitions& out,
                     std::vector<FinishedEpisode>& episodes, const std::string* writer_name = nullptr,
                     const std::string& writer = "");

  // Retires the accounts with no batch for idle_seconds or more (kept aside as retired: a batch
  // of one that comes back continues its account). Returns how many.
  size_t expire(double now, double idle_seconds);
  // Accounts retired so far: idle (expire), or to make room (the bounds below).
  uint64_t retired() const { return retired_count_; }
  // The last account retired to make room, "ID#SESSION (N batches)", for the log.
  const std::string& last_retired() const { return last_retired_; }

  const IngestCounters& counters() const { return counters_; }
  using Key = std::pair<std::string, uint64_t>;  // (worker id, session)
  const std::map<Key, WorkerAccount>& workers() const { return workers_; }
  // Accounts retired and kept (the last kMaxRetired): a stream that comes back continues its own.
  const std::map<Key, WorkerAccount>& retired_accounts() const { return retired_; }
  // Their keys, oldest retired first.
  const std::deque<Key>& retired_order() const { return retired_order_; }
  // Gap numbers remembered over all accounts (at most kMaxMissingTotal).
  size_t missing_total() const { return missing_total_; }
  // Restores accounting from a checkpoint (ingest_accounts.h), so batches sent while the learner
  // was away count as lost: the open streams, and the retired ones, oldest first (at most
  // kMaxAccounts and the last kMaxRetired of them).
  void restore(const std::map<Key, WorkerAccount>& open, const std::vector<WorkerAccount>& retired,
               const IngestCounters& counters);

  // The shape/number check alone, exposed for tests and tools; "" when valid.
  std::string check(const farm::msg::TransitionBatch& b) const;

  // A stream's sequence numbers never jump further than this (forged or corrupted otherwise);
  // the first kMaxMissing numbers of a stream's gaps are remembered, so a late batch is not counted
  // twice. At most kMaxAccounts streams (worker id, session) are open, and at most
  // kMaxSessionsPerWorker of one worker id. A new stream past either bound retires an open one
  // rather than being refused, so invented streams cannot lock real workers out: the open stream
  // with the fewest accepted batches (the least recently seen of those), of that id past the id's
  // bound, of all past the total. A real worker's stream, with its many batches, outlasts
  // invented ones. A worker's id is its certificate's name under DDS
  // Security, so there the per-id bound is a bound per authenticated name. The last
  // kMaxRetired retired accounts are kept: a stream that comes back continues its own.
  static constexpr uint64_t kMaxSequenceJump = uint64_t(1) << 20;
  static constexpr size_t kMaxAccounts = 4096;
  static constexpr size_t kMaxSessionsPerWorker = 4;
  static constexpr size_t kMaxRetired = 4096;
  static constexpr size_t kMaxMissing = 4096;
  // Remembered gap numbers over all accounts, open and retired: streams invented by the thousand,
  // each opening or jumping far, would otherwise hold kMaxAccounts + kMaxRetired full lists (256 MiB)
  // and write them into every checkpoint. Past it a gap is counted lost and not remembered.
  static constexpr size_t kMaxMissingTotal = 65536;
  // A worker id's bytes, as for heartbeats (WorkerRoster::kMaxIdBytes): every accepted episode,
  // account and event carries one.
  static constexpr size_t kMaxIdBytes = 256;

  // The largest serialized TransitionBatch (CDR, encapsulation included) a worker of this
  // experiment can send: steps_per_batch steps of kMaxEnvsPerWorker envs (a worker may run more envs
  // than the config's), at most kMaxBatchTransitions, every step ending an episode with its final
  // observation and a summary of num_metrics metrics, plus kBatchHeaderBytes for ids and headers.
  // The learner's batch reader refuses larger samples before taking memory for them
  // (dds::Reader's max_sample_bytes); pendulum at 25 steps per batch: 6.9 MB. A refused sample
  // takes no memory: fed 26 MiB batches, the learner of integration.hostile stays under its
  // documented 320 MiB peak RSS (docs/record/reliability.md, "size limits before memory").
  static uint64_t max_batch_bytes(int obs_dim, int act_dim, int num_metrics, int steps_per_batch);
  static constexpr uint64_t kBatchHeaderBytes = 64 * 1024;
  // Samples the bus refused before they became batches (over max_batch_bytes), as the reader's
  // running total: the ones not yet counted are counted invalid, on no account since their sender is
  // unknown. Returns how many were new.
  uint64_t count_refused_samples(uint64_t refused_total);

  // Discrete actions (n > 0): each action must be an index in [0, n) instead of a value in
  // [-1, 1].
  void set_num_actions(int n) { num_actions_ = n; }
  // The task's bound on |reward| of one step (TaskSpec::reward_bound; infinite: not declared): a
  // batch with a reward beyond it is refused.
  // reward_min, reward_max: the one-sided bounds of one step's reward (TaskSpec), where declared.
  void set_reward_bound(double bound, double reward_min = -HUGE_VAL, double reward_max = HUGE_VAL) {
    reward_bound_ = bound;
    reward_min_ = reward_min;
    reward_max_ = reward_max;
  }
  // The task's time limit (TaskSpec::max_episode_steps; 0: none): an episode summary longer than it
  // is refused.
  void set_max_episode_steps(int steps) { max_episode_steps_ = steps; }
  // Who announced a worker session: the participant (dds::participant_key) of the first heartbeat of
  // (worker id, session), "" when none was heard. A stream then opens only from that participant:
  // a session number is random and first read off the bus in its worker's own heartbeat, so a
  // participant that copies it and writes the first batch under it (a stream thief) is refused,
  // counted invalid on no account. A stream whose heartbeat is not heard opens from its writer;
  // the ingest thread holds such a first batch a while for its announcement (first_batch_hold.h).
  using Announcer = std::function<std::string(const std::string& worker_id, uint64_t session)>;
  void set_announcer(Announcer announcer) { announcer_ = std::move(announcer); }
  // Whether batch b of this experiment would open a stream the announcer knows nothing of yet: no
  // stream of its (worker id, session) open or retired here, an announcer set, and no announcement
  // heard.
  bool unannounced_opening(const farm::msg::TransitionBatch& b) const {
    const Key key{b.worker_id(), b.worker_session()};
    return announcer_ && b.experiment_id() == experiment_id_ && !workers_.count(key) && !retired_.count(key) &&
           announced(key).empty();
  }
  // The announcer's answer ("" when none is set or nothing was heard).
  std::string announced(const Key& key) const { return announcer_ ? announcer_(key.first, key.second) : ""; }

  // No task observes or is rewarded beyond this magnitude: a batch with an observation or reward
  // beyond it is refused. Squared (a critic's or a value's error), it stays a float32, so one
  // finite but absurd number from the network cannot make a loss infinite and end the run.
  static constexpr double kMaxMagnitude = 1e9;

 private:
  // check() plus the policy version against the learner's latest; "" when valid.
  std::string content_problem(const farm::msg::TransitionBatch& b, uint64_t current_version) const;

  std::string experiment_id_;
  int obs_dim_, act_dim_, num_metrics_;
  int num_actions_ = 0;
  double reward_bound_ = HUGE_VAL, reward_min_ = -HUGE_VAL, reward_max_ = HUGE_VAL;
  int max_episode_steps_ = 0;
  Announcer announcer_;
  IngestCounters counters_;
  size_t missing_total_ = 0;  // the sizes of every account's `missing`, open and retired
  // Moves an open account to retired_ (bounded, oldest out first).
  void retire(std::map<Key, WorkerAccount>::iterator it);
  std::map<Key, WorkerAccount> workers_;
  std::map<Key, WorkerAccount> retired_;
  std::deque<Key> retired_order_;  // the keys of retired_, oldest first
  uint64_t retired_count_ = 0;
  std::string last_retired_;
  uint64_t refused_samples_ = 0;  // of this process's reader, so not checkpointed
};

}  // namespace farm
