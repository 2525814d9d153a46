// Fused CUDA kernels for the SAC update's graph (sac_cuda_graph.cpp, sac.cuda_fused_kernels): each
// replaces a run of small elementwise or reduction kernels on the update's critical path with one.
// Built only with a CUDA compiler next to a CUDA LibTorch (learner/algorithms/CMakeLists.txt,
// FARM_CUDA_KERNELS). Plain pointers and sizes, no Torch: the callers check shapes, strides and
// devices; every launcher enqueues on `stream` and returns the launch's error.
#pragma once

#include <cuda_runtime_api.h>

namespace farm::sac_kernels {

// The tanh-squashed Gaussian sample from the actor's output `out` [B, 2A] (mean, then the
// unclamped log std) and standard normal `noise` [B, A]: action [B, A] = tanh(mean + exp(ls) *
// noise) with ls = clamp(log std, lo, hi), and log_prob [B] = sum over A of
// -noise^2 / 2 - log(2 pi) / 2 - ls - log(1 - action^2 + 1e-6). All contiguous.
cudaError_t squashed_sample_forward(const float* out, const float* noise, float* action, float* log_prob, int B, int A,
                                    float lo, float hi, cudaStream_t stream);

// Its gradient: g_out [B, 2A] from g_action [B, A] (row stride ld_g_action; null for zero) and
// g_log_prob [B] (null for zero), with the noise held fixed (the reparameterization) and the clamp
// passing the gradient where lo <= log std <= hi, as torch's clamp does.
cudaError_t squashed_sample_backward(const float* out, const float* noise, const float* action, const float* g_action,
                                     int ld_g_action, const float* g_log_prob, float* g_out, int B, int A, float lo,
                                     float hi, cudaStream_t stream);

// The critics' target [B]: rewards + gamma * (1 - terminated) * (min(next_q[0], next_q[1]) -
// alpha[0] * next_log_prob), next_q [2, B].
cudaError_t soft_target(const float* next_q, const float* next_log_prob, const float* alpha, const float* rewards,
                        const float* terminated, float gamma, float* target, int B, cudaStream_t stream);

// The actor's loss: loss[0] = mean over B of alpha[0] * log_prob - min(q[0], q[1]), q [2, B].
// partial: actor_objective_partials(B) floats of scratch (each block's sum, then summed in a fixed
// order: the same loss for the same input on every run).
int actor_objective_partials(int B);
cudaError_t actor_objective_forward(const float* q, const float* log_prob, const float* alpha, float* partial,
                                    float* loss, int B, cudaStream_t stream);

// Its gradient for an upstream g_loss[0]: g_q [2, B] (to the smaller critic, half each on a tie, as
// torch::min gives it) and g_log_prob [B].
cudaError_t actor_objective_backward(const float* q, const float* alpha, const float* g_loss, float* g_q,
                                     float* g_log_prob, int B, cudaStream_t stream);

// A replay minibatch drawn inside the graph (sac.replay_on_device): row b is
// rows[min(floor(u[b] * fill[0]), fill[0] - 1)] of the packed rows [*, 2O + A + 2] (obs | action |
// reward | terminated | next_obs, DeviceReplay), written field by field into `out`: obs [B, O],
// then actions [B, A], rewards [B], terminated [B] and next_obs [B, O], each contiguous.
cudaError_t gather_rows(const float* rows, const double* u, const long long* fill, float* out, int B, int O, int A,
                        cudaStream_t stream);

// A hidden layer's epilogue over y [n / cols, cols] (the critics' [2, B, H] products): y += bias,
// bias [2, H] picked by the row's critic (row / rows_per_bias), then ReLU where `relu` (NaN kept,
// as torch's). In place; float32 or bfloat16 (`bf16`), contiguous, 16-byte aligned.
cudaError_t bias_relu_forward(void* y, const void* bias, long long n, int cols, long long rows_per_bias, bool relu,
                              bool bf16, cudaStream_t stream);

// ReLU's gradient from its output: g_in[i] = y[i] <= 0 ? 0 : g[i] (torch's threshold_backward).
cudaError_t relu_backward(const void* y, const void* g, void* g_in, long long n, bool bf16, cudaStream_t stream);

// ReLU's gradient and the bias gradient in one pass, for y, g and g_in [groups, rows, cols] (a
// critic a group): g_in as relu_backward's, and partial [groups, chunks, cols] (float32) the sums
// of g_in over each chunk of relu_backward_bias_chunks(rows) rows, to be summed over the chunks
// (a fixed order: the same sums on every run). cols / (16 / element size) at most 256.
int relu_backward_bias_chunks(long long rows);
cudaError_t relu_backward_bias(const void* y, const void* g, void* g_in, float* partial, int groups, long long rows,
                               int cols, bool bf16, cudaStream_t stream);

}  // namespace farm::sac_kernels
