// What sac.cpp and sac_cuda_graph.cpp share: the networks, their flat parameter buffers and the
// state of one Sac (Sac::Impl). Included by those two files only.
#pragma once

#include <torch/torch.h>

#include <cmath>
#include <functional>
#include <memory>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "compute.h"
#include "config.h"
#include "device_replay.h"
#include "flat_params.h"
#include "linear_mlp.h"
#include "sac.h"

namespace farm {

namespace sac_detail {

using farm::FlatParams;
using farm::placed;

// Matches torch::nn::Linear's default init (kaiming_uniform with a = sqrt(5) reduces to this), so
// the fused critics start from the same distribution as sb3's nn.Linear critics.
inline void linear_init_(torch::Tensor t, int64_t fan_in) {
  const double bound = 1.0 / std::sqrt(double(fan_in));
  t.uniform_(-bound, bound);
}

// The actor: farm's LinearMlp (linear_mlp.h), relu or tanh between its layers.
using Actor = LinearMlp;
using farm::TwinLayerFn;
// The fused layer where this build has the kernels, else null.
TwinLayerFn fused_twin_layer();

// Both critics in one module, evaluated together as batched matmuls over a leading critic
// dimension of 2: half the ops of two separate MLPs, which is what bounds small-network updates on
// CPU. Weights are stored [critic, in, out] so no transpose is needed per call.
struct TwinCriticImpl : torch::nn::Module {
  TwinCriticImpl(const std::vector<int64_t>& sizes, bool tanh_hidden) : tanh_hidden(tanh_hidden) {
    torch::NoGradGuard no_grad;
    for (size_t i = 0; i + 1 < sizes.size(); ++i) {
      const std::string k = std::to_string(i);
      w.push_back(register_parameter("w" + k, torch::empty({2, sizes[i], sizes[i + 1]})));
      b.push_back(register_parameter("b" + k, torch::empty({2, 1, sizes[i + 1]})));
      linear_init_(w.back(), sizes[i]);
      linear_init_(b.back(), sizes[i]);
    }
  }
  // obs [B, obs], act [B, act] -> [2, B]: row 0 is Q1, row 1 is Q2.
  torch::Tensor forward(const torch::Tensor& obs, const torch::Tensor& act) {
    const bool cast = compute != torch::kFloat;  // sac.matmul_dtype
    const bool large = obs.size(0) >= kLargeBatchRows;
    const bool pad = pad_on_cuda && large;
    const TwinLayerFn layer = large ? this->layer : nullptr;
    torch::Tensor sa = cast ? torch::cat({obs.to(compute), act.to(compute)}, 1) : torch::cat({obs, act}, 1);
    torch::Tensor x;
    for (size_t i = 0; i < w.size(); ++i) {
      torch::Tensor wi = cast ? w[i].to(compute) : w[i],
                    bi = cast ? b[i].to(compute) : b[i];  // [2, in, out], [2, 1, out]
      if (i == 0) {
        if (pad) std::tie(sa, wi) = padded_input(sa, wi, 1);
        x = sa.unsqueeze(0).expand({2, sa.size(0), sa.size(1)});
      }
      if (pad && i + 1 == w.size()) {
        const int64_t extra = to_multiple_of_8(wi.size(2));
        wi = torch::constant_pad_nd(wi, {0, extra});
        bi = torch::constant_pad_nd(bi, {0, extra});
      }
      const bool hidden = i + 1 < w.size();
      if (layer && hidden && !tanh_hidden) {
        x = layer(x, wi, bi, true);
        continue;
      }
      x = torch::baddbmm(bi, x, wi);
      if (hidden) tanh_hidden ? x.tanh_() : x.relu_();
    }
    x = x.narrow(2, 0, 1).squeeze(-1);
    return cast ? x.to(torch::kFloat) : x;
  }
  std::vector<torch::Tensor> w, b;
  bool tanh_hidden;
  torch::ScalarType compute = torch::kFloat;  // sac.matmul_dtype
  bool pad_on_cuda = false;                   // see padded_input
  TwinLayerFn layer = nullptr;                // large batches: the hidden layers' fused product, bias and ReLU
};
TORCH_MODULE(TwinCritic);

// autograd::grad computes only what these parameters need (the actor loss runs through the
// critics without producing critic weight gradients), and the result replaces the previous .grad
// instead of accumulating into it: zero_grad(set_to_none) without a pass of its own.
inline void step(torch::optim::Optimizer& opt, FlatParams& net, const torch::Tensor& loss) {
  const auto grads = torch::autograd::grad({loss}, net.params);
  std::vector<torch::Tensor> flat;
  flat.reserve(grads.size());
  for (const auto& g : grads) flat.push_back(g.reshape(-1));  // a fused layer's gradient may be a transposed view
  net.flat.mutable_grad() = torch::cat(flat);
  opt.step();
}

inline void step(torch::optim::Optimizer& opt, const torch::Tensor& param, const torch::Tensor& loss) {
  param.mutable_grad() = torch::autograd::grad({loss}, {param})[0];
  opt.step();
}

// SacConfig.matmul_dtype: "float32" or "bfloat16" (anything else is refused by config validation).
inline torch::ScalarType matmul_dtype(const config::SacConfig& c) {
  return matmul_dtype_named(c.matmul_dtype(), "sac");
}

// SacConfig.activation: "tanh" or "relu" (anything else is refused by config validation).
inline bool tanh_hidden(const config::SacConfig& c) {
  if (c.activation() != "relu" && c.activation() != "tanh")
    throw std::invalid_argument("sac.activation must be \"relu\" or \"tanh\", got \"" + c.activation() + "\"");
  return c.activation() == "tanh";
}

}  // namespace sac_detail

struct Sac::Impl {
  using Actor = sac_detail::Actor;
  using TwinCritic = sac_detail::TwinCritic;
  using FlatParams = sac_detail::FlatParams;

