// SAC's update on CUDA captured as one CUDA graph (a handful of launches instead of a few hundred),
// built only against a CUDA LibTorch (FARM_CUDA_GRAPHS, learner/algorithms/CMakeLists.txt).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <deque>
#include <stdexcept>
#include <tuple>

#include "sac_impl.h"

#ifdef FARM_CUDA_GRAPHS
#include <ATen/cuda/CUDAEvent.h>
#include <ATen/cuda/CUDAGraph.h>
#include <c10/cuda/CUDAFunctions.h>
#include <c10/cuda/CUDAGuard.h>
#include <c10/cuda/CUDAStream.h>
#endif
#ifdef FARM_CUDA_GRAPHS
#include "cuda_graph_update.h"
#endif
#ifdef FARM_CUDA_KERNELS
#include "sac_cuda_kernels.h"
#endif

namespace farm {

using namespace sac_detail;

#ifdef FARM_CUDA_KERNELS
constexpr bool kFusedKernelsBuilt = true;
#else
constexpr bool kFusedKernelsBuilt = false;
#endif

#ifdef FARM_CUDA_GRAPHS
namespace {

#ifdef FARM_CUDA_KERNELS
// The fused kernels (sac_cuda_kernels.h) as autograd functions, on the current CUDA stream (in
// backward, the stream of the forward, as autograd runs it).
void launched(cudaError_t e, const char* what) {
  if (e != cudaSuccess)
    throw std::runtime_error(std::string("sac fused kernel ") + what + ": " + cudaGetErrorString(e));
}

cudaStream_t current_stream() { return c10::cuda::getCurrentCUDAStream().stream(); }

// Float32 on CUDA, contiguous, of `rows` rows (a view made contiguous where it is not).
torch::Tensor kernel_input(const torch::Tensor& t, int64_t rows, const char* what) {
  if (!t.is_cuda() || t.scalar_type() != torch::kFloat || (t.dim() > 0 && t.size(0) != rows))
    throw std::invalid_argument(std::string("sac fused kernel: ") + what + " must be a float32 CUDA tensor of " +
                                std::to_string(rows) + " rows");
  return t.contiguous();
}

// Impl::sample's tanh-squashed Gaussian from the actor's output [B, 2A] and the drawn noise [B, A]:
// (action [B, A], log_prob [B]) in one kernel, its gradient to the output in one more.
struct SquashedSample : torch::autograd::Function<SquashedSample> {
  static torch::autograd::variable_list forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& out_in,
                                                const torch::Tensor& noise_in, double lo, double hi) {
    const int64_t B = out_in.size(0), A = noise_in.size(1);
    const auto out = kernel_input(out_in, B, "actor output"), noise = kernel_input(noise_in, B, "noise");
    if (out.size(1) != 2 * A) throw std::invalid_argument("sac fused kernel: actor output is not [B, 2 * act]");
    auto action = torch::empty({B, A}, out.options());
    auto log_prob = torch::empty({B}, out.options());
    launched(sac_kernels::squashed_sample_forward(out.data_ptr<float>(), noise.data_ptr<float>(),
                                                  action.data_ptr<float>(), log_prob.data_ptr<float>(), int(B), int(A),
                                                  float(lo), float(hi), current_stream()),
             "squashed_sample_forward");
    ctx->set_materialize_grads(false);
    ctx->save_for_backward({out, noise, action});
    ctx->saved_data["lo"] = lo;
    ctx->saved_data["hi"] = hi;
    return {action, log_prob};
  }
  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const torch::Tensor &out = saved[0], &noise = saved[1], &action = saved[2];
    const int64_t B = out.size(0), A = noise.size(1);
    torch::Tensor g_action = grads[0], g_log_prob = grads[1];
    if (g_action.defined() && (g_action.dim() != 2 || g_action.stride(1) != 1)) g_action = g_action.contiguous();
    if (g_log_prob.defined()) g_log_prob = kernel_input(g_log_prob, B, "log_prob gradient");
    auto g_out = torch::empty_like(out);
    launched(
        sac_kernels::squashed_sample_backward(
            out.data_ptr<float>(), noise.data_ptr<float>(), action.data_ptr<float>(),
            g_action.defined() ? g_action.data_ptr<float>() : nullptr, g_action.defined() ? int(g_action.stride(0)) : 0,
            g_log_prob.defined() ? g_log_prob.data_ptr<float>() : nullptr, g_out.data_ptr<float>(), int(B), int(A),
            float(ctx->saved_data["lo"].toDouble()), float(ctx->saved_data["hi"].toDouble()), current_stream()),
        "squashed_sample_backward");
    return {g_out, torch::Tensor(), torch::Tensor(), torch::Tensor()};
  }
};

