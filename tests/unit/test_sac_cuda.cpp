// The SAC update on the GPU: the CUDA graph, its queued replays and fused kernels against the eager
// update. Each test skips where no GPU and CUDA LibTorch are there.
#include "compute.h"
#include "device_replay.h"
#include "sac.h"
#include "sac_test_util.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

namespace farm {
namespace {

using namespace sac_test;

// Only where a GPU and a CUDA LibTorch are there: the CUDA-graph update (warm-up, capture, replays)
// computes what the eager CUDA update computes from the same start on the same batches, with the
// actor's step after the critics' and beside it (sac.actor_on_previous_critic).
TEST(SacCuda, GraphUpdateMatchesEager) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  for (const bool beside : {false, true}) {
    SCOPED_TRACE(beside ? "actor_on_previous_critic" : "actor after the critics");
    auto cfg = cuda_config();
    cfg.set_actor_on_previous_critic(beside);
    const auto eager_cfg = without_graph(cfg);
    Sac graph(cfg, 3, 2, 5), eager(eager_cfg, 3, 2, 5);
    if (!graph.uses_cuda_graph()) GTEST_SKIP() << "built against a LibTorch without CUDA";
    EXPECT_FALSE(eager.uses_cuda_graph());
    constexpr double kTol = 1e-3;
    // random_batch seeds the generators, so both instances draw the same policy noise.
    for (int k = 0; k < 30; ++k) {
      const SacStats g = graph.update(random_batch(64, 3, 2, 500 + k));
      const SacStats e = eager.update(random_batch(64, 3, 2, 500 + k));
      expect_stats_near(g, e, kTol, k);
    }
    EXPECT_EQ(graph.updates(), 30);
    EXPECT_LE(relative_difference(graph.actor_parameters(), eager.actor_parameters()), kTol);
    EXPECT_LE(relative_difference(graph.critic_parameters(), eager.critic_parameters()), kTol);
    EXPECT_LE(relative_difference(graph.target_critic_parameters(), eager.target_critic_parameters()), kTol);
  }
}

// The graph honours sac.actor_on_previous_critic through warm-ups, capture and replays: with a
// large critic step the two orders give actors far apart, and the graph's actor is the eager
// update's of the same order (a graph that ignored the option, or raced the critics' step against
// the actor's reading of them, would not be).
TEST(SacCuda, GraphHonoursTheActorOrder) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  auto cfg = cuda_config();
  cfg.set_cuda_tf32(false);
  cfg.set_critic_lr(0.1);
  cfg.set_actor_on_previous_critic(true);
  const auto eager_cfg = without_graph(cfg);
  auto after_cfg = eager_cfg;
  after_cfg.set_actor_on_previous_critic(false);
  Sac graph(cfg, 3, 2, 5), eager(eager_cfg, 3, 2, 5), after(after_cfg, 3, 2, 5);
  if (!graph.uses_cuda_graph()) GTEST_SKIP() << "built against a LibTorch without CUDA";
  for (int k = 0; k < 8; ++k) {
    graph.update(random_batch(64, 3, 2, 800 + k));
    eager.update(random_batch(64, 3, 2, 800 + k));
    after.update(random_batch(64, 3, 2, 800 + k));
  }
  const double same = relative_difference(graph.actor_parameters(), eager.actor_parameters());
  const double other = relative_difference(graph.actor_parameters(), after.actor_parameters());
  EXPECT_LE(same, 1e-3);
  EXPECT_GT(other, 10 * same) << "the graph's actor is as near the other order's as its own";
}

// A learning-rate scale set between updates reaches the captured graph (its fused Adam holds the
// rate as a constant, so the graph is captured again) as it reaches the eager update. The batch
// keeps its size here, which alone would not make a new capture: a graph kept from before the
// scale would move the networks by the old rate and part from the eager instance.
TEST(SacCuda, GraphFollowsALearningRateScale) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  auto cfg = cuda_config();
  cfg.set_cuda_tf32(false);
  const auto eager_cfg = without_graph(cfg);
  Sac graph(cfg, 3, 2, 5), eager(eager_cfg, 3, 2, 5);
  if (!graph.uses_cuda_graph()) GTEST_SKIP() << "built against a LibTorch without CUDA";
  constexpr double kTol = 1e-3;
  int k = 0;
  for (; k < 10; ++k) {
    graph.update(random_batch(64, 3, 2, 600 + k));
    eager.update(random_batch(64, 3, 2, 600 + k));
  }
  for (const double scale : {4.0, 1.0}) {
    graph.scale_learning_rates(scale);
    eager.scale_learning_rates(scale);
    for (const int stop = k + 10; k < stop; ++k) {
      const SacStats g = graph.update(random_batch(64, 3, 2, 600 + k));
      const SacStats e = eager.update(random_batch(64, 3, 2, 600 + k));
      expect_stats_near(g, e, kTol, k);
    }
    EXPECT_LE(relative_difference(graph.critic_parameters(), eager.critic_parameters()), kTol) << "scale " << scale;
    EXPECT_LE(relative_difference(graph.actor_parameters(), eager.actor_parameters()), kTol) << "scale " << scale;
  }
}

