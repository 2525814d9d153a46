#include "replay_buffer.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <stdexcept>

namespace farm {

namespace {

// 02: rows carry their horizon (multi-step returns); 01 files had no such column.
constexpr char kMagic[8] = {'F', 'A', 'R', 'M', 'R', 'B', '0', '2'};

struct FileHeader {
  char magic[8];
  int32_t obs_dim, act_dim;
  int64_t capacity, size, next, total_added;
};

std::string describe_dims(int64_t capacity, int obs_dim, int act_dim) {
  return "capacity " + std::to_string(capacity) + ", obs_dim " + std::to_string(obs_dim) + ", act_dim " +
         std::to_string(act_dim);
}

}  // namespace

ReplayBuffer::ReplayBuffer(int64_t capacity, int obs_dim, int act_dim)
    : capacity_(capacity), obs_dim_(obs_dim), act_dim_(act_dim) {
  if (capacity <= 0 || obs_dim <= 0 || act_dim <= 0)
    throw std::invalid_argument("ReplayBuffer: expected positive sizes, got " +
                                describe_dims(capacity, obs_dim, act_dim));
  const auto f32 = torch::TensorOptions().dtype(torch::kFloat32);
  obs_ = torch::empty({capacity, obs_dim}, f32);
  actions_ = torch::empty({capacity, act_dim}, f32);
  rewards_ = torch::empty({capacity}, f32);
  terminated_ = torch::empty({capacity}, f32);
  next_obs_ = torch::empty({capacity, obs_dim}, f32);
  horizon_ = torch::empty({capacity}, f32);
  obs_p_ = obs_.data_ptr<float>();
  actions_p_ = actions_.data_ptr<float>();
  rewards_p_ = rewards_.data_ptr<float>();
  terminated_p_ = terminated_.data_ptr<float>();
  next_obs_p_ = next_obs_.data_ptr<float>();
  horizon_p_ = horizon_.data_ptr<float>();
}

void ReplayBuffer::copy_rows(int64_t dst, int64_t src, int64_t n, const float* obs, const float* actions,
                             const float* rewards, const uint8_t* terminated, const float* next_obs,
                             const float* horizon) {
  assert(dst + n <= capacity_);
  std::memcpy(obs_p_ + dst * obs_dim_, obs + src * obs_dim_, sizeof(float) * n * obs_dim_);
  std::memcpy(actions_p_ + dst * act_dim_, actions + src * act_dim_, sizeof(float) * n * act_dim_);
  std::memcpy(rewards_p_ + dst, rewards + src, sizeof(float) * n);
  for (int64_t i = 0; i < n; ++i) terminated_p_[dst + i] = terminated[src + i] ? 1.f : 0.f;
  std::memcpy(next_obs_p_ + dst * obs_dim_, next_obs + src * obs_dim_, sizeof(float) * n * obs_dim_);
  if (horizon) {
    std::memcpy(horizon_p_ + dst, horizon + src, sizeof(float) * n);
  } else {
    std::fill(horizon_p_ + dst, horizon_p_ + dst + n, 1.f);
  }
}

void ReplayBuffer::add(const float* obs, const float* action, float reward, bool terminated, const float* next_obs) {
  const uint8_t t = terminated ? 1 : 0;
  copy_rows(next_, 0, 1, obs, action, &reward, &t, next_obs, nullptr);
  next_ = (next_ + 1) % capacity_;
  if (size_ < capacity_) ++size_;
  ++total_added_;
}

RingPlacement place_in_ring(int64_t capacity, int64_t next, int64_t n) {
  RingPlacement p{};
  p.skip = std::max<int64_t>(0, n - capacity);
  p.at = (next + p.skip) % capacity;
  const int64_t kept = n - p.skip;
  p.first = std::min(kept, capacity - p.at);
  p.rest = kept - p.first;
  p.next_after = (p.at + kept) % capacity;
  return p;
}

void ReplayBuffer::add_n(int64_t n, const float* obs, const float* actions, const float* rewards,
                         const uint8_t* terminated, const float* next_obs, const float* horizon) {
  if (n <= 0) return;
  total_added_ += n;
  const RingPlacement p = place_in_ring(capacity_, next_, n);
  copy_rows(p.at, p.skip, p.first, obs, actions, rewards, terminated, next_obs, horizon);
  if (p.rest > 0) copy_rows(0, p.skip + p.first, p.rest, obs, actions, rewards, terminated, next_obs, horizon);
  next_ = p.next_after;
  size_ = std::min(capacity_, size_ + p.first + p.rest);
}

SampledBatch ReplayBuffer::sample(int batch_size, std::mt19937_64& rng) const {
  if (size_ == 0) throw std::logic_error("ReplayBuffer::sample: the buffer is empty");
  const auto f32 = torch::TensorOptions().dtype(torch::kFloat32);
  SampledBatch b;
  b.obs = torch::empty({batch_size, obs_dim_}, f32);
  b.actions = torch::empty({batch_size, act_dim_}, f32);
  b.rewards = torch::empty({batch_size}, f32);
  b.terminated = torch::empty({batch_size}, f32);
  b.next_obs = torch::empty({batch_size, obs_dim_}, f32);
  b.horizon = torch::empty({batch_size}, f32);
  float* obs = b.obs.data_ptr<float>();
  float* act = b.actions.data_ptr<float>();
  float* rew = b.rewards.data_ptr<float>();
  float* term = b.terminated.data_ptr<float>();
  float* next_obs = b.next_obs.data_ptr<float>();
  float* horizon = b.horizon.data_ptr<float>();
  std::uniform_int_distribution<int64_t> pick(0, size_ - 1);
  const size_t obs_bytes = sizeof(float) * obs_dim_, act_bytes = sizeof(float) * act_dim_;
  for (int i = 0; i < batch_size; ++i) {
    const int64_t j = pick(rng);
    std::memcpy(obs + int64_t(i) * obs_dim_, obs_p_ + j * obs_dim_, obs_bytes);
    std::memcpy(act + int64_t(i) * act_dim_, actions_p_ + j * act_dim_, act_bytes);
    rew[i] = rewards_p_[j];
    term[i] = terminated_p_[j];
    horizon[i] = horizon_p_[j];
    std::memcpy(next_obs + int64_t(i) * obs_dim_, next_obs_p_ + j * obs_dim_, obs_bytes);
  }
  return b;
}

float fold_horizon(float terminated, float horizon, double gamma) {
  if (horizon == 1.f) return terminated;
  return float(1.0 - std::pow(gamma, double(horizon) - 1.0) * (1.0 - double(terminated)));
}

SampledBatch fold_horizon(const SampledBatch& b, double gamma) {
  if (!b.horizon.defined()) return b;
  SampledBatch out = b;
  out.horizon = torch::Tensor();
  if (b.terminated.device().is_cpu() && b.horizon.device().is_cpu()) {
    // The host path of every update: a loop over B floats, not a few tensor ops' dispatch.
    const auto t = b.terminated.to(torch::kFloat).contiguous(), h = b.horizon.to(torch::kFloat).contiguous();
    if (t.numel() != h.numel())
      throw std::invalid_argument("fold_horizon: " + std::to_string(t.numel()) + " terminated flags but " +
                                  std::to_string(h.numel()) + " horizons");
    const float *tp = t.data_ptr<float>(), *hp = h.data_ptr<float>();
    // One-step rows (every horizon 1: n_step 1, the default) keep their flags, with no new tensor.
    if (std::all_of(hp, hp + h.numel(), [](float x) { return x == 1.f; })) return out;
    out.terminated = torch::empty_like(t);
    float* op = out.terminated.data_ptr<float>();
    for (int64_t i = 0; i < t.numel(); ++i) op[i] = fold_horizon(tp[i], hp[i], gamma);
  } else {
    out.terminated = 1.0 - torch::pow(gamma, b.horizon - 1.0) * (1.0 - b.terminated);
  }
  return out;
}

SampledBatch ReplayBuffer::stored() const {
  return {obs_.narrow(0, 0, size_),        actions_.narrow(0, 0, size_),  rewards_.narrow(0, 0, size_),
          terminated_.narrow(0, 0, size_), next_obs_.narrow(0, 0, size_), horizon_.narrow(0, 0, size_)};
}

void ReplayBuffer::save(const std::string& file) const {
  const std::string tmp = file + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) throw std::runtime_error("replay buffer " + tmp + ": cannot open for writing");
    FileHeader h{};
    std::memcpy(h.magic, kMagic, sizeof kMagic);
    h.obs_dim = obs_dim_;
    h.act_dim = act_dim_;
    h.capacity = capacity_;
    h.size = size_;
    h.next = next_;
    h.total_added = total_added_;
    out.write(reinterpret_cast<const char*>(&h), sizeof h);
    // Until the ring has wrapped, rows [0, size) are exactly the stored ones; after it, size is
    // the capacity.
    auto put = [&](const float* p, int64_t cols) {
      out.write(reinterpret_cast<const char*>(p), std::streamsize(sizeof(float) * size_ * cols));
    };
    put(obs_p_, obs_dim_);
    put(actions_p_, act_dim_);
    put(rewards_p_, 1);
    put(terminated_p_, 1);
    put(next_obs_p_, obs_dim_);
    put(horizon_p_, 1);
    out.flush();
    if (!out) throw std::runtime_error("replay buffer " + tmp + ": write failed");
  }
  if (std::rename(tmp.c_str(), file.c_str()) != 0)
    throw std::runtime_error("replay buffer " + file + ": cannot rename " + tmp + " to it");
}