// The actor's loss mean(alpha * log_prob - min(q[0], q[1])) from q [2, B], log_prob [B] and the
// temperature alpha [1] (held fixed): one two-stage reduction, its gradient in one kernel more.
struct ActorObjective : torch::autograd::Function<ActorObjective> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& q_in,
                               const torch::Tensor& log_prob_in, const torch::Tensor& alpha_in) {
    const int64_t B = log_prob_in.size(0);
    const auto q = kernel_input(q_in, 2, "q"), log_prob = kernel_input(log_prob_in, B, "log_prob");
    const auto alpha = kernel_input(alpha_in, 1, "alpha");
    if (q.size(1) != B) throw std::invalid_argument("sac fused kernel: q is not [2, B]");
    auto loss = torch::empty({}, q.options());
    auto partial = torch::empty({sac_kernels::actor_objective_partials(int(B))}, q.options());
    launched(sac_kernels::actor_objective_forward(q.data_ptr<float>(), log_prob.data_ptr<float>(),
                                                  alpha.data_ptr<float>(), partial.data_ptr<float>(),
                                                  loss.data_ptr<float>(), int(B), current_stream()),
             "actor_objective_forward");
    ctx->save_for_backward({q, alpha});
    return loss;
  }
  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const torch::Tensor &q = saved[0], &alpha = saved[1];
    const int64_t B = q.size(1);
    const auto g_loss = kernel_input(grads[0].reshape({1}), 1, "loss gradient");
    auto g_q = torch::empty_like(q);
    auto g_log_prob = torch::empty({B}, q.options());
    launched(sac_kernels::actor_objective_backward(q.data_ptr<float>(), alpha.data_ptr<float>(),
                                                   g_loss.data_ptr<float>(), g_q.data_ptr<float>(),
                                                   g_log_prob.data_ptr<float>(), int(B), current_stream()),
             "actor_objective_backward");
    return {g_q, g_log_prob, torch::Tensor()};
  }
};

// A critic layer as sac_detail::TwinLayerFn: the product by cuBLAS, the bias and ReLU in one pass
// over it (torch's baddbmm first writes the broadcast bias into the output, a pass of its own, and
// ReLU is another); backward: ReLU's mask and the bias gradient (the sum over the batch, which
// torch reduces in a pass of its own) in one pass, then the two products.
struct TwinLayer : torch::autograd::Function<TwinLayer> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x, const torch::Tensor& w,
                               const torch::Tensor& b, bool relu) {
    auto y = torch::bmm(x, w);
    const auto bias = b.contiguous();
    launched(sac_kernels::bias_relu_forward(y.data_ptr(), bias.data_ptr(), y.numel(), int(y.size(2)), y.size(1), relu,
                                            y.scalar_type() == torch::kBFloat16, current_stream()),
             "bias_relu_forward");
    ctx->save_for_backward({x, w, y});
    ctx->saved_data["relu"] = relu;
    return y;
  }
  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const torch::Tensor &x = saved[0], &w = saved[1], &y = saved[2];
    torch::Tensor g = grads[0].contiguous(), g_b;
    const bool bf16 = y.scalar_type() == torch::kBFloat16;
    if (ctx->saved_data["relu"].toBool() && y.size(2) / (bf16 ? 8 : 4) <= 256) {
      // ReLU's mask and the bias gradient in one pass (per-chunk sums, then a sum over chunks).
      auto g_in = torch::empty_like(y);
      auto partial = torch::empty({y.size(0), sac_kernels::relu_backward_bias_chunks(y.size(1)), y.size(2)},
                                  y.options().dtype(torch::kFloat));
      launched(sac_kernels::relu_backward_bias(y.data_ptr(), g.data_ptr(), g_in.data_ptr(), partial.data_ptr<float>(),
                                               int(y.size(0)), y.size(1), int(y.size(2)), bf16, current_stream()),
               "relu_backward_bias");
      g = g_in;
      if (ctx->needs_input_grad(2)) g_b = partial.sum(1, /*keepdim=*/true).to(y.scalar_type());
    } else if (ctx->saved_data["relu"].toBool()) {
      auto g_in = torch::empty_like(y);
      launched(
          sac_kernels::relu_backward(y.data_ptr(), g.data_ptr(), g_in.data_ptr(), y.numel(), bf16, current_stream()),
          "relu_backward");
      g = g_in;
    }
    torch::Tensor g_x, g_w;
    if (ctx->needs_input_grad(0)) g_x = torch::bmm(g, w.transpose(1, 2));
    if (ctx->needs_input_grad(1)) g_w = torch::bmm(x.transpose(1, 2), g);
    if (ctx->needs_input_grad(2) && !g_b.defined())
      g_b = torch::bmm(torch::ones({g.size(0), 1, g.size(1)}, g.options()), g);
    return {g_x, g_w, g_b, torch::Tensor()};
  }
};

