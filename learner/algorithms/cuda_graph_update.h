// What SAC's and DQN's updates as CUDA graphs share (sac_cuda_graph.cpp, dqn.cpp): Adam inside the
// graph, and the warm-ups, capture and replays of one update. Included only where
// FARM_CUDA_GRAPHS is defined (a CUDA LibTorch).
#pragma once

#include <ATen/cuda/CUDAGraph.h>
#include <c10/cuda/CUDAFunctions.h>
#include <c10/cuda/CUDAGuard.h>
#include <c10/cuda/CUDAStream.h>
#include <torch/torch.h>

#include <memory>

#include <sstream>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

namespace farm {

// The key torch::optim keeps a parameter's state under: the parameter's TensorImpl address, as a
// string in older LibTorch releases and as the pointer itself in newer ones.
template <class Key>
Key optimizer_state_key(const torch::Tensor& p) {
  if constexpr (std::is_same_v<Key, std::string>) {
    std::ostringstream s;  // c10::guts::to_string's form
    s << p.unsafeGetTensorImpl();
    return s.str();
  } else {
    return static_cast<Key>(p.unsafeGetTensorImpl());
  }
}

// Adam as torch::optim::Adam computes it (no weight decay, no amsgrad), but in one fused kernel that
// reads the step counts from device tensors: a captured graph replays the same kernels with the
// same arguments, so a host-side step count (and with it the bias correction) would be frozen at
// its value during capture. The moment estimates are the torch::optim::Adam state tensors
// themselves, whose host step counts are advanced after each replay (advance_host_steps), so
// save(), load() and the eager path see the same optimizer state either way.
struct GraphAdam {
  GraphAdam(torch::optim::Adam& opt, std::vector<torch::Tensor> params_in) : params(std::move(params_in)) {
    // The state appears at the first step. One step with zero gradients creates it and leaves the
    // parameters exactly as they were (p - step_size * 0 / eps), then the counts are put back to 0.
    if (opt.state().empty()) {
      for (auto& p : params) p.mutable_grad() = torch::zeros_like(p);
      opt.step();
      for (auto& p : params) p.mutable_grad() = torch::Tensor();
      for (auto& p : params) state_of(opt, p).step(0);
    }
    const auto& o = static_cast<const torch::optim::AdamOptions&>(opt.param_groups()[0].options());
    if (o.weight_decay() != 0 || o.amsgrad())
      throw std::logic_error("cuda graph: Adam with weight decay or amsgrad is not supported");
    lr = o.lr();
    beta1 = std::get<0>(o.betas());
    beta2 = std::get<1>(o.betas());
    eps = o.eps();
    for (auto& p : params) {
      auto& st = state_of(opt, p);
      states.push_back(&st);
      exp_avg.push_back(st.exp_avg());
      exp_avg_sq.push_back(st.exp_avg_sq());
      step_count.push_back(torch::full({}, double(st.step()), p.options().dtype(torch::kFloat)));
    }
  }
  // Graph-safe: only device work. The step counts must have been advanced for this step
  // (advance_device_steps, which the caller may put off the critical path).
  void step(const std::vector<torch::Tensor>& grads) {
    torch::NoGradGuard no_grad;
    at::_fused_adam_(params, grads, exp_avg, exp_avg_sq, {}, step_count, lr, beta1, beta2, /*weight_decay=*/0.0, eps,
                     /*amsgrad=*/false, /*maximize=*/false);
  }
  void advance_device_steps() { torch::_foreach_add_(step_count, 1); }
  // After a replay (or a warm-up) is queued: the host's counts as the device's.
  void advance_host_steps() {
    for (auto* st : states) st->step(st->step() + 1);
  }

  std::vector<torch::Tensor> params, exp_avg, exp_avg_sq, step_count;
  std::vector<torch::optim::AdamParamState*> states;
  double lr, beta1, beta2, eps;

 private:
  static torch::optim::AdamParamState& state_of(torch::optim::Adam& opt, const torch::Tensor& p) {
    auto& state = opt.state();
    using Key = typename std::decay_t<decltype(state)>::key_type;
    const auto it = state.find(optimizer_state_key<Key>(p));
    if (it == state.end()) throw std::logic_error("cuda graph: a parameter without Adam state");
    return static_cast<torch::optim::AdamParamState&>(*it->second);
  }
};

// One update as a CUDA graph: `body` (which queues the update's kernels on the current stream)
// runs eagerly on the side stream `capture_stream` while `warmups_left` > 0, so that lazily created
// state (cuBLAS handles and workspaces, autograd's device threads, allocator blocks) exists before
// the capture; the next call captures it into `graph`; every call from then on replays it. The
// update runs once per call either way, the replay on the current stream (capture cannot use the
// default stream; the synchronizations keep the side stream ordered with it).
template <class Body>
void run_graph_update(std::unique_ptr<at::cuda::CUDAGraph>& graph, int& warmups_left, c10::DeviceIndex device,
                      const c10::cuda::CUDAStream& capture_stream, Body&& body) {
  if (graph) {
    graph->replay();
    return;
  }
  torch::cuda::synchronize(device);
  {
    c10::cuda::CUDAStreamGuard stream_guard(capture_stream);
    if (warmups_left > 0) {
      --warmups_left;
      body();
    } else {
      auto captured = std::make_unique<at::cuda::CUDAGraph>();
      captured->capture_begin();
      body();
      captured->capture_end();
      graph = std::move(captured);
    }
  }
  torch::cuda::synchronize(device);
  if (graph) graph->replay();  // capture recorded the update without running it
}

}  // namespace farm