void ReplayBuffer::load(const std::string& file) {
  std::ifstream in(file, std::ios::binary | std::ios::ate);
  if (!in) throw std::runtime_error("replay buffer " + file + ": cannot open for reading");
  const int64_t file_bytes = in.tellg();
  in.seekg(0);
  FileHeader h{};
  if (file_bytes < int64_t(sizeof h) || !in.read(reinterpret_cast<char*>(&h), sizeof h))
    throw std::runtime_error("replay buffer " + file + ": truncated header");
  if (std::memcmp(h.magic, kMagic, 6) == 0 && std::memcmp(h.magic, kMagic, sizeof kMagic) != 0)
    throw std::runtime_error("replay buffer " + file + ": format " + std::string(h.magic + 6, 2) +
                             " is not this learner's " + std::string(kMagic + 6, 2) +
                             " (start a new run, or resume it with the learner that wrote it)");
  if (std::memcmp(h.magic, kMagic, sizeof kMagic) != 0)
    throw std::runtime_error("replay buffer " + file + ": not a replay buffer file (bad magic)");
  if (h.obs_dim != obs_dim_ || h.act_dim != act_dim_ || h.capacity != capacity_)
    throw std::runtime_error("replay buffer " + file + ": file has " + describe_dims(h.capacity, h.obs_dim, h.act_dim) +
                             ", expected " + describe_dims(capacity_, obs_dim_, act_dim_));
  if (h.size < 0 || h.size > h.capacity || h.next < 0 || h.next >= h.capacity || h.total_added < h.size ||
      (h.size < h.capacity && h.next != h.size))
    throw std::runtime_error("replay buffer " + file + ": inconsistent header (size " + std::to_string(h.size) +
                             ", next " + std::to_string(h.next) + ", total_added " + std::to_string(h.total_added) +
                             ")");
  const int64_t expected = int64_t(sizeof h) + int64_t(sizeof(float)) * h.size * (2 * int64_t(obs_dim_) + act_dim_ + 3);
  if (file_bytes != expected)
    throw std::runtime_error("replay buffer " + file + ": " + std::to_string(file_bytes) + " bytes, expected " +
                             std::to_string(expected) + " for " + std::to_string(h.size) + " rows");
  auto get = [&](float* p, int64_t cols) {
    in.read(reinterpret_cast<char*>(p), std::streamsize(sizeof(float) * h.size * cols));
  };
  get(obs_p_, obs_dim_);
  get(actions_p_, act_dim_);
  get(rewards_p_, 1);
  get(terminated_p_, 1);
  get(next_obs_p_, obs_dim_);
  get(horizon_p_, 1);
  if (!in) {
    size_ = next_ = total_added_ = 0;
    throw std::runtime_error("replay buffer " + file + ": read failed; buffer cleared");
  }
  size_ = h.size;
  next_ = h.next;
  total_added_ = h.total_added;
}

}  // namespace farm