torch::Tensor twin_layer(const torch::Tensor& x, const torch::Tensor& w, const torch::Tensor& b, bool relu) {
  // The kernels' shapes: 16-byte packs of a row, float32 or bfloat16 on CUDA; else torch's ops.
  const int pack = x.scalar_type() == torch::kBFloat16 ? 8 : 4;
  if (!x.is_cuda() || w.size(2) % pack != 0 || x.scalar_type() != w.scalar_type() ||
      (x.scalar_type() != torch::kFloat && x.scalar_type() != torch::kBFloat16)) {
    auto y = torch::baddbmm(b, x, w);
    return relu ? y.relu_() : y;
  }
  return TwinLayer::apply(x, w, b, relu);
}

// The critics' target r + gamma * (1 - done) * (min(next_q[0], next_q[1]) - alpha * next_log_prob).
torch::Tensor fused_soft_target(const torch::Tensor& next_q_in, const torch::Tensor& next_log_prob_in,
                                const torch::Tensor& alpha_in, const torch::Tensor& rewards_in,
                                const torch::Tensor& terminated_in, double gamma) {
  const int64_t B = rewards_in.size(0);
  const auto next_q = kernel_input(next_q_in, 2, "next_q"),
             next_log_prob = kernel_input(next_log_prob_in, B, "log_prob");
  const auto alpha = kernel_input(alpha_in, 1, "alpha"), rewards = kernel_input(rewards_in, B, "rewards");
  const auto terminated = kernel_input(terminated_in, B, "terminated");
  if (next_q.size(1) != B) throw std::invalid_argument("sac fused kernel: next_q is not [2, B]");
  auto target = torch::empty({B}, rewards.options());
  launched(sac_kernels::soft_target(next_q.data_ptr<float>(), next_log_prob.data_ptr<float>(), alpha.data_ptr<float>(),
                                    rewards.data_ptr<float>(), terminated.data_ptr<float>(), float(gamma),
                                    target.data_ptr<float>(), int(B), current_stream()),
           "soft_target");
  return target;
}
#endif  // FARM_CUDA_KERNELS

}  // namespace

// One update captured as a CUDA graph. Its inputs are static device tensors that each update
// overwrites with the sampled batch (one pinned host buffer, one host-to-device copy), or, for a
// graph built on a DeviceReplay (graph_update_n_from), that its first two kernels fill with rows
// drawn from the replay on the GPU (draw_batch), so the host only launches replays; its output
// is a static tensor of the six figures, read back with one copy. Replays can be queued
// (graph_update_n): each queued update stages its batch in a pinned buffer of its own and reads
// its figures back into a pinned slot of its own, and the stream's order keeps every copy between
// the replays it belongs to. The slots are a ring: a replay's slot is used again only after the
// event recorded behind its figures' copy has passed, so replays may still be running when
// graph_update_n returns, and the next call queues behind them. The policy's sampling noise is
// drawn inside the graph from the default CUDA generator, which graph capture registers: each
// replay advances the generator's philox offset by what the captured kernels consume, so a replay
// draws the same numbers the eager ops would from the same generator state.
//
// The update is a chain of small kernels, so what bounds a replay is the length of its longest
// dependency chain, not the kernel count. Three parts that the rest does not wait for run on side
// streams, which capture turns into parallel branches of the graph: the critic target (the
// policy's sample on next_obs and the target critics) from the start until the critic loss; the
// temperature step after the policy's sample on obs; the polyak update after the critic step; with
// sac.actor_on_previous_critic, the actor's step from the policy's sample on obs to its Adam step.
struct Sac::Impl::CudaGraph {
  // Updates run eagerly (on the capture streams) before capture, so that lazily created state
  // (cuBLAS handles and workspaces, autograd's device threads, allocator blocks, events) exists
  // before it.
  static constexpr int kWarmupUpdates = 3;
  // Replays queued at most before the host waits for them (pinned input and output slots).
  static constexpr int kSlots = 16;