  Impl(const config::SacConfig& c, int obs, int act)
      : cfg(c),
        obs_dim(obs),
        act_dim(act),
        hidden(sac_hidden(c)),
        critic_hidden(sac_critic_hidden(c)),
        target_entropy(std::isnan(c.target_entropy()) ? -double(act) : c.target_entropy()),
        device(learner_device(c.device(), "sac.device")),
        actor(layer_sizes(obs, hidden, 2 * act), sac_detail::tanh_hidden(c)),
        critic(layer_sizes(obs + act, critic_hidden, 1), sac_detail::tanh_hidden(c)),
        critic_target(layer_sizes(obs + act, critic_hidden, 1), sac_detail::tanh_hidden(c)),
        actor_p(*sac_detail::placed(actor, device)),
        critic_p(*sac_detail::placed(critic, device)),
        target_p(*sac_detail::placed(critic_target, device)) {
    actor->compute = critic->compute = critic_target->compute = sac_detail::matmul_dtype(c);
    actor->pad_on_cuda = critic->pad_on_cuda = critic_target->pad_on_cuda = device.is_cuda();
    if (device.is_cuda() && c.cuda_fused_kernels())
      actor->layer = critic->layer = critic_target->layer = sac_detail::fused_twin_layer();
    {
      torch::NoGradGuard no_grad;
      target_p.flat.copy_(critic_p.flat);
      for (auto& t : target_p.params) t.requires_grad_(false);
    }
    log_alpha =
        torch::full({1}, std::log(cfg.initial_alpha()), torch::TensorOptions().device(device).requires_grad(true));
    // Each optimizer owns one flat buffer; its .grad is the concatenated parameter gradients.
    actor_opt = std::make_unique<torch::optim::Adam>(std::vector<torch::Tensor>{actor_p.flat},
                                                     torch::optim::AdamOptions(cfg.actor_lr()));
    critic_opt = std::make_unique<torch::optim::Adam>(std::vector<torch::Tensor>{critic_p.flat},
                                                      torch::optim::AdamOptions(cfg.critic_lr()));
    alpha_opt = std::make_unique<torch::optim::Adam>(std::vector<torch::Tensor>{log_alpha},
                                                     torch::optim::AdamOptions(cfg.alpha_lr()));
  }

  static std::vector<int64_t> layer_sizes(int in, const std::vector<int>& hidden, int out) {
    std::vector<int64_t> s{in};
    s.insert(s.end(), hidden.begin(), hidden.end());
    s.push_back(out);
    return s;
  }

