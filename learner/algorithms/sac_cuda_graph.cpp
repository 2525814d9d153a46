// SAC's update on CUDA captured as one CUDA graph (a handful of launches instead of a few hundred),
// built only against a CUDA LibTorch (FARM_CUDA_GRAPHS, learner/algorithms/CMakeLists.txt).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
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

namespace farm {

using namespace sac_detail;

#ifdef FARM_CUDA_GRAPHS
namespace {

// Adam as torch::optim::Adam computes it (no weight decay, no amsgrad), but in one fused kernel that
// reads the step count from a device tensor: a captured graph replays the same kernels with the
// same arguments, so a host-side step count (and with it the bias correction) would be frozen at
// its value during capture. The moment estimates are the torch::optim::Adam state tensors
// themselves, whose host step count is advanced after each replay, so save(), load() and the eager
// path see the same optimizer state either way.
struct GraphAdam {
  GraphAdam(torch::optim::Adam& opt, const torch::Tensor& param) : param(param) {
    // The state appears at the first step. One step with a zero gradient creates it and leaves the
    // parameter exactly as it was (p - step_size * 0 / eps), then the count is put back to 0.
    if (opt.state().empty()) {
      torch::Tensor p = param;
      p.mutable_grad() = torch::zeros_like(param);
      opt.step();
      p.mutable_grad() = torch::Tensor();
      static_cast<torch::optim::AdamParamState&>(*opt.state().begin()->second).step(0);
    }
    state = &static_cast<torch::optim::AdamParamState&>(*opt.state().begin()->second);
    const auto& o = static_cast<const torch::optim::AdamOptions&>(opt.param_groups()[0].options());
    if (o.weight_decay() != 0 || o.amsgrad())
      throw std::logic_error("sac cuda graph: Adam with weight decay or amsgrad is not supported");
    lr = o.lr();
    beta1 = std::get<0>(o.betas());
    beta2 = std::get<1>(o.betas());
    eps = o.eps();
    step_count = torch::full({}, double(state->step()), param.options().dtype(torch::kFloat));
  }
  // Graph-safe: only device work. step_count must have been advanced for this step (the update
  // does that off its critical path).
  void step(const torch::Tensor& grad) {
    torch::NoGradGuard no_grad;
    at::_fused_adam_({param}, {grad}, {state->exp_avg()}, {state->exp_avg_sq()}, {}, {step_count}, lr, beta1, beta2,
                     /*weight_decay=*/0.0, eps, /*amsgrad=*/false, /*maximize=*/false);
  }
  torch::Tensor param, step_count;
  torch::optim::AdamParamState* state;
  double lr, beta1, beta2, eps;
};

}  // namespace

// One update captured as a CUDA graph. Its inputs are static device tensors that each update
// overwrites with the sampled batch (one pinned host buffer, one host-to-device copy); its output
// is a static tensor of the six figures, read back with one copy. Replays can be queued
// (graph_update_n): each queued update stages its batch in a pinned buffer of its own and reads
// its figures back into a pinned slot of its own, and the stream's order keeps every copy between
// the replays it belongs to. The policy's sampling noise is
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