  ~CudaGraph() {
    // Nothing queued may outlive the pinned slots and the graph's memory it uses. A sticky CUDA
    // error (the reason this is being unwound, maybe) is said, not thrown from a destructor.
    if (in_flight.empty()) return;
    try {
      c10::cuda::getCurrentCUDAStream(device_index).synchronize();
    } catch (const std::exception& e) {
      std::fprintf(stderr, "[learner] sac: waiting for queued CUDA graph replays failed: %s\n", e.what());
    }
  }

  CudaGraph(Impl& s, int64_t batch, const DeviceReplay* replay)
      : batch(batch),
        drawn_from(replay),
        device_index(s.device.has_index() ? s.device.index() : c10::cuda::current_device()),
        actor_adam(*s.actor_opt, {s.actor_p.flat}),
        critic_adam(*s.critic_opt, {s.critic_p.flat}),
        alpha_adam(*s.alpha_opt, {s.log_alpha}),
        streams{c10::cuda::getStreamFromPool(false, device_index), c10::cuda::getStreamFromPool(false, device_index),
                c10::cuda::getStreamFromPool(false, device_index), c10::cuda::getStreamFromPool(false, device_index)},
        fused(s.use_fused_kernels()) {
    const int64_t o = s.obs_dim, a = s.act_dim;
    widths = {o, a, 1, 1, o};
    const auto f32 = torch::TensorOptions().dtype(torch::kFloat);
    for (auto& h : host_in) h = torch::empty({batch * (2 * o + a + 2)}, f32.pinned_memory(true));
    dev_in = torch::empty({batch * (2 * o + a + 2)}, f32.device(s.device));
    std::array<torch::Tensor*, 5> views{&obs, &actions, &rewards, &terminated, &next_obs};
    int64_t offset = 0;
    for (size_t i = 0; i < views.size(); ++i) {
      const int64_t n = batch * widths[i];
      // rewards and terminated are [B], the others [B, width].
      *views[i] = i == 2 || i == 3 ? dev_in.narrow(0, offset, n) : dev_in.narrow(0, offset, n).view({batch, widths[i]});
      offset += n;
    }
    out = torch::zeros({kFigures}, f32.device(s.device));
    for (auto& h : host_out) h = torch::empty({kFigures}, f32.pinned_memory(true));
  }

  // Stages the sampled batch in pinned slot `slot` (plain memcpy: the sampled tensors are fresh
  // host floats), then queues one asynchronous copy to the static inputs on the current stream,
  // the one the graph replays on. The slot must not have a copy still pending.
  void stage(const SampledBatch& host_batch, int slot) {
    const std::array<const torch::Tensor*, 5> fields{&host_batch.obs, &host_batch.actions, &host_batch.rewards,
                                                     &host_batch.terminated, &host_batch.next_obs};
    float* dst = host_in[slot].data_ptr<float>();
    for (size_t i = 0; i < fields.size(); ++i) {
      const torch::Tensor t = fields[i]->to(torch::kCPU, torch::kFloat).contiguous();
      if (t.numel() != batch * widths[i])
        throw std::invalid_argument("sac update: batch field " + std::to_string(i) + " has " +
                                    std::to_string(t.numel()) + " values, expected " +
                                    std::to_string(batch * widths[i]));
      std::memcpy(dst, t.data_ptr<float>(), sizeof(float) * t.numel());
      dst += t.numel();
    }
    dev_in.copy_(host_in[slot], /*non_blocking=*/true);
  }