  // Reparameterized sample: returns (tanh action, log_prob [B]).
  std::pair<torch::Tensor, torch::Tensor> sample(const torch::Tensor& obs) {
    const auto out = actor->forward(obs);
    const auto mean = out.narrow(1, 0, act_dim);
    const auto log_std = out.narrow(1, act_dim, act_dim).clamp(cfg.log_std_min(), cfg.log_std_max());
    const auto pre_tanh = torch::addcmul(mean, torch::exp(log_std), torch::randn_like(mean));
    return {torch::tanh(pre_tanh), squashed_gaussian_log_prob(mean, log_std, pre_tanh)};
  }

  config::SacConfig cfg;
  int obs_dim, act_dim;
  std::vector<int> hidden, critic_hidden;
  double target_entropy;
  torch::Device device;
  Actor actor;
  TwinCritic critic, critic_target;
  FlatParams actor_p, critic_p, target_p;
  torch::Tensor log_alpha;
  std::unique_ptr<torch::optim::Adam> actor_opt, critic_opt, alpha_opt;
  int64_t updates = 0;
  double lr_scale = 1.0;  // Sac::scale_learning_rates
  // sac.policy_average_tau > 0: the published actor's flat parameters, a Polyak average of
  // actor_p.flat; undefined until the first update (the actor itself is published until then).
  torch::Tensor policy_average;
  // After n more updates: one step of 1 - (1 - tau)^n, as n steps of tau toward the last actor.
  // Queued on the current stream, behind the updates it follows.
  void average_policy(int n) {
    const double tau = cfg.policy_average_tau();
    if (tau <= 0 || n <= 0) return;
    torch::NoGradGuard no_grad;
    if (!policy_average.defined())
      policy_average = actor_p.flat.detach().clone();
    else
      policy_average.lerp_(actor_p.flat.detach(), 1.0 - std::pow(1.0 - tau, n));
  }
  // The actor's, critics' and temperature's Adam learning rates from cfg and lr_scale; a CUDA graph
  // captured with others is dropped (its fused Adam holds the learning rate as a constant).
  void apply_learning_rates() {
    for (auto [opt, lr] : {std::pair{actor_opt.get(), cfg.actor_lr()}, std::pair{critic_opt.get(), cfg.critic_lr()},
                           std::pair{alpha_opt.get(), cfg.alpha_lr()}})
      for (auto& group : opt->param_groups())
        static_cast<torch::optim::AdamOptions&>(group.options()).lr(lr * lr_scale);
    drop_graph();
  }
#ifdef FARM_CUDA_GRAPHS
  // Built at the first update on CUDA (cfg.cuda_graph) and again after load() or a new batch size.
  // (sac_cuda_graph.cpp, the one file that sees CudaGraph whole, deletes it).
  struct CudaGraph;
  struct CudaGraphDeleter {
    void operator()(CudaGraph* g) const;
  };
  std::unique_ptr<CudaGraph, CudaGraphDeleter> graph;
#endif
  bool use_graph() const;
  bool use_fused_kernels() const;  // in the graph: sac.cuda_fused_kernels where they are built
  SacStats graph_update(const SampledBatch& host_batch);
  std::vector<SacStats> graph_update_n(int n, const std::function<SampledBatch()>& next_batch);
  std::vector<SacStats> graph_update_n_from(int n, int64_t batch, const DeviceReplay& replay);
  // One graph update's input: `batch` rows of `host` staged through a pinned slot, or (replay set)
  // drawn from `replay` inside the graph. A graph is built for one (batch, replay) pair.
  struct GraphInput {
    int64_t batch = 0;
    const DeviceReplay* replay = nullptr;
    SampledBatch host;
  };
  SacStats graph_update_one(const GraphInput& in);
  std::vector<SacStats> queue_graph_updates(int n, const std::function<GraphInput()>& next);
  int64_t updates_in_flight() const;
  std::vector<SacStats> finish_updates();
  // Waits for the queued replays; their figures go to `ready` (returned first by the next
  // graph_update_n or finish_updates), and no pinned slot or graph memory is in use after it.
  void settle_graph();
  std::vector<SacStats> ready;
  void drop_graph();  // the next update on CUDA captures anew (after settle_graph)
};

}  // namespace farm
