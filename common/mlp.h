// Policy network layout shared by the learner (LibTorch, training) and the workers (Eigen,
// inference). The flat parameter order is the contract: for each layer, the weight matrix
// [out x in] row-major (torch::nn::Linear's own layout), then its bias [out].
#pragma once

#include <cstdint>
#include <random>
#include <string>
#include <vector>

namespace farm {

// The hidden layers' activation; the values are the wire's (PolicyWeights.activation). kElu:
// x > 0 ? x : exp(x) - 1 (alpha 1, legged_gym's actor), computed with std::expm1.
enum class Activation : int32_t { kRelu = 0, kTanh = 1, kElu = 2 };
// Whether a wire value is one of the above.
bool activation_known(int32_t wire);
// The activation a config names ("relu", "tanh" or "elu"); std::invalid_argument otherwise.
Activation activation_from_name(const std::string& name);

// How the network output turns into an action.
enum class PolicyHead : int32_t {
  // SAC: output [mean | log_std] (2 x act_dim); a = tanh(mean + std * eps), in [-1, 1].
  kSquashedGaussian = 0,
  // DQN: output Q(s, a) for every discrete action; the action is argmax_a Q as one float (the
  // index), or with probability epsilon a uniformly random index when not deterministic.
  kDiscreteQ = 2,
  // PPO: output the mean (act_dim); a state-independent learned log-std (PolicyParams::log_std);
  // a = clamp(mean + std * eps, -1, 1); log_prob is that of the clipped Gaussian: the density
  // inside (-1, 1), the probability mass beyond the bound where a sample was clamped.
  kGaussian = 1,
};

// Bounds on a layout, far above any network of the farm, so that num_params() cannot overflow
// (64 layers of at most 2^20 x 2^20 weights): a layout comes over the network (PolicyWeights), and
// one whose count wrapped around 2^64 to the number of floats it carried would pass the size check.
inline constexpr int kMaxMlpWidth = 1 << 20;
inline constexpr size_t kMaxMlpLayers = 64;

struct MlpLayout {
  std::vector<int> sizes;  // [input, hidden..., output]
  Activation activation = Activation::kRelu;
  // Throws std::invalid_argument, naming what is wrong, unless there are 2 .. kMaxMlpLayers + 1
  // sizes, each in 1 .. kMaxMlpWidth.
  void check() const;
  size_t num_params() const;     // the flat parameter count; call check() first
  std::string describe() const;  // e.g. "3-64-64-2 relu" (or tanh, elu)
};

// Which compiled form of the forward kernel (common/mlp_kernel.cpp) a network runs. kBaseline
// runs on any x86-64 (SSE2: a multiply and an add, each rounded); kAvx2Fma needs a CPU with AVX2
// and FMA (a fused multiply-add, rounded once), so the two paths may differ in the last bits of
// a result. On one path a row's result never depends on the batch (see EigenMlp::forward).
// kAuto: kAvx2Fma where the CPU has it, unless the environment sets FARM_MLP_ISA=baseline
// (FARM_MLP_ISA=avx2 asks for the AVX2 path and fails where the CPU lacks it; auto or unset
// chooses by the CPU).
enum class MlpIsa : int32_t { kAuto = -1, kBaseline = 0, kAvx2Fma = 1 };
const char* mlp_isa_name(MlpIsa isa);  // "auto", "baseline", "avx2+fma"
bool mlp_isa_supported(MlpIsa isa);    // whether this CPU can run the path (kAuto: always)

// Feed-forward network evaluated on a batch of rows by the kernel of common/mlp_kernel.h, a block
// of rows per pass over each weight matrix. Allocates only when the batch grows, so a worker's
// hot loop does not allocate.
class EigenMlp {
 public:
  EigenMlp() = default;
  // Throws std::invalid_argument if params.size() != layout.num_params(), on an unknown
  // FARM_MLP_ISA value (kAuto), or if the CPU cannot run the path asked for.
  EigenMlp(const MlpLayout& layout, const std::vector<float>& params, MlpIsa isa = MlpIsa::kAuto);
  const MlpLayout& layout() const { return layout_; }
  MlpIsa isa() const { return isa_; }  // the path chosen at construction, never kAuto
  // in: [rows x sizes.front()], out: [rows x sizes.back()]. Row r of out depends on row r of in
  // only, bit for bit, whatever other rows share the call (on one path, on one machine).
  void forward(const float* in, int rows, float* out);

 private:
  MlpLayout layout_;
  MlpIsa isa_ = MlpIsa::kBaseline;
  // Per layer, the weights and bias packed for the kernel (mlp_kernel::pack_layer), and the
  // layer's output width padded to the kernel's panel width.
  std::vector<std::vector<float>> panels_, biases_;
  std::vector<int> widths_;
  // Two activation buffers, [rows x widest padded layer] each, used in turn layer by layer.
  std::vector<float> scratch_;
};

// A policy as the workers run it: observation normalizer + network + head.
struct PolicyParams {
  uint64_t version = 0;
  PolicyHead head = PolicyHead::kSquashedGaussian;
  MlpLayout layout;
  std::vector<float> obs_mean;  // empty: no normalization
  std::vector<float> obs_std;
  std::vector<float> params;
  float log_std_min = -20.f;
  float log_std_max = 2.f;
  float epsilon = 0.f;         // kDiscreteQ: exploration probability, in [0, 1]
  std::vector<float> log_std;  // kGaussian: act_dim values; empty for the other heads
};

// log Phi(z), the standard normal's log CDF, accurate far into the lower tail.
double gaussian_log_cdf(double z);

class Policy {
 public:
  Policy() = default;
  explicit Policy(const PolicyParams& p);  // throws std::invalid_argument on inconsistent sizes
  uint64_t version() const { return p_.version; }
  int obs_dim() const;
  int act_dim() const;
  // kDiscreteQ: the number of discrete actions (Q outputs); 0 for continuous heads.
  int num_actions() const;
  // obs: [rows x obs_dim]; actions: [rows x act_dim] in [-1, 1]; log_prob: [rows] (may be null).
  // deterministic: the mode (tanh(mean)), no noise, log_prob of the mode is not computed.
  void act(const float* obs, int rows, std::mt19937_64& rng, bool deterministic, float* actions, float* log_prob);
  // As act(), but row r draws its noise from row_rngs[r] only, so a row's action does not
  // depend on which other rows share the call (rollouts reproducible across thread splits).
  // row_scale (null: 1 for every row): kSquashedGaussian's std of row r times row_scale[r] > 0
  // (worker.exploration_scale_min/max), its log_prob that of the scaled Gaussian; the other
  // heads ignore it.
  void act_per_row(const float* obs, int rows, std::mt19937_64* row_rngs, bool deterministic, float* actions,
                   float* log_prob, const float* row_scale = nullptr);

 private:
  void act_rows(const float* obs, int rows, std::mt19937_64* rngs, size_t rng_stride, bool deterministic,
                float* actions, float* log_prob, const float* row_scale = nullptr);
  void act_gaussian(int rows, std::mt19937_64* rngs, size_t rng_stride, bool deterministic, float* actions,
                    float* log_prob);
  void act_discrete(int rows, std::mt19937_64* rngs, size_t rng_stride, bool deterministic, float* actions,
                    float* log_prob);
  PolicyParams p_;
  EigenMlp net_;
  std::vector<float> normed_, out_;
};

}  // namespace farm