  // After a replay (or the eager warm-up) is queued: its figures to pinned slot `slot`, and the
  // host's Adam step counts (save() writes them) advanced as the device's were.
  void queue_figures(int slot) {
    host_out[slot].copy_(out, /*non_blocking=*/true);
    for (GraphAdam* a : {&actor_adam, &critic_adam, &alpha_adam}) a->advance_host_steps();
  }

  // Slot `slot`'s figures; only after the stream has been synchronized past their copy.
  SacStats figures(int slot) const {
    const float* f = host_out[slot].data_ptr<float>();
    SacStats st;
    st.critic_loss = f[0];
    st.actor_loss = f[1];
    st.alpha_loss = f[2];
    st.entropy = f[3];
    st.q_mean = f[4];
    st.alpha = f[5];
    return st;
  }

  // The update of Sac::update with the temperature kept on the device (no item()) and the three
  // Adam steps as GraphAdam steps; writes the figures into `out`.
  // Runs with streams.capture current. Every tensor that one stream makes and another uses is held
  // by a local until the end, after the joins, so the allocator cannot hand its memory to a later
  // kernel while another stream may still read it. The two noise draws are issued in the eager
  // order (obs, then next_obs), which is what fixes their philox offsets.
  void body(Impl& s) {
    const c10::cuda::CUDAStream main = c10::cuda::getCurrentCUDAStream(device_index);
    if (drawn_from) draw_batch();
    // sac.actor_on_previous_critic: the actor's step (from its sample on obs to its Adam step) as a
    // branch of its own beside the critics' step. Backward ops run on the streams of their forward
    // ops, so the sample must be on that branch too. The branch reads the critics' weights
    // (forward, and backward to the action) before their step writes them, and writes the actor's
    // weights after the target branch read them.
    const bool beside = s.cfg.actor_on_previous_critic();
    const c10::cuda::CUDAStream sampled_on = beside ? streams.actor : main;
    const auto alpha = s.log_alpha.detach().exp();  // the temperature before this update's step
    order_after(events[0], main, streams.target);
    if (beside) order_after(events[6], main, streams.actor);
    torch::Tensor pi_action, log_prob;
    {
      c10::cuda::CUDAStreamGuard on(sampled_on);
      std::tie(pi_action, log_prob) = sample(s, obs, fused);
    }

    torch::Tensor target;
    {
      c10::cuda::CUDAStreamGuard on_side(streams.target);
      torch::NoGradGuard no_grad;
      // Main joins this stream before either step reads its count (and so does the actor's branch).
      torch::_foreach_add_(std::vector<torch::Tensor>{critic_adam.step_count[0], actor_adam.step_count[0]}, 1);
      auto [next_action, next_log_prob] = sample(s, next_obs, fused);
      if (beside) events[8].record(streams.target);  // the actor's weights read: its Adam step waits
      const auto next_q = s.critic_target->forward(next_obs, next_action);
#ifdef FARM_CUDA_KERNELS
      if (fused) target = fused_soft_target(next_q, next_log_prob, alpha, rewards, terminated, s.cfg.gamma());
#endif
      if (!target.defined()) {
        auto soft_v = torch::min(next_q[0], next_q[1]).sub_(next_log_prob * alpha);
        target = torch::addcmul(rewards, soft_v, 1.0 - terminated, s.cfg.gamma());
      }
    }

    torch::Tensor alpha_loss, entropy;
    order_after(events[1], sampled_on, streams.alpha);
    {
      c10::cuda::CUDAStreamGuard on_side(streams.alpha);
      alpha_loss = sac_temperature_loss(s.log_alpha, log_prob, s.target_entropy);
      const auto grad = torch::autograd::grad({alpha_loss}, {s.log_alpha})[0];
      alpha_adam.advance_device_steps();
      alpha_adam.step({grad});
      torch::NoGradGuard no_grad;
      entropy = log_prob.mean().neg();
    }

    torch::Tensor actor_loss;
    auto actor_step = [&] {
      const auto q_pi = s.critic->forward(obs, pi_action);
#ifdef FARM_CUDA_KERNELS
      if (fused) actor_loss = ActorObjective::apply(q_pi, log_prob, alpha);
#endif
      if (!actor_loss.defined()) actor_loss = (alpha * log_prob - torch::min(q_pi[0], q_pi[1])).mean();
      const auto grad = flat_grad(actor_loss, s.actor_p);
      if (beside) {
        events[7].record(streams.actor);  // the critics' weights read; main waits before their step
        events[8].block(streams.actor);
      }
      actor_adam.step({grad});
    };
    if (beside) {
      c10::cuda::CUDAStreamGuard on_side(streams.actor);
      actor_step();
    }

    const auto q = s.critic->forward(obs, actions);
    order_after(events[2], streams.target, main);
    const auto critic_loss = torch::mse_loss(q, target.unsqueeze(0).expand_as(q));
    const auto critic_grad = flat_grad(critic_loss, s.critic_p);
    if (beside) events[7].block(main);
    critic_adam.step({critic_grad});

    torch::Tensor q_mean;
    order_after(events[3], main, streams.target);
    {
      c10::cuda::CUDAStreamGuard on_side(streams.target);
      torch::NoGradGuard no_grad;
      s.target_p.flat.lerp_(s.critic_p.flat, s.cfg.tau());
      q_mean = q.mean();
    }

    if (beside)
      order_after(events[9], streams.actor, main);
    else
      actor_step();

    order_after(events[4], streams.target, main);
    order_after(events[5], streams.alpha, main);
    torch::NoGradGuard no_grad;
    torch::cat_out(out, {critic_loss.reshape({1}), actor_loss.reshape({1}), alpha_loss.reshape({1}),
                         entropy.reshape({1}), q_mean.reshape({1}), alpha.reshape({1})});
  }

