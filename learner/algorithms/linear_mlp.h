// The multilayer perceptron of torch::nn::Linear layers that SAC's actor and DQN's Q networks are,
// with what a large batch on a GPU needs of it: products in bfloat16 where the config asks
// (sac.matmul_dtype, dqn.matmul_dtype), inputs and outputs widened to multiples of 8
// (padded_input), and the hidden layers' product, bias and ReLU as one fused layer where one is
// given (SAC's kernels, sac_cuda_graph.cpp).
#pragma once

#include <torch/torch.h>

#include <cstdint>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

namespace farm {

// A layer's x [G, B, in] @ w [G, in, out] + b [G, 1, out] for G groups (SAC's two critics, or one
// network as one group), then ReLU where `relu`, with a backward that takes the bias gradient as a
// product too (sac_cuda_graph.cpp, fused kernels).
using TwinLayerFn = torch::Tensor (*)(const torch::Tensor& x, const torch::Tensor& w, const torch::Tensor& b,
                                      bool relu);

// The large-batch path (padded_input, TwinLayerFn) from this many rows on. Below it an update is
// bound by its chain of launches, not by bytes or products, and the padding and the fused layers
// only add launches to it.
constexpr int64_t kLargeBatchRows = 1024;

// Zero columns that make n a multiple of 8.
inline int64_t to_multiple_of_8(int64_t n) { return (8 - n % 8) % 8; }

// x [..., in] and a weight with `in` along dimension `dim`, both widened with zeros to a multiple
// of 8: the same products (the added terms are exact zeros, and the weight's gradient is the
// slice of the widened one), but cuBLAS runs 8-aligned matrices on its tensor-core kernels, while
// an odd width (an observation of 17, a critic input of 23) sends the products and, worst, the
// weight gradient summed over a batch of tens of thousands to its slow unaligned ones: at a batch
// of 32,768 that one gradient took a third of a SAC update on an H100. The networks' parameters
// keep their shapes (checkpoints and the workers' weights are unchanged).
inline std::pair<torch::Tensor, torch::Tensor> padded_input(const torch::Tensor& x, const torch::Tensor& w,
                                                            int64_t dim) {
  const int64_t extra = to_multiple_of_8(x.size(-1));
  if (extra == 0) return {x, w};
  std::vector<int64_t> pad_w(2 * (w.dim() - dim), 0);  // constant_pad_nd lists the last dimension first
  pad_w.back() = extra;
  return {torch::constant_pad_nd(x, {0, extra}), torch::constant_pad_nd(w, pad_w)};
}

// A section's matmul_dtype ("float32" or "bfloat16", which config validation checks) as a scalar
// type; `section` names it in the error for anything else.
inline torch::ScalarType matmul_dtype_named(const std::string& value, const std::string& section) {
  if (value != "float32" && value != "bfloat16")
    throw std::invalid_argument(section + ".matmul_dtype must be \"float32\" or \"bfloat16\", got \"" + value + "\"");
  return value == "bfloat16" ? torch::kBFloat16 : torch::kFloat;
}

// Plain MLP of torch::nn::Linear layers ("l0", "l1", ...), so that weight.flatten() then bias is the
// flat layout the workers' EigenMlp reads; ReLU (or tanh) between layers, none after the last.
struct LinearMlpImpl : torch::nn::Module {
  LinearMlpImpl(const std::vector<int64_t>& sizes, bool tanh_hidden) : tanh_hidden(tanh_hidden) {
    for (size_t i = 0; i + 1 < sizes.size(); ++i)
      layers.push_back(register_module("l" + std::to_string(i), torch::nn::Linear(sizes[i], sizes[i + 1])));
  }
  torch::Tensor forward(torch::Tensor x) {
    const bool cast = compute != torch::kFloat;  // matmul_dtype
    const bool large = x.size(0) >= kLargeBatchRows;
    const bool pad = pad_on_cuda && large;
    const TwinLayerFn layer = large ? this->layer : nullptr;
    if (cast) x = x.to(compute);
    const int64_t out = layers.back()->weight.size(0);
    for (size_t i = 0; i < layers.size(); ++i) {
      torch::Tensor w = layers[i]->weight, b = layers[i]->bias;  // [out, in], [out]
      if (cast) {
        w = w.to(compute);
        b = b.to(compute);
      }
      if (pad && i == 0) std::tie(x, w) = padded_input(x, w, 1);
      if (pad && i + 1 == layers.size()) {
        const int64_t extra = to_multiple_of_8(out);
        w = torch::constant_pad_nd(w, {0, 0, 0, extra});
        b = torch::constant_pad_nd(b, {0, extra});
      }
      const bool hidden = i + 1 < layers.size();
      if (layer && hidden && !tanh_hidden) {  // as one group of TwinLayerFn's
        x = layer(x.unsqueeze(0), w.t().unsqueeze(0), b.view({1, 1, -1}), true).squeeze(0);
        continue;
      }
      x = torch::linear(x, w, b);
      if (hidden) tanh_hidden ? x.tanh_() : x.relu_();
    }
    if (x.size(1) != out) x = x.narrow(1, 0, out);
    return cast ? x.to(torch::kFloat) : x;
  }
  std::vector<torch::nn::Linear> layers;
  bool tanh_hidden;
  // The products' type (matmul_dtype): with bfloat16 each product casts its weights and input, and
  // the output comes back as float32, as torch's autocast does; the parameters stay float32.
  torch::ScalarType compute = torch::kFloat;
  bool pad_on_cuda = false;     // see padded_input
  TwinLayerFn layer = nullptr;  // large batches: the hidden layers' fused product, bias and ReLU
};
TORCH_MODULE(LinearMlp);

}  // namespace farm