// The optimizer state of graph updates goes through save/load: into an eager instance, and into a
// graph instance that must capture again, both then update as the saved one does.
TEST(SacCuda, GraphStateSurvivesSaveLoad) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  const auto cfg = cuda_config();
  const auto eager_cfg = without_graph(cfg);
  Sac graph(cfg, 3, 2, 5);
  if (!graph.uses_cuda_graph()) GTEST_SKIP() << "built against a LibTorch without CUDA";
  int k = 0;
  for (; k < 30; ++k) graph.update(random_batch(64, 3, 2, 500 + k));
  const std::string dir = temp_dir("sac_cuda_graph");
  graph.save(dir);
  Sac loaded_eager(eager_cfg, 3, 2, 9), loaded_graph(cfg, 3, 2, 9);
  loaded_eager.load(dir);
  loaded_graph.load(dir);
  EXPECT_EQ(loaded_graph.updates(), 30);
  constexpr double kTol = 1e-3;
  for (; k < 40; ++k) {
    const SacStats e = loaded_eager.update(random_batch(64, 3, 2, 500 + k));
    const SacStats g = loaded_graph.update(random_batch(64, 3, 2, 500 + k));
    const SacStats o = graph.update(random_batch(64, 3, 2, 500 + k));
    expect_stats_near(g, e, kTol, k);
    expect_stats_near(o, e, kTol, k);
  }
  EXPECT_LE(relative_difference(loaded_graph.actor_parameters(), loaded_eager.actor_parameters()), kTol);
  EXPECT_LE(relative_difference(graph.critic_parameters(), loaded_eager.critic_parameters()), kTol);
  farm::remove_tree(dir);
}

// Only where a GPU and a CUDA LibTorch are there: queued graph replays (groups that take in the
// warm-ups and the capture, and ones longer than the pinned slots) compute what one update at a
// time computes, kernel for kernel. A group may return before its last replays have run: every
// update is then either returned or in flight, and finish_updates() gives the rest, in order.
TEST(SacCuda, QueuedUpdatesMatchOneAtATime) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  const auto cfg = cuda_config();
  Sac one(cfg, 3, 2, 5), queued(cfg, 3, 2, 5);
  if (!one.uses_cuda_graph()) GTEST_SKIP() << "built against a LibTorch without CUDA";
  std::vector<SacStats> want;
  for (int k = 0; k < 80; ++k) want.push_back(one.update(random_batch(64, 3, 2, 500 + k)));
  int k = 0;
  auto next = [&] { return random_batch(64, 3, 2, 500 + k++); };
  std::vector<SacStats> got;
  int asked = 0;
  for (int n : {6, 1, 38, 8, 27}) {
    const auto part = queued.update_n(n, next);
    asked += n;
    got.insert(got.end(), part.begin(), part.end());
    EXPECT_EQ(int64_t(got.size()) + queued.updates_in_flight(), asked);
    EXPECT_LE(queued.updates_in_flight(), 16);  // the pinned slots
  }
  const auto rest = queued.finish_updates();
  got.insert(got.end(), rest.begin(), rest.end());
  EXPECT_EQ(queued.updates_in_flight(), 0);
  EXPECT_TRUE(queued.finish_updates().empty());
  ASSERT_EQ(got.size(), want.size());
  EXPECT_EQ(queued.updates(), 80);
  for (size_t i = 0; i < want.size(); ++i) expect_stats_near(got[i], want[i], 1e-6, int(i));
  EXPECT_LE(relative_difference(queued.actor_parameters(), one.actor_parameters()), 1e-6);
  EXPECT_LE(relative_difference(queued.critic_parameters(), one.critic_parameters()), 1e-6);
  EXPECT_LE(relative_difference(queued.target_critic_parameters(), one.target_critic_parameters()), 1e-6);
}

// Only where a GPU, a CUDA LibTorch and a CUDA compiler are there: the fused kernels (the policy's
// sample and its gradient, the critics' target, the actor's loss) compute in the graph what torch's
// ops compute there, from the same start on the same batches and noise. The log std bounds clamp
// part of the actor's output, where the gradient must stop; every figure and parameter depends on
// all four kernels. Full FP32, so only the kernels' float rounding differs.
TEST(SacCuda, FusedKernelsMatchTorchOps) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  auto cfg = cuda_config();
  cfg.set_cuda_tf32(false);
  cfg.set_log_std_min(-0.3);
  cfg.set_log_std_max(0.2);
  auto ops_cfg = cfg;
  ops_cfg.set_cuda_fused_kernels(false);
  Sac fused(cfg, 3, 2, 5), ops(ops_cfg, 3, 2, 5);
  if (!fused.uses_fused_kernels()) GTEST_SKIP() << "built without a CUDA compiler (no fused kernels)";
  EXPECT_TRUE(ops.uses_cuda_graph());
  EXPECT_FALSE(ops.uses_fused_kernels());
  for (int k = 0; k < 40; ++k) {
    const SacStats f = fused.update(random_batch(64, 3, 2, 700 + k));
    const SacStats o = ops.update(random_batch(64, 3, 2, 700 + k));
    expect_stats_near(f, o, 1e-4, k);
  }
  EXPECT_LE(relative_difference(fused.actor_parameters(), ops.actor_parameters()), 1e-4);
  EXPECT_LE(relative_difference(fused.critic_parameters(), ops.critic_parameters()), 1e-4);
  EXPECT_LE(relative_difference(fused.target_critic_parameters(), ops.target_critic_parameters()), 1e-4);
}