  // sac.replay_on_device: the minibatch drawn from the replay's rows on the device into the static
  // inputs, as DeviceReplay::sample draws it (u from the default generator, then the rows at
  // DeviceReplay::indices(u), DeviceReplay::draw): the graph's first kernels, on the current stream.
  void draw_batch() {
    const auto u = torch::rand({batch}, torch::TensorOptions().dtype(torch::kDouble).device(dev_in.device()));
#ifdef FARM_CUDA_KERNELS
    if (fused) {
      launched(sac_kernels::gather_rows(drawn_from->rows().data_ptr<float>(), u.data_ptr<double>(),
                                        reinterpret_cast<const long long*>(drawn_from->fill().data_ptr<int64_t>()),
                                        dev_in.data_ptr<float>(), int(batch), int(widths[0]), int(widths[1]),
                                        current_stream()),
               "gather_rows");
      return;
    }
#endif
    torch::NoGradGuard no_grad;
    const SampledBatch b = drawn_from->draw(u);
    for (auto [to, from] : {std::pair{&obs, &b.obs}, std::pair{&actions, &b.actions}, std::pair{&rewards, &b.rewards},
                            std::pair{&terminated, &b.terminated}, std::pair{&next_obs, &b.next_obs}})
      to->copy_(*from);
  }

  // Impl::sample's draw and log-density in fewer kernels, for the graph's critical path: the
  // Gaussian term takes the drawn noise itself, which (pre_tanh - mean) / std recomputes up to
  // rounding (with a zero gradient either way), and the squash term reuses the action instead of a
  // second tanh. Same noise draw, same values up to float rounding. `fused`: the same formulas as
  // one kernel (and one for their gradient) after the noise draw.
  static std::pair<torch::Tensor, torch::Tensor> sample(Impl& s, const torch::Tensor& obs, bool fused) {
    static const double kHalfLog2Pi = 0.5 * std::log(2.0 * M_PI);
    const auto out = s.actor->forward(obs);
#ifdef FARM_CUDA_KERNELS
    if (fused) {
      const auto noise = torch::randn({out.size(0), s.act_dim}, out.options().requires_grad(false));
      const auto r = SquashedSample::apply(out, noise, s.cfg.log_std_min(), s.cfg.log_std_max());
      return {r[0], r[1]};
    }
#else
    (void)fused;
#endif
    const auto mean = out.narrow(1, 0, s.act_dim);
    const auto log_std = out.narrow(1, s.act_dim, s.act_dim).clamp(s.cfg.log_std_min(), s.cfg.log_std_max());
    const auto noise = torch::randn_like(mean);
    const auto action = torch::tanh(torch::addcmul(mean, torch::exp(log_std), noise));
    const auto gaussian = noise.square().mul_(-0.5).sub_(kHalfLog2Pi) - log_std;
    const auto squash = torch::log(action.square().neg_().add_(1.0 + 1e-6));
    return {action, (gaussian - squash).sum(-1)};
  }

