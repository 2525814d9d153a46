#include "rollout.h"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <stdexcept>
#include <string>

namespace farm {

namespace {

// Stream tags keep the noise generators independent of the envs' reset-seed streams.
constexpr uint64_t kNoiseStream = 0x6e6f697365ull;  // "noise"

void check_fits(const Policy& p, const robots::TaskSpec& s) {
  if (p.obs_dim() != s.obs_dim || p.act_dim() != s.act_dim) {
    throw std::invalid_argument("policy obs/act sizes " + std::to_string(p.obs_dim()) + "/" +
                                std::to_string(p.act_dim()) + " do not fit task '" + s.name + "' (" +
                                std::to_string(s.obs_dim) + "/" + std::to_string(s.act_dim) + ")");
  }
  if (p.num_actions() != s.num_actions) {
    throw std::invalid_argument("policy has " + std::to_string(p.num_actions()) + " discrete actions, task '" + s.name +
                                "' has " + std::to_string(s.num_actions) + " (0: continuous)");
  }
}

}  // namespace

Rollout::Rollout(std::shared_ptr<const robots::Task> task, int num_envs, int num_threads, uint64_t seed)
    : env_(std::move(task), num_envs, seed) {
  if (num_threads < 1) {
    throw std::invalid_argument("Rollout: num_threads must be >= 1, got " + std::to_string(num_threads));
  }
  const int K = std::min(num_threads, num_envs);
  env_.reset_all();
  const uint64_t noise_seed = mix_seed(seed, kNoiseStream);
  noise_rng_.reserve(num_envs);
  for (int i = 0; i < num_envs; ++i) noise_rng_.emplace_back(mix_seed(noise_seed, uint64_t(i)));
  chunks_.resize(K);
  for (int k = 0; k < K; ++k) {
    chunks_[k].begin = int(int64_t(k) * num_envs / K);
    chunks_[k].end = int(int64_t(k + 1) * num_envs / K);
  }
  for (int k = 1; k < K; ++k) threads_.emplace_back(&Rollout::thread_main, this, k);
}

Rollout::~Rollout() {
  {
    std::lock_guard<std::mutex> lk(mu_);
    stop_ = true;
  }
  start_cv_.notify_all();
  for (auto& t : threads_) t.join();
}

void Rollout::set_policy(const PolicyParams& p) {
  Policy policy(p);
  check_fits(policy, env_.spec());
  for (auto& c : chunks_) c.policy = policy;
  version_ = p.version;
  has_policy_ = true;
}

void Rollout::set_exploration_scales(double lo, double hi) {
  if (!(lo > 0 && lo <= hi))
    throw std::invalid_argument("Rollout: exploration scales must satisfy 0 < min <= max, got " + std::to_string(lo) +
                                " and " + std::to_string(hi));
  scale_.clear();
  if (lo == 1 && hi == 1) return;
  scale_lo_ = float(lo);
  scale_hi_ = float(hi);
  scale_.resize(size_t(env_.num_envs()));
  for (int i = 0; i < env_.num_envs(); ++i) scale_[size_t(i)] = draw_scale(i);
}

float Rollout::draw_scale(int env) {
  std::uniform_real_distribution<float> u(scale_lo_, scale_hi_);
  return u(noise_rng_[size_t(env)]);
}

void Rollout::thread_main(int k) {
  uint64_t seen = 0;
  for (;;) {
    {
      std::unique_lock<std::mutex> lk(mu_);
      start_cv_.wait(lk, [&] { return stop_ || generation_ != seen; });
      if (stop_) return;
      seen = generation_;
    }
    std::exception_ptr err;
    try {
      run_chunk(chunks_[k], job_T_, *job_out_);
    } catch (...) {
      err = std::current_exception();
    }
    std::lock_guard<std::mutex> lk(mu_);
    if (err && !error_) error_ = err;
    if (--pending_ == 0) done_cv_.notify_one();
  }
}

void Rollout::run_chunk(Chunk& c, int T, RolloutBatch& out) {
  const int N = env_.num_envs(), od = env_.obs_dim(), ad = env_.act_dim();
  const int b = c.begin, rows = c.end - c.begin;
  c.ends.clear();
  c.end_index.clear();
  // Two clock reads per step of the chunk (tens of ns) against microseconds of work per env.
  using Clock = std::chrono::steady_clock;
  Clock::duration infer{}, simulate{};
  for (int t = 0; t < T; ++t) {
    const size_t row0 = size_t(t) * N;
    const auto t0 = Clock::now();
    float* obs_t = out.obs.data() + (row0 + b) * od;
    std::memcpy(obs_t, env_.obs(b), sizeof(float) * rows * od);
    c.policy.act_per_row(obs_t, rows, noise_rng_.data() + b, false, out.actions.data() + (row0 + b) * ad,
                         out.log_probs.data() + row0 + b, scale_.empty() ? nullptr : scale_.data() + b);
    const int before = c.ends.size();
    const auto t1 = Clock::now();
    env_.step_range(b, c.end, out.actions.data() + row0 * ad, out.rewards.data() + row0, out.terminated.data() + row0,
                    out.truncated.data() + row0, c.ends);
    const auto t2 = Clock::now();
    infer += t1 - t0;
    simulate += t2 - t1;
    for (int i = before; i < c.ends.size(); ++i) {
      c.end_index.push_back(uint32_t(row0 + c.ends.env(i)));
      // A new episode, a new noise factor (the chunk owns its envs' entries and generators).
      if (!scale_.empty()) scale_[size_t(c.ends.env(i))] = draw_scale(c.ends.env(i));
    }
  }
  std::memcpy(out.next_obs.data() + size_t(b) * od, env_.obs(b), sizeof(float) * rows * od);
  c.infer_s += std::chrono::duration<double>(infer).count();
  c.simulate_s += std::chrono::duration<double>(simulate).count();
}

Rollout::Timing Rollout::timing() const {
  Timing t;
  for (const auto& c : chunks_) {
    t.infer_s += c.infer_s;
    t.simulate_s += c.simulate_s;
  }
  t.collect_s = collect_s_;
  return t;
}

void Rollout::collect(int T, RolloutBatch& out) {
  if (!has_policy_) throw std::logic_error("Rollout::collect: no policy set");
  if (T < 1) {
    throw std::invalid_argument("Rollout::collect: T must be >= 1, got " + std::to_string(T));
  }
  const auto start = std::chrono::steady_clock::now();
  const int N = env_.num_envs();
  out.resize(T, N, env_.obs_dim(), env_.act_dim());
  out.policy_version = version_;

  {
    std::lock_guard<std::mutex> lk(mu_);
    job_T_ = T;
    job_out_ = &out;
    error_ = nullptr;
    pending_ = int(threads_.size());
    ++generation_;
  }
  start_cv_.notify_all();
  std::exception_ptr err;
  try {
    run_chunk(chunks_[0], T, out);
  } catch (...) {
    err = std::current_exception();
  }
  {
    std::unique_lock<std::mutex> lk(mu_);
    done_cv_.wait(lk, [&] { return pending_ == 0; });
    if (!err) err = error_;
    job_out_ = nullptr;
  }
  if (err) std::rethrow_exception(err);

  merge_ends(out);
  env_steps_ += uint64_t(T) * uint64_t(N);
  collect_s_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

void Rollout::merge_ends(RolloutBatch& out) {
  merge_order_.clear();
  for (int k = 0; k < int(chunks_.size()); ++k) {
    for (int i = 0; i < chunks_[k].ends.size(); ++i) {
      merge_order_.push_back({chunks_[k].end_index[i], {k, i}});
    }
  }
  std::sort(merge_order_.begin(), merge_order_.end());
  const int od = env_.obs_dim();
  out.final_index.reserve(merge_order_.size());
  out.final_obs.reserve(merge_order_.size() * od);
  out.episodes.reserve(merge_order_.size());
  for (const auto& [index, where] : merge_order_) {
    const EpisodeEnds& ends = chunks_[where.first].ends;
    out.final_index.push_back(index);
    const float* f = ends.final_obs(where.second);
    out.final_obs.insert(out.final_obs.end(), f, f + od);
    out.add_episode() = ends.record(where.second);  // copy-assigning reuses metrics storage
  }
}

std::vector<EpisodeRecord> evaluate_policy(std::shared_ptr<const robots::Task> task, const PolicyParams& params,
                                           int episodes, uint64_t seed, const std::atomic<bool>* cancel,
                                           uint32_t first_episode, const EvaluationStep& on_step) {
  if (episodes <= 0) return {};
  Policy policy(params);
  VecEnv env(std::move(task), episodes, seed, first_episode);
  check_fits(policy, env.spec());
  const int max_steps = env.spec().max_episode_steps;
  if (max_steps <= 0) {
    throw std::invalid_argument("evaluate_policy: task '" + env.spec().name +
                                "' has no time limit, an episode might never end");
  }
  const int N = env.num_envs();
  if (const int conditions = env.task().eval_conditions(); conditions > 0) {
    for (int i = 0; i < N; ++i) env.reset_in_condition(i, int((uint64_t(first_episode) + uint64_t(i)) % conditions));
  } else {
    env.reset_all();
  }
  std::vector<float> actions(size_t(N) * env.act_dim()), rewards(N);
  std::vector<uint8_t> terminated(N), truncated(N);
  std::vector<EpisodeRecord> records(N);
  std::vector<uint8_t> done(N, 0);
  int remaining = N;
  std::mt19937_64 unused_rng;  // the deterministic policy draws no noise
  EpisodeEnds ends;
  // Every episode ends within max_steps (truncation); envs that finish early keep stepping
  // into a next episode, which is ignored.
  for (int step = 0; step < max_steps && remaining > 0; ++step) {
    if (cancel && *cancel) return {};
    policy.act(env.obs(), N, unused_rng, true, actions.data(), nullptr);
    if (on_step) on_step(env.obs(), actions.data(), N);
    ends.clear();
    env.step_range(0, N, actions.data(), rewards.data(), terminated.data(), truncated.data(), ends);
    for (int i = 0; i < ends.size(); ++i) {
      const int e = ends.env(i);
      if (done[e]) continue;
      done[e] = 1;
      records[e] = ends.record(i);
      --remaining;
    }
  }
  if (remaining > 0) {
    throw std::logic_error("evaluate_policy: task '" + env.spec().name + "' ran past its " + std::to_string(max_steps) +
                           "-step limit without ending");
  }
  return records;
}

}  // namespace farm
