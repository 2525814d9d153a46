// The fused kernels of sac_cuda_kernels.h. Each is a handful of float operations per row, so one
// thread takes one batch row (and its A action components); what they save is the launches and
// round trips through memory of the dozen or so kernels that torch's ops would take for the same
// formulas, which is what a small network's update waits for on a GPU.
#include "sac_cuda_kernels.h"

#include <cuda_bf16.h>

namespace farm::sac_kernels {
namespace {

constexpr int kThreads = 256;
constexpr float kHalfLog2Pi = 0.91893853320467274178f;  // log(2 pi) / 2
constexpr float kSquashEps = 1e-6f;

int blocks_for(int n) { return (n + kThreads - 1) / kThreads; }

// torch's clamp and min propagate NaN (fminf and fmaxf would drop it): a diverged actor's or
// critic's NaN must reach the figures that the divergence guard reads.
__device__ __forceinline__ float clamp_nan(float x, float lo, float hi) { return x < lo ? lo : (x > hi ? hi : x); }
__device__ __forceinline__ float min_nan(float a, float b) {
  if (a != a) return a;
  if (b != b) return b;
  return a < b ? a : b;
}

__global__ void squashed_sample_forward_k(const float* __restrict__ out, const float* __restrict__ noise,
                                          float* __restrict__ action, float* __restrict__ log_prob, int B, int A,
                                          float lo, float hi) {
  const int b = blockIdx.x * blockDim.x + threadIdx.x;
  if (b >= B) return;
  const float* o = out + size_t(b) * 2 * A;
  const float* n = noise + size_t(b) * A;
  float* act = action + size_t(b) * A;
  float lp = 0.f;
  for (int j = 0; j < A; ++j) {
    const float ls = clamp_nan(o[A + j], lo, hi);
    const float a = tanhf(fmaf(expf(ls), n[j], o[j]));
    act[j] = a;
    lp += -0.5f * n[j] * n[j] - kHalfLog2Pi - ls - logf(1.f - a * a + kSquashEps);
  }
  log_prob[b] = lp;
}

__global__ void squashed_sample_backward_k(const float* __restrict__ out, const float* __restrict__ noise,
                                           const float* __restrict__ action, const float* __restrict__ g_action,
                                           int ld_g_action, const float* __restrict__ g_log_prob,
                                           float* __restrict__ g_out, int B, int A, float lo, float hi) {
  const int b = blockIdx.x * blockDim.x + threadIdx.x;
  if (b >= B) return;
  const float* o = out + size_t(b) * 2 * A;
  const float* n = noise + size_t(b) * A;
  const float* act = action + size_t(b) * A;
  float* g = g_out + size_t(b) * 2 * A;
  const float g_lp = g_log_prob ? g_log_prob[b] : 0.f;
  for (int j = 0; j < A; ++j) {
    const float a = act[j];
    // log_prob holds -log(1 - a^2 + eps): d/da = 2a / (1 - a^2 + eps); tanh' = 1 - a^2.
    float g_a = g_lp * 2.f * a / (1.f - a * a + kSquashEps);
    if (g_action) g_a += g_action[size_t(b) * ld_g_action + j];
    const float g_pre = g_a * (1.f - a * a);
    const float x = o[A + j];
    const float ls = clamp_nan(x, lo, hi);
    g[j] = g_pre;
    // d pre / d ls = exp(ls) * noise; d log_prob / d ls = -1 (the noise held fixed).
    g[A + j] = (x >= lo && x <= hi) ? g_pre * expf(ls) * n[j] - g_lp : 0.f;
  }
}

__global__ void soft_target_k(const float* __restrict__ next_q, const float* __restrict__ next_log_prob,
                              const float* __restrict__ alpha, const float* __restrict__ rewards,
                              const float* __restrict__ terminated, float gamma, float* __restrict__ target, int B) {
  const int b = blockIdx.x * blockDim.x + threadIdx.x;
  if (b >= B) return;
  const float soft_v = min_nan(next_q[b], next_q[B + b]) - next_log_prob[b] * alpha[0];
  target[b] = rewards[b] + gamma * soft_v * (1.f - terminated[b]);
}

// Block sums in a grid-stride loop, one partial per block; then one block sums the partials. A
// batch of tens of thousands would keep a single block busy for a tenth of a millisecond.
constexpr int kMaxPartials = 128;

__device__ float block_sum(float s) {
  __shared__ float partial[kThreads];
  partial[threadIdx.x] = s;
  __syncthreads();
  for (int stride = blockDim.x / 2; stride > 0; stride /= 2) {
    if (threadIdx.x < stride) partial[threadIdx.x] += partial[threadIdx.x + stride];
    __syncthreads();
  }
  return partial[0];
}

__global__ void actor_objective_partial_k(const float* __restrict__ q, const float* __restrict__ log_prob,
                                          const float* __restrict__ alpha, float* __restrict__ partial, int B) {
  const float a = alpha[0];
  float s = 0.f;
  for (int b = blockIdx.x * blockDim.x + threadIdx.x; b < B; b += gridDim.x * blockDim.x)
    s += a * log_prob[b] - min_nan(q[b], q[B + b]);
  const float total = block_sum(s);
  if (threadIdx.x == 0) partial[blockIdx.x] = total;
}

__global__ void actor_objective_total_k(const float* __restrict__ partial, int n, float* __restrict__ loss, int B) {
  float s = 0.f;
  for (int i = threadIdx.x; i < n; i += blockDim.x) s += partial[i];
  const float total = block_sum(s);
  if (threadIdx.x == 0) loss[0] = total / float(B);
}

__global__ void actor_objective_backward_k(const float* __restrict__ q, const float* __restrict__ alpha,
                                           const float* __restrict__ g_loss, float* __restrict__ g_q,
                                           float* __restrict__ g_log_prob, int B) {
  const int b = blockIdx.x * blockDim.x + threadIdx.x;
  if (b >= B) return;
  const float g = g_loss[0] / float(B);
  g_log_prob[b] = g * alpha[0];
  // d/dq of -min(q0, q1): torch's min gives a tie half to each side, and with a NaN the whole to both.
  const float q0 = q[b], q1 = q[B + b];
  g_q[b] = q0 == q1 ? -0.5f * g : (q0 > q1 ? 0.f : -g);
  g_q[B + b] = q0 == q1 ? -0.5f * g : (q1 > q0 ? 0.f : -g);
}

// One thread per float of the batch: neighbouring threads read neighbouring floats of a row.
__global__ void gather_rows_k(const float* __restrict__ rows, const double* __restrict__ u,
                              const long long* __restrict__ fill, float* __restrict__ out, int B, int O, int A) {
  const int W = 2 * O + A + 2;
  const long long t = (long long)blockIdx.x * blockDim.x + threadIdx.x;
  if (t >= (long long)B * W) return;
  const int b = int(t / W), c = int(t % W);
  const long long n = fill[0];
  long long row = (long long)(u[b] * double(n));
  if (row > n - 1) row = n - 1;
  const float v = rows[row * W + c];
  const long long plane = (long long)B;
  if (c < O)
    out[(long long)b * O + c] = v;
  else if (c < O + A)
    out[plane * O + (long long)b * A + (c - O)] = v;
  else if (c == O + A)
    out[plane * (O + A) + b] = v;
  else if (c == O + A + 1)
    out[plane * (O + A + 1) + b] = v;
  else
    out[plane * (O + A + 2) + (long long)b * O + (c - O - A - 2)] = v;
}

// 16 bytes a thread: 8 bfloat16 or 4 float32 values, loaded and stored as one uint4.
template <typename T>
struct Pack {
  static constexpr int kN = 16 / sizeof(T);
  union {
    uint4 raw;
    T v[kN];
  };
};
__device__ __forceinline__ float to_f(float x) { return x; }
__device__ __forceinline__ float to_f(__nv_bfloat16 x) { return __bfloat162float(x); }
template <typename T>
__device__ __forceinline__ T from_f(float x);
template <>
__device__ __forceinline__ float from_f<float>(float x) {
  return x;
}
template <>
__device__ __forceinline__ __nv_bfloat16 from_f<__nv_bfloat16>(float x) {
  return __float2bfloat16(x);
}

template <typename T>
__global__ void bias_relu_k(T* __restrict__ y, const T* __restrict__ bias, long long packs, int cols,
                            long long rows_per_bias, bool relu) {
  constexpr int kN = Pack<T>::kN;
  for (long long p = (long long)blockIdx.x * blockDim.x + threadIdx.x; p < packs;
       p += (long long)gridDim.x * blockDim.x) {
    const long long i = p * kN;
    const long long row = i / cols;
    const T* b = bias + (row / rows_per_bias) * cols + (i % cols);
    Pack<T> pk;
    pk.raw = reinterpret_cast<const uint4*>(y)[p];
#pragma unroll
    for (int k = 0; k < kN; ++k) {
      float v = to_f(pk.v[k]) + to_f(b[k]);
      if (relu && v < 0.f) v = 0.f;
      pk.v[k] = from_f<T>(v);
    }
    reinterpret_cast<uint4*>(y)[p] = pk.raw;
  }
}

template <typename T>
__global__ void relu_backward_k(const T* __restrict__ y, const T* __restrict__ g, T* __restrict__ g_in,
                                long long packs) {
  constexpr int kN = Pack<T>::kN;
  for (long long p = (long long)blockIdx.x * blockDim.x + threadIdx.x; p < packs;
       p += (long long)gridDim.x * blockDim.x) {
    Pack<T> yp, gp;
    yp.raw = reinterpret_cast<const uint4*>(y)[p];
    gp.raw = reinterpret_cast<const uint4*>(g)[p];
#pragma unroll
    for (int k = 0; k < kN; ++k)
      if (to_f(yp.v[k]) <= 0.f) gp.v[k] = from_f<T>(0.f);
    reinterpret_cast<uint4*>(g_in)[p] = gp.raw;
  }
}

template <typename T>
__global__ void relu_backward_bias_k(const T* __restrict__ y, const T* __restrict__ g, T* __restrict__ g_in,
                                     float* __restrict__ partial, long long rows, int cols, long long chunk_rows,
                                     int chunks) {
  constexpr int kN = Pack<T>::kN;
  extern __shared__ float sums[];  // [blockDim.y][cols]
  const int packs = cols / kN, px = threadIdx.x, group = blockIdx.z, chunk = blockIdx.y;
  const long long r0 = chunk * chunk_rows, r1 = r0 + chunk_rows < rows ? r0 + chunk_rows : rows;
  float acc[kN];
#pragma unroll
  for (int k = 0; k < kN; ++k) acc[k] = 0.f;
  for (long long r = r0 + threadIdx.y; r < r1; r += blockDim.y) {
    const long long p = (group * rows + r) * packs + px;
    Pack<T> yp, gp;
    yp.raw = reinterpret_cast<const uint4*>(y)[p];
    gp.raw = reinterpret_cast<const uint4*>(g)[p];
#pragma unroll
    for (int k = 0; k < kN; ++k) {
      if (to_f(yp.v[k]) <= 0.f) gp.v[k] = from_f<T>(0.f);
      acc[k] += to_f(gp.v[k]);
    }
    reinterpret_cast<uint4*>(g_in)[p] = gp.raw;
  }
#pragma unroll
  for (int k = 0; k < kN; ++k) sums[threadIdx.y * cols + px * kN + k] = acc[k];
  __syncthreads();
  if (threadIdx.y != 0) return;
#pragma unroll
  for (int k = 0; k < kN; ++k) {
    float s = 0.f;
    for (int j = 0; j < int(blockDim.y); ++j) s += sums[j * cols + px * kN + k];
    partial[((long long)group * chunks + chunk) * cols + px * kN + k] = s;
  }
}

int grid_for(long long packs) {
  const long long blocks = (packs + kThreads - 1) / kThreads;
  return int(blocks < 65535 ? (blocks < 1 ? 1 : blocks) : 65535);
}

}  // namespace

cudaError_t bias_relu_forward(void* y, const void* bias, long long n, int cols, long long rows_per_bias, bool relu,
                              bool bf16, cudaStream_t stream) {
  const int k = bf16 ? Pack<__nv_bfloat16>::kN : Pack<float>::kN;
  if (n % k != 0 || cols % k != 0) return cudaErrorInvalidValue;
  if (bf16)
    bias_relu_k<<<grid_for(n / k), kThreads, 0, stream>>>(
        static_cast<__nv_bfloat16*>(y), static_cast<const __nv_bfloat16*>(bias), n / k, cols, rows_per_bias, relu);
  else
    bias_relu_k<<<grid_for(n / k), kThreads, 0, stream>>>(static_cast<float*>(y), static_cast<const float*>(bias),
                                                          n / k, cols, rows_per_bias, relu);
  return cudaGetLastError();
}

int relu_backward_bias_chunks(long long rows) {
  const long long c = rows / 256;
  return int(c < 1 ? 1 : (c > 256 ? 256 : c));
}

cudaError_t relu_backward_bias(const void* y, const void* g, void* g_in, float* partial, int groups, long long rows,
                               int cols, bool bf16, cudaStream_t stream) {
  const int k = bf16 ? Pack<__nv_bfloat16>::kN : Pack<float>::kN;
  if (cols % k != 0 || cols / k > kThreads || groups < 1 || rows < 1) return cudaErrorInvalidValue;
  const int packs = cols / k, chunks = relu_backward_bias_chunks(rows);
  const long long chunk_rows = (rows + chunks - 1) / chunks;
  const dim3 block(packs, kThreads / packs > 0 ? kThreads / packs : 1), grid(1, chunks, groups);
  const size_t shared = sizeof(float) * block.y * cols;
  if (bf16)
    relu_backward_bias_k<<<grid, block, shared, stream>>>(
        static_cast<const __nv_bfloat16*>(y), static_cast<const __nv_bfloat16*>(g), static_cast<__nv_bfloat16*>(g_in),
        partial, rows, cols, chunk_rows, chunks);
  else
    relu_backward_bias_k<<<grid, block, shared, stream>>>(static_cast<const float*>(y), static_cast<const float*>(g),
                                                          static_cast<float*>(g_in), partial, rows, cols, chunk_rows,
                                                          chunks);
  return cudaGetLastError();
}

cudaError_t relu_backward(const void* y, const void* g, void* g_in, long long n, bool bf16, cudaStream_t stream) {
  const int k = bf16 ? Pack<__nv_bfloat16>::kN : Pack<float>::kN;
  if (n % k != 0) return cudaErrorInvalidValue;
  if (bf16)
    relu_backward_k<<<grid_for(n / k), kThreads, 0, stream>>>(static_cast<const __nv_bfloat16*>(y),
                                                              static_cast<const __nv_bfloat16*>(g),
                                                              static_cast<__nv_bfloat16*>(g_in), n / k);
  else
    relu_backward_k<<<grid_for(n / k), kThreads, 0, stream>>>(
        static_cast<const float*>(y), static_cast<const float*>(g), static_cast<float*>(g_in), n / k);
  return cudaGetLastError();
}

cudaError_t gather_rows(const float* rows, const double* u, const long long* fill, float* out, int B, int O, int A,
                        cudaStream_t stream) {
  const long long n = (long long)B * (2 * O + A + 2);
  gather_rows_k<<<int((n + kThreads - 1) / kThreads), kThreads, 0, stream>>>(rows, u, fill, out, B, O, A);
  return cudaGetLastError();
}

cudaError_t squashed_sample_forward(const float* out, const float* noise, float* action, float* log_prob, int B, int A,
                                    float lo, float hi, cudaStream_t stream) {
  squashed_sample_forward_k<<<blocks_for(B), kThreads, 0, stream>>>(out, noise, action, log_prob, B, A, lo, hi);
  return cudaGetLastError();
}

cudaError_t squashed_sample_backward(const float* out, const float* noise, const float* action, const float* g_action,
                                     int ld_g_action, const float* g_log_prob, float* g_out, int B, int A, float lo,
                                     float hi, cudaStream_t stream) {
  squashed_sample_backward_k<<<blocks_for(B), kThreads, 0, stream>>>(out, noise, action, g_action, ld_g_action,
                                                                     g_log_prob, g_out, B, A, lo, hi);
  return cudaGetLastError();
}

cudaError_t soft_target(const float* next_q, const float* next_log_prob, const float* alpha, const float* rewards,
                        const float* terminated, float gamma, float* target, int B, cudaStream_t stream) {
  soft_target_k<<<blocks_for(B), kThreads, 0, stream>>>(next_q, next_log_prob, alpha, rewards, terminated, gamma,
                                                        target, B);
  return cudaGetLastError();
}

int actor_objective_partials(int B) {
  return B < 1 ? 1 : (blocks_for(B) < kMaxPartials ? blocks_for(B) : kMaxPartials);
}

cudaError_t actor_objective_forward(const float* q, const float* log_prob, const float* alpha, float* partial,
                                    float* loss, int B, cudaStream_t stream) {
  const int n = actor_objective_partials(B);
  actor_objective_partial_k<<<n, kThreads, 0, stream>>>(q, log_prob, alpha, partial, B);
  if (const cudaError_t e = cudaGetLastError(); e != cudaSuccess) return e;
  actor_objective_total_k<<<1, kThreads, 0, stream>>>(partial, n, loss, B);
  return cudaGetLastError();
}

cudaError_t actor_objective_backward(const float* q, const float* alpha, const float* g_loss, float* g_q,
                                     float* g_log_prob, int B, cudaStream_t stream) {
  actor_objective_backward_k<<<blocks_for(B), kThreads, 0, stream>>>(q, alpha, g_loss, g_q, g_log_prob, B);
  return cudaGetLastError();
}

}  // namespace farm::sac_kernels
