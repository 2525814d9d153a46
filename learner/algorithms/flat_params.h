// One network's parameters made views of a single contiguous buffer, shared by SAC, TD3 and FastSAC. Adam,
// gradient clipping and the polyak update then run a handful of ops on one tensor instead of a
// handful per parameter tensor: on small networks the per-op overhead, not the arithmetic, is
// what an update costs.
#pragma once

#include <torch/torch.h>

#include <vector>

namespace farm {

struct FlatParams {
  explicit FlatParams(torch::nn::Module& m) : params(m.parameters()) {
    int64_t n = 0;
    for (const auto& p : params) n += p.numel();
    flat = torch::empty({n}, params.empty() ? torch::TensorOptions() : params[0].options());
    torch::NoGradGuard no_grad;
    int64_t offset = 0;
    for (auto& p : params) {
      const auto view = flat.narrow(0, offset, p.numel()).view(p.sizes());
      view.copy_(p);
      p.set_(view);
      offset += p.numel();
    }
  }
  std::vector<torch::Tensor> params;  // the module's own parameter tensors, in module order
  torch::Tensor flat;
};

// The gradient of `loss` with respect to `net` alone (an actor's loss runs through the critics
// without producing their gradients), its norm clipped to max_norm where max_norm > 0, then the
// optimizer's step.
inline void step_flat(torch::optim::Optimizer& opt, FlatParams& net, const torch::Tensor& loss, double max_norm) {
  const auto grads = torch::autograd::grad({loss}, net.params);
  std::vector<torch::Tensor> flat;
  flat.reserve(grads.size());
  for (const auto& g : grads) flat.push_back(g.reshape(-1));
  net.flat.mutable_grad() = torch::cat(flat);
  if (max_norm > 0) torch::nn::utils::clip_grad_norm_(net.flat, max_norm);
  opt.step();
}

// Moves a module's parameters to `d` before FlatParams gathers them there.
template <class M>
inline M& placed(M& m, torch::Device d) {
  m->to(d);
  return m;
}

}  // namespace farm