// The large-batch path: odd widths (an observation of 17, an action of 6) padded to 8-aligned
// products from 1,024 rows on, the critics' hidden layers as one product and one bias-and-ReLU
// pass (with the bias gradient as a product), the actor's loss as a two-stage reduction over
// 2,048 rows, in float32 and in bfloat16 (sac.matmul_dtype): the same update as torch's ops, and
// bfloat16 near float32.
TEST(SacCuda, LargeBatchPathMatchesTorchOps) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  constexpr int kObs = 17, kAct = 6, kRows = 2048, kUpdates = 10;
  std::vector<SacStats> float32_stats;
  for (const std::string dtype : {"float32", "bfloat16"}) {
    SCOPED_TRACE(dtype);
    auto cfg = cuda_config();
    cfg.set_cuda_tf32(false);
    cfg.set_matmul_dtype(dtype);
    auto ops_cfg = cfg;
    ops_cfg.set_cuda_fused_kernels(false);
    Sac fused(cfg, kObs, kAct, 5), ops(ops_cfg, kObs, kAct, 5);
    if (!fused.uses_fused_kernels()) GTEST_SKIP() << "built without a CUDA compiler (no fused kernels)";
    // bfloat16 rounds each product's output to 8 bits of mantissa, where the two paths round at
    // different points (after the bias in one, in the product's epilogue in the other).
    const double tol = dtype == "float32" ? 1e-4 : 2e-2;
    for (int k = 0; k < kUpdates; ++k) {
      const SacStats f = fused.update(random_batch(kRows, kObs, kAct, 900 + k));
      const SacStats o = ops.update(random_batch(kRows, kObs, kAct, 900 + k));
      expect_stats_near(f, o, tol, k);
      if (dtype == "float32")
        float32_stats.push_back(f);
      else
        expect_stats_near(f, float32_stats[k], 5e-2, k);
    }
    EXPECT_LE(relative_difference(fused.actor_parameters(), ops.actor_parameters()), tol);
    EXPECT_LE(relative_difference(fused.critic_parameters(), ops.critic_parameters()), tol);
  }
}

// Only where a GPU and a CUDA LibTorch are there: a graph that draws its own batches from a replay
// on the GPU (sac.replay_on_device), queued as the learner queues them, computes what the eager
// update computes drawing the same rows, with torch's ops and with the fused kernels (the gather).
TEST(SacCuda, GraphDrawsItsBatchesAsTheEagerUpdateDoes) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  for (const bool fused : {false, true}) {
    SCOPED_TRACE(fused ? "fused kernels" : "torch's ops");
    auto cfg = cuda_config();
    cfg.set_cuda_tf32(false);
    cfg.set_cuda_fused_kernels(fused);
    Sac graph(cfg, 3, 2, 5), eager(without_graph(cfg), 3, 2, 5);
    if (!graph.uses_cuda_graph()) GTEST_SKIP() << "built against a LibTorch without CUDA";
    if (fused && !graph.uses_fused_kernels()) GTEST_SKIP() << "built without a CUDA compiler (no fused kernels)";
    ReplayBuffer host(4000, 3, 2);
    DeviceReplay dev(4000, 3, 2, torch::Device(torch::kCUDA, 0), 0.99);
    fill_replays(host, dev, 1000, 31);
    std::vector<SacStats> got;
    torch::manual_seed(41);
    for (int n : {6, 1, 38, 8, 27}) {
      const auto part = graph.update_n_from(n, 64, dev);
      got.insert(got.end(), part.begin(), part.end());
      EXPECT_LE(graph.updates_in_flight(), 16);
    }
    const auto rest = graph.finish_updates();
    got.insert(got.end(), rest.begin(), rest.end());
    torch::manual_seed(41);
    const auto want = eager.update_n_from(80, 64, dev);
    ASSERT_EQ(got.size(), want.size());
    for (size_t i = 0; i < want.size(); ++i) expect_stats_near(got[i], want[i], 1e-4, int(i));
    EXPECT_LE(relative_difference(graph.actor_parameters(), eager.actor_parameters()), 1e-4);
    EXPECT_LE(relative_difference(graph.critic_parameters(), eager.critic_parameters()), 1e-4);
    EXPECT_LE(relative_difference(graph.target_critic_parameters(), eager.target_critic_parameters()), 1e-4);
    // Rows added between groups are drawn by the replays queued after them.
    fill_replays(host, dev, 3000, 37);
    EXPECT_EQ(dev.size(), 4000);
    const auto more = graph.update_n_from(8, 64, dev);
    const auto last = graph.finish_updates();
    EXPECT_EQ(more.size() + last.size(), 8u);
  }
}

}  // namespace
}  // namespace farm