  CudaGraph(Impl& s, int64_t batch)
      : batch(batch),
        device_index(s.device.has_index() ? s.device.index() : c10::cuda::current_device()),
        actor_adam(*s.actor_opt, s.actor_p.flat),
        critic_adam(*s.critic_opt, s.critic_p.flat),
        alpha_adam(*s.alpha_opt, s.log_alpha),
        capture_stream(c10::cuda::getStreamFromPool(false, device_index)),
        target_stream(c10::cuda::getStreamFromPool(false, device_index)),
        alpha_stream(c10::cuda::getStreamFromPool(false, device_index)),
        actor_stream(c10::cuda::getStreamFromPool(false, device_index)) {
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
    for (GraphAdam* a : {&actor_adam, &critic_adam, &alpha_adam}) a->state->step(a->state->step() + 1);
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
  // Runs with capture_stream current. Every tensor that one stream makes and another uses is held
  // by a local until the end, after the joins, so the allocator cannot hand its memory to a later
  // kernel while another stream may still read it. The two noise draws are issued in the eager
  // order (obs, then next_obs), which is what fixes their philox offsets.
  void body(Impl& s) {
    const c10::cuda::CUDAStream main = c10::cuda::getCurrentCUDAStream(device_index);
    // sac.actor_on_previous_critic: the actor's step (from its sample on obs to its Adam step) as a
    // branch of its own beside the critics' step. Backward ops run on the streams of their forward
    // ops, so the sample must be on that branch too. The branch reads the critics' weights
    // (forward, and backward to the action) before their step writes them, and writes the actor's
    // weights after the target branch read them.
    const bool beside = s.cfg.actor_on_previous_critic();
    const c10::cuda::CUDAStream sampled_on = beside ? actor_stream : main;
    const auto alpha = s.log_alpha.detach().exp();  // the temperature before this update's step
    order_after(events[0], main, target_stream);
    if (beside) order_after(events[6], main, actor_stream);
    torch::Tensor pi_action, log_prob;
    {
      c10::cuda::CUDAStreamGuard on(sampled_on);
      std::tie(pi_action, log_prob) = sample(s, obs);
    }

    torch::Tensor target;
    {
      c10::cuda::CUDAStreamGuard on_side(target_stream);
      torch::NoGradGuard no_grad;
      // Main joins this stream before either step reads its count (and so does the actor's branch).
      torch::_foreach_add_(std::vector<torch::Tensor>{critic_adam.step_count, actor_adam.step_count}, 1);
      auto [next_action, next_log_prob] = sample(s, next_obs);
      if (beside) events[8].record(target_stream);  // the actor's weights read: its Adam step waits
      const auto next_q = s.critic_target->forward(next_obs, next_action);
      auto soft_v = torch::min(next_q[0], next_q[1]).sub_(next_log_prob * alpha);
      target = torch::addcmul(rewards, soft_v, 1.0 - terminated, s.cfg.gamma());
    }

    torch::Tensor alpha_loss, entropy;
    order_after(events[1], sampled_on, alpha_stream);
    {
      c10::cuda::CUDAStreamGuard on_side(alpha_stream);
      alpha_loss = sac_temperature_loss(s.log_alpha, log_prob, s.target_entropy);
      const auto grad = torch::autograd::grad({alpha_loss}, {s.log_alpha})[0];
      alpha_adam.step_count.add_(1);
      alpha_adam.step(grad);
      torch::NoGradGuard no_grad;
      entropy = log_prob.mean().neg();
    }

    torch::Tensor actor_loss;
    auto actor_step = [&] {
      const auto q_pi = s.critic->forward(obs, pi_action);
      actor_loss = (alpha * log_prob - torch::min(q_pi[0], q_pi[1])).mean();
      const auto grad = flat_grad(actor_loss, s.actor_p);
      if (beside) {
        events[7].record(actor_stream);  // the critics' weights read; main waits before their step
        events[8].block(actor_stream);
      }
      actor_adam.step(grad);
    };
    if (beside) {
      c10::cuda::CUDAStreamGuard on_side(actor_stream);
      actor_step();
    }

    const auto q = s.critic->forward(obs, actions);
    order_after(events[2], target_stream, main);
    const auto critic_loss = torch::mse_loss(q, target.unsqueeze(0).expand_as(q));
    const auto critic_grad = flat_grad(critic_loss, s.critic_p);
    if (beside) events[7].block(main);
    critic_adam.step(critic_grad);

    torch::Tensor q_mean;
    order_after(events[3], main, target_stream);
    {
      c10::cuda::CUDAStreamGuard on_side(target_stream);
      torch::NoGradGuard no_grad;
      s.target_p.flat.lerp_(s.critic_p.flat, s.cfg.tau());
      q_mean = q.mean();
    }

    if (beside)
      order_after(events[9], actor_stream, main);
    else
      actor_step();

    order_after(events[4], target_stream, main);
    order_after(events[5], alpha_stream, main);
    torch::NoGradGuard no_grad;
    torch::cat_out(out, {critic_loss.reshape({1}), actor_loss.reshape({1}), alpha_loss.reshape({1}),
                         entropy.reshape({1}), q_mean.reshape({1}), alpha.reshape({1})});
  }

  // Impl::sample's draw and log-density in fewer kernels, for the graph's critical path: the
  // Gaussian term takes the drawn noise itself, which (pre_tanh - mean) / std recomputes up to
  // rounding (with a zero gradient either way), and the squash term reuses the action instead of a
  // second tanh. Same noise draw, same values up to float rounding.
  static std::pair<torch::Tensor, torch::Tensor> sample(Impl& s, const torch::Tensor& obs) {
    static const double kHalfLog2Pi = 0.5 * std::log(2.0 * M_PI);
    const auto out = s.actor->forward(obs);
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
    for (const auto& g : grads) flat.push_back(g.view(-1));
    return torch::cat(flat);
  }

  static constexpr int64_t kFigures = 6;
  int64_t batch;
  c10::DeviceIndex device_index;
  std::array<int64_t, 5> widths;
  std::array<torch::Tensor, kSlots> host_in, host_out;
  torch::Tensor dev_in, obs, actions, rewards, terminated, next_obs, out;
  GraphAdam actor_adam, critic_adam, alpha_adam;
  c10::cuda::CUDAStream capture_stream, target_stream, alpha_stream, actor_stream;
  std::array<at::cuda::CUDAEvent, 10> events;
  std::unique_ptr<at::cuda::CUDAGraph> graph;
  int warmups_left = kWarmupUpdates;
};
#endif  // FARM_CUDA_GRAPHS

bool Sac::Impl::use_graph() const {
#ifdef FARM_CUDA_GRAPHS
  return device.is_cuda() && cfg.cuda_graph();
#else
  return false;
#endif
}

SacStats Sac::Impl::graph_update(const SampledBatch& host_batch) {
#ifdef FARM_CUDA_GRAPHS
  const int64_t b = host_batch.obs.size(0);
  if (!graph || graph->batch != b) {
    graph.reset();  // its private memory pool goes before the next graph's
    graph.reset(new CudaGraph(*this, b));
  }
  CudaGraph& g = *graph;
  c10::cuda::CUDAGuard device_guard(g.device_index);
  g.stage(host_batch, 0);

  if (g.graph) {
    g.graph->replay();
  } else {
    // Warm-up and capture run on a side stream (capture cannot use the default stream); the
    // synchronizations keep it ordered with the default stream, where replays go.
    torch::cuda::synchronize(g.device_index);
    {
      c10::cuda::CUDAStreamGuard stream_guard(g.capture_stream);
      if (g.warmups_left > 0) {
        --g.warmups_left;
        g.body(*this);
      } else {
        auto graph_ptr = std::make_unique<at::cuda::CUDAGraph>();
        graph_ptr->capture_begin();
        g.body(*this);
        graph_ptr->capture_end();
        g.graph = std::move(graph_ptr);
      }
    }
    torch::cuda::synchronize(g.device_index);
    if (g.graph) g.graph->replay();  // capture recorded the update without running it
  }
  g.queue_figures(0);
  c10::cuda::getCurrentCUDAStream(g.device_index).synchronize();
  ++updates;
  return g.figures(0);
#else
  (void)host_batch;
  throw std::logic_error("sac: CUDA graph update in a build without CUDA");
#endif
}

std::vector<SacStats> Sac::Impl::graph_update_n(int n, const std::function<SampledBatch()>& next_batch) {
  std::vector<SacStats> stats;
  stats.reserve(std::max(n, 0));
#ifdef FARM_CUDA_GRAPHS
  int queued = 0;  // replays whose figures are in slots 0 .. queued-1, not yet read
  auto collect = [&] {
    if (queued == 0) return;
    c10::cuda::getCurrentCUDAStream(graph->device_index).synchronize();
    for (int k = 0; k < queued; ++k) stats.push_back(graph->figures(k));
    queued = 0;
  };
  try {
    for (int i = 0; i < n; ++i) {
      const SampledBatch b = next_batch();  // on the host, while the queued replays run
      if (!graph || !graph->graph || graph->batch != b.obs.size(0)) {
        // Warm-ups, the capture, a new batch size: one at a time, after what is queued.
        if (graph) {
          c10::cuda::CUDAGuard device_guard(graph->device_index);
          collect();
        }
        stats.push_back(graph_update(b));
        continue;
      }
      CudaGraph& g = *graph;
      c10::cuda::CUDAGuard device_guard(g.device_index);
      if (queued == CudaGraph::kSlots) collect();
      g.stage(b, queued);
      g.graph->replay();
      g.queue_figures(queued);
      ++queued;
      ++updates;
    }
  } catch (...) {
    // A batch that failed to sample or stage: what is queued still runs; wait for it, so that
    // no copy from a pinned slot is pending when the next call writes that slot.
    if (graph && queued > 0) c10::cuda::getCurrentCUDAStream(graph->device_index).synchronize();
    throw;
  }
  if (graph) {
    c10::cuda::CUDAGuard device_guard(graph->device_index);
    collect();
  }
#else
  (void)n;
  (void)next_batch;
  throw std::logic_error("sac: CUDA graph update in a build without CUDA");
#endif
  return stats;
}

// Construction order matters: the seed must be set before the networks are initialized.

#ifdef FARM_CUDA_GRAPHS
void Sac::Impl::CudaGraphDeleter::operator()(CudaGraph* g) const { delete g; }
#endif

void Sac::Impl::drop_graph() {
#ifdef FARM_CUDA_GRAPHS
  graph.reset();
#endif
}

}  // namespace farm
