// The worker's hot loop allocates nothing once warmed up: every heap allocation in this test
// binary is counted, C++ and C alike (malloc, calloc, realloc and the aligned allocations Eigen and
// MuJoCo use are replaced here and forwarded to glibc; operator new goes through malloc), and
// Rollout::collect must not make one after the first batches have sized every buffer, including
// batches in which episodes end (their records and final observations).
#include <gtest/gtest.h>

#include <atomic>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <new>
#include <random>

#include "mlp.h"
#include "rollout.h"
#include "task.h"

namespace {
std::atomic<uint64_t> g_allocations{0};
}  // namespace

// glibc's own entry points, under the names it exports for replacements like these.
extern "C" {
void* __libc_malloc(size_t);
void* __libc_calloc(size_t, size_t);
void* __libc_realloc(void*, size_t);
void* __libc_memalign(size_t, size_t);

void* malloc(size_t n) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  return __libc_malloc(n);
}
void* calloc(size_t k, size_t n) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  return __libc_calloc(k, n);
}
void* realloc(void* p, size_t n) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  return __libc_realloc(p, n);
}
void* memalign(size_t a, size_t n) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  return __libc_memalign(a, n);
}
void* aligned_alloc(size_t a, size_t n) { return memalign(a, n); }
int posix_memalign(void** out, size_t a, size_t n) {
  void* p = memalign(a, n);
  if (!p) return ENOMEM;
  *out = p;
  return 0;
}
}

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
  EXPECT_EQ(allocations, 0u) << allocations << " heap allocations in " << 3 * limit * envs << " env steps (" << envs
                             << " envs, " << threads << " threads)";
}

TEST(RolloutAllocation, CountingAllocatorSeesNewAndMalloc) {
  uint64_t before = g_allocations.load();
  auto p = std::make_unique<int>(1);
  EXPECT_EQ(*p, 1);
  EXPECT_GT(g_allocations.load(), before);
  before = g_allocations.load();
  void* volatile m = std::malloc(64);
  EXPECT_GT(g_allocations.load(), before);
  std::free(m);
  before = g_allocations.load();
  void* a = nullptr;
  ASSERT_EQ(posix_memalign(&a, 64, 256), 0);  // how Eigen and MuJoCo get aligned memory
  EXPECT_GT(g_allocations.load(), before);
  std::free(a);
}

TEST(RolloutAllocation, OneThreadCollectAllocatesNothing) { expect_no_allocation(8, 1); }

TEST(RolloutAllocation, SeveralThreadsCollectAllocatesNothing) { expect_no_allocation(16, 3); }

}  // namespace