  // What is enqueued on `waiter` from now on runs after what has been enqueued on `on` so far.
  static void order_after(at::cuda::CUDAEvent& event, const c10::cuda::CUDAStream& on,
                          const c10::cuda::CUDAStream& waiter) {
    event.record(on);
    event.block(waiter);
  }

  static torch::Tensor flat_grad(const torch::Tensor& loss, FlatParams& net) {
    const auto grads = torch::autograd::grad({loss}, net.params);
    std::vector<torch::Tensor> flat;
    flat.reserve(grads.size());
    for (const auto& g : grads) flat.push_back(g.reshape(-1));  // a fused layer's gradient may be a transposed view
    return torch::cat(flat);
  }

  static constexpr int64_t kFigures = 6;
  int64_t batch;
  const DeviceReplay* drawn_from;  // where the graph draws its batch; null: staged from the host
  c10::DeviceIndex device_index;
  std::array<int64_t, 5> widths;
  std::array<torch::Tensor, kSlots> host_in, host_out;
  torch::Tensor dev_in, obs, actions, rewards, terminated, next_obs, out;
  GraphAdam actor_adam, critic_adam, alpha_adam;
  // The stream the graph is captured on, and those its side branches run on.
  struct Streams {
    c10::cuda::CUDAStream capture, target, alpha, actor;
  } streams;
  std::array<at::cuda::CUDAEvent, 10> events;
  std::unique_ptr<at::cuda::CUDAGraph> graph;
  int warmups_left = kWarmupUpdates;
  // sac.cuda_fused_kernels in a build that has them.
  bool fused;
  // Queued replays whose figures have not been read, oldest first (their slots), each with the
  // event recorded behind its figures' copy; the slot the next queued replay takes.
  std::deque<int> in_flight;
  std::array<at::cuda::CUDAEvent, kSlots> done;
  int next_slot = 0;
};
#endif  // FARM_CUDA_GRAPHS

sac_detail::TwinLayerFn sac_detail::fused_twin_layer() {
#if defined(FARM_CUDA_GRAPHS) && defined(FARM_CUDA_KERNELS)
  return &twin_layer;
#else
  return nullptr;
#endif
}

bool Sac::Impl::use_graph() const {
#ifdef FARM_CUDA_GRAPHS
  return device.is_cuda() && cfg.cuda_graph();
#else
  return false;
#endif
}

bool Sac::Impl::use_fused_kernels() const { return use_graph() && cfg.cuda_fused_kernels() && kFusedKernelsBuilt; }

SacStats Sac::Impl::graph_update(const SampledBatch& host_batch) {
  return graph_update_one({host_batch.obs.size(0), nullptr, host_batch});
}

SacStats Sac::Impl::graph_update_one(const GraphInput& in) {
#ifdef FARM_CUDA_GRAPHS
  settle_graph();  // one update at a time uses slot 0: nothing may be queued
  if (!graph || graph->batch != in.batch || graph->drawn_from != in.replay) {
    graph.reset();  // its private memory pool goes before the next graph's
    graph.reset(new CudaGraph(*this, in.batch, in.replay));
  }
  CudaGraph& g = *graph;
  c10::cuda::CUDAGuard device_guard(g.device_index);
  if (!in.replay) g.stage(in.host, 0);
  run_graph_update(g.graph, g.warmups_left, g.device_index, g.streams.capture, [&] { g.body(*this); });
  g.queue_figures(0);
  c10::cuda::getCurrentCUDAStream(g.device_index).synchronize();
  ++updates;
  return g.figures(0);
#else
  (void)in;
  throw std::logic_error("sac: CUDA graph update in a build without CUDA");
#endif
}

