// Replay buffer for off-policy learners: a ring over preallocated contiguous storage, filled from
// ingested transitions and sampled uniformly with replacement.
#pragma once

#include <torch/types.h>

#include <cstdint>
#include <random>
#include <string>

namespace farm {

// A sampled minibatch, each tensor freshly allocated and contiguous:
// obs [B, obs_dim], actions [B, act_dim], rewards [B], terminated [B] (0/1), next_obs [B, obs_dim],
// horizon [B]: the number of environment steps between obs and next_obs (1 unless the rows were
// folded into multi-step returns, see fold_n_step in ingest.h). An undefined horizon means 1.
struct SampledBatch {
  torch::Tensor obs, actions, rewards, terminated, next_obs, horizon;
};

// A row's horizon h folded into its terminated flag, for targets of the form r + gamma * (1 - t) * v
// (SAC's critics, sac.n_step): t = 1 - gamma^(h-1) * (1 - terminated), so gamma * (1 - t) is
// gamma^h * (1 - terminated). h = 1 leaves terminated exactly as it is.
float fold_horizon(float terminated, float horizon, double gamma);
// The batch with its horizon so folded into a new terminated tensor, horizon left undefined; the
// batch as it is where horizon is undefined.
SampledBatch fold_horizon(const SampledBatch& b, double gamma);

// Where add_n's n rows land in a ring of `capacity` rows whose next row is `next`: the first `skip`
// rows are left out (a later row of the same call would overwrite them), the others go to rows
// [at, at + first) and then [0, rest), and the ring's next row is next_after. ReplayBuffer and its
// device copy (DeviceReplay) place rows by it, so both hold the same rows at the same positions.
struct RingPlacement {
  int64_t skip, at, first, rest, next_after;
};
RingPlacement place_in_ring(int64_t capacity, int64_t next, int64_t n);

class ReplayBuffer {
 public:
  // Storage is reserved up front but not touched, so a large capacity costs memory only as it
  // fills.
  ReplayBuffer(int64_t capacity, int obs_dim, int act_dim);

  void add(const float* obs, const float* action, float reward, bool terminated, const float* next_obs);
  // n rows, each array row-major: obs/next_obs [n x obs_dim], actions [n x act_dim], rewards,
  // terminated and horizon [n] (horizon nullptr: every row spans 1 step). When n exceeds the
  // capacity only the last `capacity` rows are kept.
  void add_n(int64_t n, const float* obs, const float* actions, const float* rewards, const uint8_t* terminated,
             const float* next_obs, const float* horizon = nullptr);

  int64_t size() const { return size_; }
  int64_t capacity() const { return capacity_; }
  int64_t total_added() const { return total_added_; }
  int obs_dim() const { return obs_dim_; }
  int act_dim() const { return act_dim_; }

  // Uniform over the stored rows, with replacement. Throws std::logic_error when empty.
  SampledBatch sample(int batch_size, std::mt19937_64& rng) const;
  // The stored rows [0, size()) as views of the storage (not copies), at their ring positions;
  // the row the next add writes is next_row(). For a copy kept elsewhere (DeviceReplay).
  SampledBatch stored() const;
  int64_t next_row() const { return next_; }

  // Binary snapshot of the stored rows and the ring position. save() writes FILE.tmp then renames,
  // so a crash never leaves a half-written file under the real name.
  void save(const std::string& file) const;
  // Throws std::runtime_error naming the file and what did not match (dims, capacity, format,
  // size); on such errors the buffer is left unchanged. A failed read after validation clears it.
  void load(const std::string& file);

 private:
  void copy_rows(int64_t dst, int64_t src, int64_t n, const float* obs, const float* actions, const float* rewards,
                 const uint8_t* terminated, const float* next_obs, const float* horizon);

  int64_t capacity_;
  int obs_dim_, act_dim_;
  int64_t size_ = 0, next_ = 0, total_added_ = 0;
  torch::Tensor obs_, actions_, rewards_, terminated_, next_obs_, horizon_;
  float *obs_p_, *actions_p_, *rewards_p_, *terminated_p_, *next_obs_p_, *horizon_p_;
};

}  // namespace farm
