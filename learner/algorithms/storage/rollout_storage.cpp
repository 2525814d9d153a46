#include "rollout_storage.h"

#include <algorithm>
#include <cstring>
#include <fstream>
#include <stdexcept>

#include "gae.h"

namespace farm {

void RolloutStorage::add(int T, int N, const float* obs, const float* actions, const float* rewards,
                         const uint8_t* terminated, const uint8_t* truncated, const float* log_probs,
                         const float* next_obs, uint64_t version) {
  const int od = obs_dim_, ad = act_dim_;
  for (int n = 0; n < N; ++n) {
    Trajectory tr;
    tr.version = version;
    tr.len = T;
    tr.obs.resize(size_t(T) * od);
    tr.next_obs.resize(size_t(T) * od);
    tr.actions.resize(size_t(T) * ad);
    tr.rewards.resize(T);
    tr.log_probs.resize(T);
    tr.terminated.resize(T);
    tr.truncated.resize(T);
    for (int t = 0; t < T; ++t) {
      const size_t i = size_t(t) * N + n;
      std::copy(obs + i * od, obs + (i + 1) * od, tr.obs.begin() + size_t(t) * od);
      std::copy(next_obs + i * od, next_obs + (i + 1) * od, tr.next_obs.begin() + size_t(t) * od);
      std::copy(actions + i * ad, actions + (i + 1) * ad, tr.actions.begin() + size_t(t) * ad);
      tr.rewards[t] = rewards[i];
      tr.log_probs[t] = log_probs[i];
      tr.terminated[t] = terminated[i];
      tr.truncated[t] = truncated[i];
    }
    trajs_.push_back(std::move(tr));
  }
  steps_ += int64_t(T) * N;
}

void RolloutStorage::clear() {
  trajs_.clear();
  steps_ = 0;
}

int64_t RolloutStorage::drop_older_than(uint64_t min_version) {
  int64_t dropped = 0;
  for (auto it = trajs_.begin(); it != trajs_.end();) {
    if (it->version < min_version) {
      dropped += it->len;
      it = trajs_.erase(it);
    } else {
      ++it;
    }
  }
  steps_ -= dropped;
  return dropped;
}

void RolloutStorage::shift_versions(uint64_t offset) {
  for (auto& tr : trajs_) tr.version += offset;
}

namespace {

constexpr char kRolloutMagic[8] = {'F', 'R', 'O', 'L', 'L', '0', '0', '1'};

struct RolloutHeader {
  char magic[8];
  int32_t obs_dim, act_dim;
  int64_t trajectories, steps;
};

// A trajectory's bytes after its (version, len) pair.
int64_t trajectory_bytes(int64_t len, int od, int ad) {
  return len * int64_t(sizeof(float)) * (2 * od + ad + 2) + 2 * len;
}

}  // namespace

void RolloutStorage::save(const std::string& file) const {
  std::ofstream out(file, std::ios::binary | std::ios::trunc);
  if (!out) throw std::runtime_error("rollout storage " + file + ": cannot open for writing");
  RolloutHeader h{};
  std::memcpy(h.magic, kRolloutMagic, sizeof kRolloutMagic);
  h.obs_dim = obs_dim_;
  h.act_dim = act_dim_;
  h.trajectories = int64_t(trajs_.size());
  h.steps = steps_;
  out.write(reinterpret_cast<const char*>(&h), sizeof h);
  auto put = [&out](const auto& v) {
    out.write(reinterpret_cast<const char*>(v.data()), std::streamsize(v.size() * sizeof(v[0])));
  };
  for (const auto& tr : trajs_) {
    out.write(reinterpret_cast<const char*>(&tr.version), sizeof tr.version);
    out.write(reinterpret_cast<const char*>(&tr.len), sizeof tr.len);
    put(tr.obs);
    put(tr.next_obs);
    put(tr.actions);
    put(tr.rewards);
    put(tr.log_probs);
    put(tr.terminated);
    put(tr.truncated);
  }
  out.flush();
  if (!out) throw std::runtime_error("rollout storage " + file + ": write failed");
}

void RolloutStorage::load(const std::string& file) {
  clear();
  std::ifstream in(file, std::ios::binary | std::ios::ate);
  if (!in) throw std::runtime_error("rollout storage " + file + ": cannot open for reading");
  const int64_t file_bytes = in.tellg();
  in.seekg(0);
  RolloutHeader h{};
  if (file_bytes < int64_t(sizeof h) || !in.read(reinterpret_cast<char*>(&h), sizeof h))
    throw std::runtime_error("rollout storage " + file + ": truncated header");
  if (std::memcmp(h.magic, kRolloutMagic, sizeof kRolloutMagic) != 0)
    throw std::runtime_error("rollout storage " + file + ": not a rollout storage file (bad magic)");
  if (h.obs_dim != obs_dim_ || h.act_dim != act_dim_)
    throw std::runtime_error("rollout storage " + file + ": file has obs " + std::to_string(h.obs_dim) + ", act " +
                             std::to_string(h.act_dim) + ", expected obs " + std::to_string(obs_dim_) + ", act " +
                             std::to_string(act_dim_));
  const int od = obs_dim_, ad = act_dim_;
  // Every trajectory has at least one step: the counts are bounded by the file's size before any
  // allocation follows them.
  const int64_t least = int64_t(sizeof(uint64_t) + sizeof(int64_t)) + trajectory_bytes(1, od, ad);
  if (h.trajectories < 0 || h.steps < h.trajectories || h.trajectories > (file_bytes - int64_t(sizeof h)) / least)
    throw std::runtime_error("rollout storage " + file + ": inconsistent header (" + std::to_string(h.trajectories) +
                             " trajectories, " + std::to_string(h.steps) + " steps in " + std::to_string(file_bytes) +
                             " bytes)");
  int64_t left = file_bytes - int64_t(sizeof h), steps = 0;
  auto fail = [this, &file](const std::string& why) {
    clear();
    return std::runtime_error("rollout storage " + file + ": " + why + "; nothing restored");
  };
  auto get = [&in](auto& v, int64_t n) {
    v.resize(size_t(n));
    in.read(reinterpret_cast<char*>(v.data()), std::streamsize(size_t(n) * sizeof(v[0])));
  };
  for (int64_t k = 0; k < h.trajectories; ++k) {
    Trajectory tr;
    if (!in.read(reinterpret_cast<char*>(&tr.version), sizeof tr.version) ||
        !in.read(reinterpret_cast<char*>(&tr.len), sizeof tr.len))
      throw fail("truncated at trajectory " + std::to_string(k));
    left -= int64_t(sizeof tr.version + sizeof tr.len);
    if (tr.len <= 0 || tr.len > h.steps - steps || trajectory_bytes(tr.len, od, ad) > left)
      throw fail("trajectory " + std::to_string(k) + " has " + std::to_string(tr.len) +
                 " steps, past what the file holds");
    get(tr.obs, tr.len * od);
    get(tr.next_obs, tr.len * od);
    get(tr.actions, tr.len * ad);
    get(tr.rewards, tr.len);
    get(tr.log_probs, tr.len);
    get(tr.terminated, tr.len);
    get(tr.truncated, tr.len);
    if (!in) throw fail("read failed at trajectory " + std::to_string(k));
    left -= trajectory_bytes(tr.len, od, ad);
    steps += tr.len;
    trajs_.push_back(std::move(tr));
  }
  if (steps != h.steps || left != 0)
    throw fail(std::to_string(steps) + " steps read where the header says " + std::to_string(h.steps) + ", " +
               std::to_string(left) + " bytes left over");
  steps_ = steps;
}

void RolloutStorage::take(int64_t steps, const ValueFn& value, double gamma, double lambda, uint64_t current_version,
                          PpoSamples& out, const VTrace* vtrace, std::map<uint64_t, int64_t>* steps_by_version) {
  if (steps < 0 || steps > steps_)
    throw std::invalid_argument("RolloutStorage::take: " + std::to_string(steps) + " steps asked, " +
                                std::to_string(steps_) + " stored");
  const int od = obs_dim_, ad = act_dim_;
  out = PpoSamples{};
  out.n = steps;
  out.obs.reserve(size_t(steps) * od);
  out.actions.reserve(size_t(steps) * ad);
  // The values of every trajectory this fit touches, in one call of `value` (on a GPU, thousands
  // of 16-row calls cost more than the fit itself): obs of all of them, then all next_obs.
  int64_t rows = 0;
  size_t touched = 0;
  for (int64_t need = steps; need > 0 && touched < trajs_.size(); ++touched) {
    rows += trajs_[touched].len;
    need -= trajs_[touched].len;
  }
  std::vector<float> both(size_t(2 * rows) * od);
  auto at = both.begin();
  for (size_t i = 0; i < touched; ++i) at = std::copy(trajs_[i].obs.begin(), trajs_[i].obs.end(), at);
  for (size_t i = 0; i < touched; ++i) at = std::copy(trajs_[i].next_obs.begin(), trajs_[i].next_obs.end(), at);
  const std::vector<float> values = rows > 0 ? value(both.data(), 2 * rows) : std::vector<float>{};
  // V-trace: the current policy's log-probability of every touched step's action, one call too.
  std::vector<float> log_ratio;
  if (vtrace && rows > 0) {
    std::vector<float> acts(size_t(rows) * ad);
    auto a = acts.begin();
    for (size_t i = 0; i < touched; ++i) a = std::copy(trajs_[i].actions.begin(), trajs_[i].actions.end(), a);
    log_ratio = vtrace->log_prob(both.data(), acts.data(), rows);
    int64_t r = 0;
    for (size_t i = 0; i < touched; ++i)
      for (int64_t t = 0; t < trajs_[i].len; ++t, ++r)
        // The current version's own steps: the same policy, a ratio of exactly 1 (not float noise).
        log_ratio[r] = trajs_[i].version == current_version ? 0.f : log_ratio[r] - trajs_[i].log_probs[t];
  }
  std::vector<float> adv, ret;
  int64_t left = steps, offset = 0;
  while (left > 0) {
    Trajectory& tr = trajs_.front();
    const int64_t row0 = offset;
    const float* v = values.data() + row0;
    const float* nv = values.data() + rows + row0;
    offset += tr.len;
    adv.resize(tr.len);
    ret.resize(tr.len);
    // The last step bootstraps on its next observation unless it terminated: compute_gae treats
    // every step's next value that way, and cuts the chain only at episode ends.
    if (vtrace)
      compute_vtrace(tr.rewards.data(), v, nv, tr.terminated.data(), tr.truncated.data(), log_ratio.data() + row0,
                     tr.len, gamma, lambda, vtrace->rho_bar, vtrace->c_bar, adv.data(), ret.data());
    else
      compute_gae(tr.rewards.data(), v, nv, tr.terminated.data(), tr.truncated.data(), tr.len, gamma, lambda,
                  adv.data(), ret.data());
    const int64_t k = std::min(left, tr.len);
    if (steps_by_version) (*steps_by_version)[tr.version] += k;
    out.obs.insert(out.obs.end(), tr.obs.begin(), tr.obs.begin() + k * od);
    out.actions.insert(out.actions.end(), tr.actions.begin(), tr.actions.begin() + k * ad);
    out.behaviour_log_prob.insert(out.behaviour_log_prob.end(), tr.log_probs.begin(), tr.log_probs.begin() + k);
    out.current.insert(out.current.end(), size_t(k), tr.version == current_version ? 1 : 0);
    out.advantages.insert(out.advantages.end(), adv.begin(), adv.begin() + k);
    out.returns.insert(out.returns.end(), ret.begin(), ret.begin() + k);
    left -= k;
    steps_ -= k;
    if (k == tr.len) {
      trajs_.pop_front();
    } else {
      // Split: the tail is carried over, a trajectory of its own that starts mid-episode.
      tr.len -= k;
      tr.obs.erase(tr.obs.begin(), tr.obs.begin() + k * od);
      tr.next_obs.erase(tr.next_obs.begin(), tr.next_obs.begin() + k * od);
      tr.actions.erase(tr.actions.begin(), tr.actions.begin() + k * ad);
      tr.rewards.erase(tr.rewards.begin(), tr.rewards.begin() + k);
      tr.log_probs.erase(tr.log_probs.begin(), tr.log_probs.begin() + k);
      tr.terminated.erase(tr.terminated.begin(), tr.terminated.begin() + k);
      tr.truncated.erase(tr.truncated.begin(), tr.truncated.begin() + k);
    }
  }
}

}  // namespace farm
