// One network's parameters made views of a single contiguous buffer, shared by SAC and TD3. Adam,
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

// Moves a module's parameters to `d` before FlatParams gathers them there.
template <class M>
inline M& placed(M& m, torch::Device d) {
  m->to(d);
  return m;
}

}  // namespace farm
