// Policy network layout shared by the learner (LibTorch, training) and the workers (Eigen,
// inference). The flat parameter order is the contract: for each layer, the weight matrix
// [out x in] row-major (torch::nn::Linear's own layout), then its bias [out].
#pragma once

#include <Eigen/Dense>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

namespace farm {

enum class Activation : int32_t { kRelu = 0, kTanh = 1 };

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

struct MlpLayout {
  std::vector<int> sizes;  // [input, hidden..., output]
  Activation activation = Activation::kRelu;
  size_t num_params() const;
  std::string describe() const;  // e.g. "3-64-64-2 relu"
};

// Feed-forward network evaluated in Eigen on a batch of rows. Allocates only when the batch
// grows, so a worker's hot loop does not allocate.
class EigenMlp {
 public:
  using Matrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  EigenMlp() = default;
  // Throws std::invalid_argument if params.size() != layout.num_params().
  EigenMlp(const MlpLayout& layout, const std::vector<float>& params);
  const MlpLayout& layout() const { return layout_; }
  // in: [rows x sizes.front()], out: [rows x sizes.back()].
  void forward(const float* in, int rows, float* out);

 private:
  MlpLayout layout_;
  std::vector<Matrix> weights_;  // [out x in]
  std::vector<Eigen::Matrix<float, 1, Eigen::Dynamic>> biases_;
  std::vector<Matrix> acts_;  // scratch per layer
  // [in x out] copies for layers at least as wide out as in, evaluated as sums of columns
  // (faster there than row dot products); empty for the other layers.
  std::vector<Matrix> weights_t_;
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
  void act_per_row(const float* obs, int rows, std::mt19937_64* row_rngs, bool deterministic, float* actions,
                   float* log_prob);

 private:
  void act_rows(const float* obs, int rows, std::mt19937_64* rngs, size_t rng_stride, bool deterministic,
                float* actions, float* log_prob);
  void act_gaussian(int rows, std::mt19937_64* rngs, size_t rng_stride, bool deterministic, float* actions,
                    float* log_prob);
  void act_discrete(int rows, std::mt19937_64* rngs, size_t rng_stride, bool deterministic, float* actions,
                    float* log_prob);
  PolicyParams p_;
  EigenMlp net_;
  std::vector<float> normed_, out_;
};

}  // namespace farm
