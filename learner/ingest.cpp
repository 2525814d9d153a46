#include "ingest.h"

#include "config.h"
#include "config_validator.h"
#include "task_spec.h"

#include <algorithm>
#include <cmath>
#include <iterator>
#include <stdexcept>

namespace farm {

namespace {

std::string all_finite(const std::vector<float>& v, const char* name) {
  for (size_t i = 0; i < v.size(); ++i) {
    if (!std::isfinite(v[i])) return std::string("non-finite value in ") + name + " at index " + std::to_string(i);
  }
  return "";
}

// all_finite and, in the same pass, every |value| at most bound (`what` says whose bound it is).
// The float a worker sends may round a value at the bound, computed in double, up by a part in
// 10^7: 1e-6 of slack.
std::string all_within(const std::vector<float>& v, double bound, const char* name, const char* what) {
  const double most = bound * (1 + 1e-6);
  for (size_t i = 0; i < v.size(); ++i) {
    if (std::fabs(double(v[i])) <= most) continue;
    if (!std::isfinite(v[i])) return std::string("non-finite value in ") + name + " at index " + std::to_string(i);
    return std::string(name) + " at index " + std::to_string(i) + " is " + config_checks::num(v[i]) + ", beyond +-" +
           config_checks::num(bound) + ", " + what;
  }
  return "";
}

// Why seq is refused on a stream whose next expected number is `next`: no worker skips more than
// kMaxSequenceJump, so a number further on is forged or corrupted. "" when within.
std::string too_far(uint64_t seq, uint64_t next, const std::string& worker_id) {
  if (seq < next || seq - next <= Ingest::kMaxSequenceJump) return "";
  return "sequence number " + std::to_string(seq) + " jumps more than " + std::to_string(Ingest::kMaxSequenceJump) +
         " past " + std::to_string(next) + ", the next expected from " + worker_id;
}

std::string size_is(size_t got, size_t want, const char* name) {
  if (got == want) return "";
  return std::string(name) + " has " + std::to_string(got) + " values, expected " + std::to_string(want);
}

}  // namespace

Ingest::Ingest(std::string experiment_id, int obs_dim, int act_dim, int num_metrics)
    : experiment_id_(std::move(experiment_id)), obs_dim_(obs_dim), act_dim_(act_dim), num_metrics_(num_metrics) {}

std::string Ingest::check(const farm::msg::TransitionBatch& b) const {
  if (b.experiment_id() != experiment_id_)
    return "experiment id '" + b.experiment_id() + "' is not '" + experiment_id_ + "'";
  if (b.worker_id().empty()) return "empty worker id";
  if (b.worker_id().size() > kMaxIdBytes)
    return "worker id of " + std::to_string(b.worker_id().size()) + " bytes (at most " + std::to_string(kMaxIdBytes) +
           ")";
  if (static_cast<int>(b.obs_dim()) != obs_dim_ || static_cast<int>(b.act_dim()) != act_dim_)
    return "dims obs " + std::to_string(b.obs_dim()) + " act " + std::to_string(b.act_dim()) + ", expected obs " +
           std::to_string(obs_dim_) + " act " + std::to_string(act_dim_);
  const size_t T = b.num_steps(), N = b.num_envs();
  if (T == 0 && !b.end_of_stream()) return "empty batch (0 steps) without end_of_stream";
  if (T > 0 && N == 0) return "0 environments";
  if (N > size_t(kMaxEnvsPerWorker))
    return std::to_string(N) + " environments, more than a worker runs (" + std::to_string(kMaxEnvsPerWorker) + ")";
  if (T * N > size_t(kMaxBatchTransitions))
    return "implausible batch size " + std::to_string(T) + "x" + std::to_string(N) + " (at most " +
           std::to_string(kMaxBatchTransitions) + " transitions)";
  const size_t TN = T * N, od = obs_dim_, ad = act_dim_;
  for (auto r :
       {size_is(b.observations().size(), TN * od, "observations"), size_is(b.actions().size(), TN * ad, "actions"),
        size_is(b.rewards().size(), TN, "rewards"), size_is(b.terminated().size(), TN, "terminated"),
        size_is(b.truncated().size(), TN, "truncated"), size_is(b.log_probs().size(), TN, "log_probs"),
        size_is(b.next_observations().size(), T > 0 ? N * od : 0, "next_observations"),
        size_is(b.final_observations().size(), b.final_index().size() * od, "final_observations")}) {
    if (!r.empty()) return r;
  }
  const char* most = "more than any task's";
  const bool declared = reward_bound_ < kMaxMagnitude;
  for (auto r : {all_within(b.observations(), kMaxMagnitude, "observations", most), all_finite(b.actions(), "actions"),
                 all_within(b.rewards(), declared ? reward_bound_ : kMaxMagnitude, "rewards",
                            declared ? "the task's bound on one step's reward" : most),
                 all_finite(b.log_probs(), "log_probs"),
                 all_within(b.next_observations(), kMaxMagnitude, "next_observations", most),
                 all_within(b.final_observations(), kMaxMagnitude, "final_observations", most)}) {
    if (!r.empty()) return r;
  }
  if (std::isfinite(reward_min_) || std::isfinite(reward_max_))
    for (size_t i = 0; i < b.rewards().size(); ++i)
      if (!robots::return_within_range(b.rewards()[i], 1, reward_min_, reward_max_))
        return "reward " + config_checks::num(b.rewards()[i]) + " at " + std::to_string(i) +
               " outside the task's range of one step's reward [" + config_checks::num(reward_min_) + ", " +
               config_checks::num(reward_max_) + "]";
  for (float a : b.actions()) {
    if (num_actions_ > 0) {
      if (a < 0.f || a > float(num_actions_ - 1) || a != std::floor(a))
        return "action " + std::to_string(a) + " is not an index in [0, " + std::to_string(num_actions_) + ")";
    } else if (a < -1.0001f || a > 1.0001f) {
      return "action " + std::to_string(a) + " outside [-1, 1]";
    }
  }
  // Every step that ended an episode carries its true final observation, and only those.
  size_t k = 0;
  for (size_t i = 0; i < TN; ++i) {
    uint8_t te = b.terminated()[i], tr = b.truncated()[i];
    if (te > 1 || tr > 1) return "flag value other than 0/1 at step index " + std::to_string(i);
    bool done = te || tr;
    bool listed = k < b.final_index().size() && b.final_index()[k] == i;
    if (done != listed) return "final_index does not match the done flags at step index " + std::to_string(i);
    if (listed) ++k;
  }
  if (k != b.final_index().size()) return "final_index has entries out of order or out of range";
  // One summary for each episode that ended, in final_index's order: a batch claiming more would
  // count episodes that never ran (PPO's episode counts, the stop rules) and take memory for them.
  if (b.episodes().size() != b.final_index().size())
    return std::to_string(b.episodes().size()) + " episode summaries for " + std::to_string(b.final_index().size()) +
           " episode ends";
  for (size_t j = 0; j < b.episodes().size(); ++j) {
    const auto& e = b.episodes()[j];
    const size_t end = b.final_index()[j];
    const std::string which = "episode summary " + std::to_string(j);
    if (e.env() != end % N)
      return which + " names env " + std::to_string(e.env()) + ", its end (step index " + std::to_string(end) +
             ") is env " + std::to_string(end % N);
    if (e.terminated() != bool(b.terminated()[end]))
      return which + ": terminated does not match the flag at step index " + std::to_string(end);
    if (e.length() == 0) return which + " has length 0";
    // The task's limits hold for training episodes as for evaluated ones (eval_answer.cpp): their
    // returns are the run's mean return in the logs, learner.csv and the status.
    if (max_episode_steps_ > 0 && e.length() > uint32_t(max_episode_steps_))
      return which + " has length " + std::to_string(e.length()) + ", beyond the task's time limit of " +
             std::to_string(max_episode_steps_) + " steps";
    if (!std::isfinite(e.episode_return())) return which + " has a non-finite return";
    if (!robots::return_within_bound(e.episode_return(), e.length(), reward_bound_))
      return which + " returns " + config_checks::num(e.episode_return()) + ", beyond what " +
             std::to_string(e.length()) + " steps can give at the task's bound of " +
             config_checks::num(reward_bound_) + " a step";
    if (!robots::return_within_range(e.episode_return(), e.length(), reward_min_, reward_max_))
      return which + " returns " + config_checks::num(e.episode_return()) + ", outside what " +
             std::to_string(e.length()) + " steps can give with each step's reward in [" +
             config_checks::num(reward_min_) + ", " + config_checks::num(reward_max_) + "]";
    if (e.metrics().size() != size_t(num_metrics_))
      return which + " has " + std::to_string(e.metrics().size()) + " metrics, the task has " +
             std::to_string(num_metrics_);
    if (auto r = all_within(e.metrics(), kMaxMagnitude, "episode metrics", most); !r.empty()) return which + ": " + r;
  }
  return "";
}

std::string Ingest::content_problem(const farm::msg::TransitionBatch& b, uint64_t current_version) const {
  std::string why = check(b);
  // No learner ever published a version above the current one (a resumed learner skips ahead of
  // whatever its crashed predecessor published), so such a batch is forged or corrupted.
  if (why.empty() && !b.end_of_stream() && b.policy_version() > current_version)
    why = "policy version " + std::to_string(b.policy_version()) + " is newer than the learner's latest (" +
          std::to_string(current_version) + ")";
  return why;
}

std::string Ingest::accept(const farm::msg::TransitionBatch& b, uint64_t current_version, double now, Transitions& out,
                           std::vector<FinishedEpisode>& episodes, const std::string* writer_name,
                           const std::string& writer) {
  if (b.experiment_id() != experiment_id_) {
    // Another experiment on the same domain (its own learner accounts it): counted apart, never
    // taken, and not invalid, which would hide a real fault among another run's normal traffic.
    ++counters_.foreign;
    return "experiment id '" + b.experiment_id() + "' is not '" + experiment_id_ + "'";
  }
  if (writer_name && *writer_name != b.worker_id()) {
    // Under DDS Security a worker's id is its certificate's name: a batch under another id comes
    // from a certificate used for someone else (a leaked one, or a worker started with a foreign
    // --id). Refused before any account is looked at, so it opens and moves none.
    ++counters_.invalid;
    if (writer_name->empty())
      return "worker id '" + b.worker_id() + "' from a writer DDS Security binds to no granted worker name";
    return "worker id '" + b.worker_id() + "' is not '" + *writer_name +
           "', the certificate name of the participant that wrote it";
  }
  const uint64_t seq = b.sequence_number();
  const Key key{b.worker_id(), b.worker_session()};
  auto it = workers_.find(key);
  if (it == workers_.end()) {
    // A stream not open: its first batch passes every check before an account is opened (or a
    // retired one continued).
    std::string why = content_problem(b, current_version);
    const auto back = retired_.find(key);
    if (why.empty() && back == retired_.end() && seq > kMaxSequenceJump)
      why = "sequence number " + std::to_string(seq) + " opens a stream of " + b.worker_id() + " more than " +
            std::to_string(kMaxSequenceJump) + " past its start";
    // A retired stream that comes back is held to the bound an open one is held to, from where it
    // stopped, so no forged number restores it with a loss near 2^64.
    if (why.empty() && back != retired_.end()) why = too_far(seq, back->second.next_sequence, b.worker_id());
    if (why.empty() && back != retired_.end() && !back->second.writer.empty() && !writer.empty() &&
        back->second.writer != writer)
      why = "a batch of " + b.worker_id() + "'s stream from another participant than the one that opened it";
    if (why.empty() && back == retired_.end() && announcer_ && !writer.empty()) {
      const std::string announced = announcer_(b.worker_id(), b.worker_session());
      if (!announced.empty() && announced != writer)
        why = "the first batch of " + b.worker_id() + " session " + std::to_string(b.worker_session()) +
              " from another participant than the one whose heartbeats announced it";
    }
    if (!why.empty()) {
      ++counters_.invalid;
      return why;
    }
    WorkerAccount account;
    const bool restored = back != retired_.end();
    if (restored) {
      account = std::move(back->second);
      retired_.erase(back);
      retired_order_.erase(std::find(retired_order_.begin(), retired_order_.end(), key));
    } else {
      account.worker_id = b.worker_id();
      account.session = b.worker_session();
    }
    // Room: past the id's bound, or past the total, the open stream with the fewest accepted
    // batches (the least recently seen of those) goes, of that id or of all.
    const auto fewer = [](const WorkerAccount& a, const WorkerAccount& b) {
      return a.received != b.received ? a.received < b.received : a.last_seen < b.last_seen;
    };
    size_t same_id = 0;
    auto first_out = workers_.end();
    for (auto j = workers_.lower_bound(Key{b.worker_id(), 0}); j != workers_.end() && j->first.first == b.worker_id();
         ++j, ++same_id)
      if (first_out == workers_.end() || fewer(j->second, first_out->second)) first_out = j;
    if (same_id < kMaxSessionsPerWorker && workers_.size() >= kMaxAccounts) {
      first_out = workers_.begin();
      for (auto j = workers_.begin(); j != workers_.end(); ++j)
        if (fewer(j->second, first_out->second)) first_out = j;
    }
    if (same_id >= kMaxSessionsPerWorker || workers_.size() >= kMaxAccounts) retire(first_out);
    it = workers_.emplace(key, std::move(account)).first;
  } else if (!it->second.writer.empty() && !writer.empty() && it->second.writer != writer) {
    // Someone else writing under an open stream's id and session (both can be read off the bus):
    // refused without moving the account, so it can neither fake losses nor skip the sequence.
    ++counters_.invalid;
    return "a batch of " + b.worker_id() + "'s stream from another participant than the one that opened it";
  } else if (std::string far = too_far(seq, it->second.next_sequence, b.worker_id()); !far.empty()) {
    // Refused without moving the account.
    ++counters_.invalid;
    return far;
  }
  if (it->second.writer.empty()) it->second.writer = writer;
  WorkerAccount& w = it->second;
  w.last_seen = now;

  // Sequence accounting happens before the content check: an invalid batch still used its number.
  if (seq < w.next_sequence) {
    auto m = std::find(w.missing.begin(), w.missing.end(), seq);
    if (m == w.missing.end()) {
      ++w.duplicates;
      ++counters_.duplicate;
      return "duplicate sequence number " + std::to_string(seq) + " from " + b.worker_id();
    }
    w.missing.erase(m);  // late, not lost after all
    --missing_total_;
    --w.lost;
    --counters_.lost;
  } else {
    // O(1) in the gap: only the first numbers of a gap are remembered as possibly late, within the
    // bound over all accounts.
    for (uint64_t s = w.next_sequence; s < seq && w.missing.size() < kMaxMissing && missing_total_ < kMaxMissingTotal;
         ++s, ++missing_total_)
      w.missing.push_back(s);
    w.lost += seq - w.next_sequence;
    counters_.lost += seq - w.next_sequence;
    w.next_sequence = seq + 1;
  }
  if (b.end_of_stream()) w.ended = true;

  const std::string why = content_problem(b, current_version);
  if (!why.empty()) {
    ++w.invalid;
    ++counters_.invalid;
    return why;
  }
  ++w.received;
  ++counters_.ok;
  counters_.lag_sum += current_version >= b.policy_version() ? double(current_version - b.policy_version()) : 0.0;

  const size_t T = b.num_steps(), N = b.num_envs(), od = obs_dim_, ad = act_dim_;
  const size_t TN = T * N;
  w.env_steps += TN;
  counters_.env_steps += TN;
  out.obs.insert(out.obs.end(), b.observations().begin(), b.observations().end());
  out.actions.insert(out.actions.end(), b.actions().begin(), b.actions().end());
  out.rewards.insert(out.rewards.end(), b.rewards().begin(), b.rewards().end());
  out.terminated.insert(out.terminated.end(), b.terminated().begin(), b.terminated().end());
  size_t base = out.next_obs.size();
  out.next_obs.resize(base + TN * od);
  float* nx = out.next_obs.data() + base;
  size_t k = 0;
  for (size_t i = 0; i < TN; ++i) {
    const float* src;
    if (k < b.final_index().size() && b.final_index()[k] == i) {
      src = b.final_observations().data() + k * od;  // the episode ended: its true last observation
      ++k;
    } else if (i + N < TN) {
      src = b.observations().data() + (i + N) * od;
    } else {
      src = b.next_observations().data() + (i + N - TN) * od;
    }
    std::copy(src, src + od, nx + i * od);
  }
  out.n += static_cast<int64_t>(TN);
  (void)ad;
  for (const auto& e : b.episodes()) {
    episodes.push_back({b.worker_id(), e.episode_return(), e.length(), e.metrics()});
  }
  return "";
}

uint64_t Ingest::max_batch_bytes(int obs_dim, int act_dim, int num_metrics, int steps_per_batch) {
  const uint64_t n = kMaxEnvsPerWorker, od = obs_dim, ad = act_dim, m = num_metrics;
  const uint64_t tn = std::min<uint64_t>(uint64_t(steps_per_batch) * n, kMaxBatchTransitions);
  const uint64_t per_step = 4 * od + 4 * ad + 4 + 1 + 1 + 4   // observation, action, reward, flags, log-prob
                            + 4 + 4 * od                      // final_index, final observation
                            + 4 + 4 + 4 + 1 + 3 + 4 + 4 * m;  // episode summary, padded, with its metrics
  return tn * per_step + 4 * n * od + kBatchHeaderBytes;
}

uint64_t Ingest::count_refused_samples(uint64_t refused_total) {
  if (refused_total <= refused_samples_) return 0;
  const uint64_t fresh = refused_total - refused_samples_;
  refused_samples_ = refused_total;
  counters_.invalid += fresh;
  return fresh;
}

void fold_n_step(const farm::msg::TransitionBatch& b, Transitions& rows, double gamma, int n_step) {
  fold_n_step(b.num_steps(), b.num_envs(), b.truncated().data(), rows, gamma, n_step);
}

void Ingest::restore(const std::map<Key, WorkerAccount>& open, const std::vector<WorkerAccount>& retired,
                     const IngestCounters& counters) {
  workers_.clear();
  retired_.clear();
  retired_order_.clear();
  for (const auto& [key, w] : open) {
    if (workers_.size() >= kMaxAccounts) break;
    workers_.emplace(key, w);
  }
  for (size_t i = retired.size() > kMaxRetired ? retired.size() - kMaxRetired : 0; i < retired.size(); ++i) {
    const Key key{retired[i].worker_id, retired[i].session};
    if (workers_.count(key) || !retired_.emplace(key, retired[i]).second) continue;
    retired_order_.push_back(key);
  }
  // Held to the bound over all accounts, whatever the checkpoint holds.
  missing_total_ = 0;
  const auto within = [this](WorkerAccount& w) {
    w.missing.resize(std::min(w.missing.size(), kMaxMissingTotal - missing_total_));
    missing_total_ += w.missing.size();
  };
  for (auto& [_, w] : workers_) within(w);
  for (const auto& key : retired_order_) within(retired_.at(key));
  counters_ = counters;
}

void Ingest::retire(std::map<Key, WorkerAccount>::iterator it) {
  ++retired_count_;
  last_retired_ = it->first.first + "#" + std::to_string(it->first.second) + " (" +
                  std::to_string(it->second.received) + " batches)";
  while (retired_.size() >= kMaxRetired && !retired_order_.empty()) {
    const auto oldest = retired_.find(retired_order_.front());
    missing_total_ -= oldest->second.missing.size();
    retired_.erase(oldest);
    retired_order_.pop_front();
  }
  retired_order_.push_back(it->first);
  retired_[it->first] = std::move(it->second);
  workers_.erase(it);
}

size_t Ingest::expire(double now, double idle_seconds) {
  size_t n = 0;
  for (auto it = workers_.begin(); it != workers_.end();) {
    auto next = std::next(it);
    if (now - it->second.last_seen >= idle_seconds) {
      retire(it);
      ++n;
    }
    it = next;
  }
  return n;
}

}  // namespace farm
