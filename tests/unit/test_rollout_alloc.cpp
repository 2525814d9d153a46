// The worker's hot loop allocates nothing once warmed up: every global operator new in this test
// binary is counted, and Rollout::collect must not call it after the first batches have sized
// every buffer, including batches in which episodes end (their records and final observations).
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <memory>
#include <new>
#include <random>

#include "mlp.h"
#include "rollout.h"
#include "task.h"

namespace {
std::atomic<uint64_t> g_allocations{0};
}  // namespace

void* operator new(std::size_t n) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t n) { return operator new(n); }
void* operator new(std::size_t n, const std::nothrow_t&) noexcept {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  return std::malloc(n ? n : 1);
}
void* operator new[](std::size_t n, const std::nothrow_t& t) noexcept { return operator new(n, t); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }

namespace {

farm::PolicyParams random_policy(const farm::robots::TaskSpec& s) {
  farm::PolicyParams p;
  p.layout = {{s.obs_dim, 64, 64, 2 * s.act_dim}, farm::Activation::kRelu};
  p.params.resize(p.layout.num_params());
  std::mt19937_64 rng(7);
  std::normal_distribution<float> normal(0.f, 0.3f);
  for (auto& v : p.params) v = normal(rng);
  return p;
}

// Steps `T`-step batches until `steps_per_env` steps have passed; returns the episodes seen.
size_t collect_for(farm::Rollout& r, farm::RolloutBatch& b, int T, int steps_per_env) {
  size_t episodes = 0;
  for (int done = 0; done < steps_per_env; done += T) {
    r.collect(T, b);
    episodes += b.episodes.size();
  }
  return episodes;
}

void expect_no_allocation(int envs, int threads) {
  std::shared_ptr<const farm::robots::Task> task = farm::robots::make_task({});
  const int limit = task->spec().max_episode_steps;
  ASSERT_GT(limit, 0);
  farm::Rollout rollout(task, envs, threads, 3);
  rollout.set_policy(random_policy(task->spec()));
  farm::RolloutBatch batch;
  const int T = 25;
  // Warm-up: two whole episodes per env, so every list has held a batch's worth of episode ends.
  ASSERT_GT(collect_for(rollout, batch, T, 2 * limit), 0u);

  const uint64_t before = g_allocations.load();
  const size_t episodes = collect_for(rollout, batch, T, 3 * limit);
  const uint64_t allocations = g_allocations.load() - before;
  EXPECT_GT(episodes, 0u) << "the measured batches must include episode ends";
  EXPECT_EQ(allocations, 0u) << allocations << " heap allocations in " << 3 * limit * envs
                             << " env steps (" << envs << " envs, " << threads << " threads)";
}

TEST(RolloutAllocation, CountingAllocatorSeesNew) {
  const uint64_t before = g_allocations.load();
  auto p = std::make_unique<int>(1);
  EXPECT_EQ(*p, 1);
  EXPECT_GT(g_allocations.load(), before);
}

TEST(RolloutAllocation, OneThreadCollectAllocatesNothing) { expect_no_allocation(8, 1); }

TEST(RolloutAllocation, SeveralThreadsCollectAllocatesNothing) { expect_no_allocation(16, 3); }

}  // namespace