std::vector<SacStats> Sac::Impl::graph_update_n(int n, const std::function<SampledBatch()>& next_batch) {
  return queue_graph_updates(n, [&] {
    SampledBatch b = next_batch();  // on the host, while the queued replays run
    const int64_t rows = b.obs.size(0);
    return GraphInput{rows, nullptr, std::move(b)};
  });
}

std::vector<SacStats> Sac::Impl::graph_update_n_from(int n, int64_t batch, const DeviceReplay& replay) {
  if (replay.size() == 0) throw std::logic_error("sac: no rows to draw minibatches from (the replay is empty)");
  return queue_graph_updates(n, [&] { return GraphInput{batch, &replay, {}}; });
}

std::vector<SacStats> Sac::Impl::queue_graph_updates(int n, const std::function<GraphInput()>& next) {
  std::vector<SacStats> stats = std::move(ready);
  ready.clear();
  stats.reserve(stats.size() + std::max(n, 0));
#ifdef FARM_CUDA_GRAPHS
  try {
    for (int i = 0; i < n; ++i) {
      const GraphInput in = next();
      if (!graph || !graph->graph || graph->batch != in.batch || graph->drawn_from != in.replay) {
        // Warm-ups, the capture, a new batch size or source: one at a time, after what is queued
        // (whose figures graph_update_one's settle_graph puts in `ready`).
        const SacStats one = graph_update_one(in);
        stats.insert(stats.end(), ready.begin(), ready.end());
        ready.clear();
        stats.push_back(one);
        continue;
      }
      CudaGraph& g = *graph;
      c10::cuda::CUDAGuard device_guard(g.device_index);
      if (int(g.in_flight.size()) == CudaGraph::kSlots) {  // the ring is full: its oldest is next_slot
        g.done[g.in_flight.front()].synchronize();
        stats.push_back(g.figures(g.in_flight.front()));
        g.in_flight.pop_front();
      }
      const int slot = g.next_slot;
      if (!in.replay) g.stage(in.host, slot);
      g.graph->replay();
      g.queue_figures(slot);
      g.done[slot].record(c10::cuda::getCurrentCUDAStream(g.device_index));
      g.in_flight.push_back(slot);
      g.next_slot = (slot + 1) % CudaGraph::kSlots;
      ++updates;
    }
  } catch (...) {
    // A batch that failed to sample or stage: what is queued still runs; wait for it, so that
    // no copy from a pinned slot is pending when the next call writes that slot. The figures
    // already read go back to `ready`, before those of the queued ones, for the next call.
    ready.insert(ready.begin(), stats.begin(), stats.end());
    settle_graph();
    throw;
  }
  // The figures of the replays that have run, without waiting for the others.
  if (graph) {
    CudaGraph& g = *graph;
    while (!g.in_flight.empty() && g.done[g.in_flight.front()].query()) {
      stats.push_back(g.figures(g.in_flight.front()));
      g.in_flight.pop_front();
    }
  }
#else
  (void)n;
  (void)next;
  throw std::logic_error("sac: CUDA graph update in a build without CUDA");
#endif
  return stats;
}

int64_t Sac::Impl::updates_in_flight() const {
#ifdef FARM_CUDA_GRAPHS
  return int64_t(ready.size()) + (graph ? int64_t(graph->in_flight.size()) : 0);
#else
  return int64_t(ready.size());
#endif
}

std::vector<SacStats> Sac::Impl::finish_updates() {
  settle_graph();
  std::vector<SacStats> stats = std::move(ready);
  ready.clear();
  return stats;
}

void Sac::Impl::settle_graph() {
#ifdef FARM_CUDA_GRAPHS
  if (!graph || graph->in_flight.empty()) return;
  CudaGraph& g = *graph;
  c10::cuda::CUDAGuard device_guard(g.device_index);
  c10::cuda::getCurrentCUDAStream(g.device_index).synchronize();
  for (const int slot : g.in_flight) ready.push_back(g.figures(slot));
  g.in_flight.clear();
#endif
}

// Construction order matters: the seed must be set before the networks are initialized.

#ifdef FARM_CUDA_GRAPHS
void Sac::Impl::CudaGraphDeleter::operator()(CudaGraph* g) const { delete g; }
#endif

void Sac::Impl::drop_graph() {
#ifdef FARM_CUDA_GRAPHS
  settle_graph();
  graph.reset();
#endif
}

}  // namespace farm
