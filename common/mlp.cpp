#include "mlp.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace farm {

namespace {

constexpr float kHalfLog2Pi = 0.91893853320467274178f;
// Keeps log(1 - tanh(u)^2) finite when tanh saturates; the learner's log-prob uses the same
// constant (stable-baselines3's value), so behaviour and target log-probs agree.
constexpr float kTanhLogEps = 1e-6f;

const char* activation_name(Activation a) {
  switch (a) {
    case Activation::kRelu:
      return "relu";
    case Activation::kTanh:
      return "tanh";
  }
  return "unknown-activation";
}

// Grows a scratch matrix's storage, never shrinks it, so steady-state calls do not allocate.
// Rows are padded to 64 bytes so every row starts at the same alignment: Eigen picks its
// scalar/packet split by address, and the activation must not vary with a row's position.
void reserve_rows(EigenMlp::Matrix& m, int rows, int cols) {
  const Eigen::Index padded = (cols + 15) / 16 * 16;
  if (m.rows() < rows || m.cols() != padded) {
    m.resize(std::max<Eigen::Index>(rows, m.rows()), padded);
  }
}

}  // namespace

size_t MlpLayout::num_params() const {
  size_t n = 0;
  for (size_t l = 0; l + 1 < sizes.size(); ++l) {
    n += size_t(sizes[l + 1]) * size_t(sizes[l]) + size_t(sizes[l + 1]);
  }
  return n;
}

std::string MlpLayout::describe() const {
  std::ostringstream s;
  for (size_t i = 0; i < sizes.size(); ++i) s << (i ? "-" : "") << sizes[i];
  s << " " << activation_name(activation);
  return s.str();
}

EigenMlp::EigenMlp(const MlpLayout& layout, const std::vector<float>& params) : layout_(layout) {
  if (layout.sizes.size() < 2) {
    throw std::invalid_argument("mlp layout '" + layout.describe() + "': needs at least an input and an output size");
  }
  for (size_t i = 0; i < layout.sizes.size(); ++i) {
    if (layout.sizes[i] <= 0) {
      throw std::invalid_argument("mlp layout '" + layout.describe() + "': size " + std::to_string(i) + " is " +
                                  std::to_string(layout.sizes[i]) + ", must be > 0");
    }
  }
  if (layout.activation != Activation::kRelu && layout.activation != Activation::kTanh) {
    throw std::invalid_argument("mlp layout: unknown activation " + std::to_string(int(layout.activation)));
  }
  if (params.size() != layout.num_params()) {
    throw std::invalid_argument("mlp params: expected " + std::to_string(layout.num_params()) + " floats for layout " +
                                layout.describe() + ", got " + std::to_string(params.size()));
  }
  const size_t layers = layout.sizes.size() - 1;
  weights_.resize(layers);
  biases_.resize(layers);
  acts_.resize(layers);
  weights_t_.resize(layers);
  const float* p = params.data();
  for (size_t l = 0; l < layers; ++l) {
    const int in = layout.sizes[l], out = layout.sizes[l + 1];
    weights_[l] = Eigen::Map<const Matrix>(p, out, in);
    p += size_t(out) * in;
    if (out >= in) weights_t_[l] = weights_[l].transpose();
    biases_[l] = Eigen::Map<const Eigen::Matrix<float, 1, Eigen::Dynamic>>(p, out);
    p += out;
  }
}

// Rows are evaluated one at a time (matrix-vector products) rather than as one matrix product:
// Eigen's GEMM blocks by batch shape, so a row's result would change in its last bits with the
// batch size and the row's position in it, and a rollout would depend on how envs are split
// over threads. Per-row products are bit-identical wherever the row sits, and at policy sizes
// (tens of rows, 64-256 units) cost about the same or less. Which form a layer uses depends on
// its shape only, so that property holds.
void EigenMlp::forward(const float* in, int rows, float* out) {
  const size_t layers = weights_.size();
  const int in_dim = layout_.sizes.front();
  for (size_t l = 0; l + 1 < layers; ++l) reserve_rows(acts_[l], rows, layout_.sizes[l + 1]);
  using RowVec = Eigen::Matrix<float, 1, Eigen::Dynamic>;
  for (int r = 0; r < rows; ++r) {
    Eigen::Map<const RowVec> x0(in + size_t(r) * in_dim, in_dim);
    for (size_t l = 0; l < layers; ++l) {
      const int out_dim = layout_.sizes[l + 1];
      const bool last = l + 1 == layers;
      Eigen::Map<RowVec> y(last ? out + size_t(r) * out_dim : acts_[l].row(r).data(), out_dim);
      const bool by_columns = weights_t_[l].size() > 0;
      if (l == 0) {
        if (by_columns) {
          y.noalias() = x0 * weights_t_[l];
        } else {
          y.noalias() = x0 * weights_[l].transpose();
        }
      } else {
        const auto x = acts_[l - 1].row(r).head(layout_.sizes[l]);
        if (by_columns) {
          y.noalias() = x * weights_t_[l];
        } else {
          y.noalias() = x * weights_[l].transpose();
        }
      }
      y += biases_[l];
      if (last) break;
      if (layout_.activation == Activation::kRelu) {
        y = y.cwiseMax(0.f);
      } else {
        y = y.array().tanh().matrix();
      }
    }
  }
}

Policy::Policy(const PolicyParams& p) : p_(p) {
  if (p.head != PolicyHead::kSquashedGaussian && p.head != PolicyHead::kDiscreteQ && p.head != PolicyHead::kGaussian) {
    throw std::invalid_argument("policy head: unknown head " + std::to_string(int(p.head)));
  }
  if (p.layout.sizes.size() < 2) {
    throw std::invalid_argument("policy layout '" + p.layout.describe() +
                                "': needs at least an input and an output size");
  }
  for (size_t i = 0; i < p.layout.sizes.size(); ++i) {
    if (p.layout.sizes[i] <= 0) {
      throw std::invalid_argument("policy layout '" + p.layout.describe() + "': size " + std::to_string(i) + " is " +
                                  std::to_string(p.layout.sizes[i]) + ", must be > 0");
    }
  }
  const int out = p.layout.sizes.back();
  if (p.head == PolicyHead::kDiscreteQ && !(p.epsilon >= 0.f && p.epsilon <= 1.f)) {
    throw std::invalid_argument("policy: epsilon " + std::to_string(p.epsilon) + " is not a probability in [0, 1]");
  }
  if (p.head == PolicyHead::kSquashedGaussian && out % 2 != 0) {
    throw std::invalid_argument("policy layout " + p.layout.describe() +
                                ": squashed-gaussian output must be [mean | log_std], an even "
                                "size, got " +
                                std::to_string(out));
  }
  if (p.head == PolicyHead::kGaussian && p.log_std.size() != size_t(out)) {
    throw std::invalid_argument("policy layout " + p.layout.describe() + ": gaussian head needs " +
                                std::to_string(out) + " log_std values, got " + std::to_string(p.log_std.size()));
  }
  if (p.params.size() != p.layout.num_params()) {
    throw std::invalid_argument("policy params: expected " + std::to_string(p.layout.num_params()) +
                                " floats for layout " + p.layout.describe() + ", got " +
                                std::to_string(p.params.size()));
  }
  const size_t obs_dim = size_t(p.layout.sizes.front());
  if (!p.obs_mean.empty() || !p.obs_std.empty()) {
    if (p.obs_mean.size() != obs_dim || p.obs_std.size() != obs_dim) {
      throw std::invalid_argument("policy normalizer: obs_mean has " + std::to_string(p.obs_mean.size()) +
                                  " and obs_std " + std::to_string(p.obs_std.size()) + " floats, expected both " +
                                  std::to_string(obs_dim) + " (the layout's input) or both empty");
    }
    for (size_t i = 0; i < obs_dim; ++i) {
      if (!(p.obs_std[i] > 0.f) || !std::isfinite(p.obs_std[i])) {
        throw std::invalid_argument("policy normalizer: obs_std[" + std::to_string(i) +
                                    "] = " + std::to_string(p.obs_std[i]) + ", must be finite and > 0");
      }
    }
  }
  if (!(p.log_std_min <= p.log_std_max)) {
    throw std::invalid_argument("policy: log_std_min " + std::to_string(p.log_std_min) + " > log_std_max " +
                                std::to_string(p.log_std_max));
  }
  net_ = EigenMlp(p.layout, p.params);
}

int Policy::obs_dim() const { return p_.layout.sizes.empty() ? 0 : p_.layout.sizes.front(); }
int Policy::num_actions() const {
  return p_.head == PolicyHead::kDiscreteQ && !p_.layout.sizes.empty() ? p_.layout.sizes.back() : 0;
}

int Policy::act_dim() const {
  if (p_.head == PolicyHead::kDiscreteQ) return 1;  // the action index
  if (p_.head == PolicyHead::kGaussian) return p_.layout.sizes.empty() ? 0 : p_.layout.sizes.back();
  return p_.layout.sizes.empty() ? 0 : p_.layout.sizes.back() / 2;
}

void Policy::act(const float* obs, int rows, std::mt19937_64& rng, bool deterministic, float* actions,
                 float* log_prob) {
  act_rows(obs, rows, &rng, 0, deterministic, actions, log_prob);
}

void Policy::act_per_row(const float* obs, int rows, std::mt19937_64* row_rngs, bool deterministic, float* actions,
                         float* log_prob) {
  act_rows(obs, rows, row_rngs, 1, deterministic, actions, log_prob);
}

void Policy::act_rows(const float* obs, int rows, std::mt19937_64* rngs, size_t rng_stride, bool deterministic,
                      float* actions, float* log_prob) {
  if (rows <= 0) return;
  const int od = obs_dim(), ad = act_dim();
  const float* x = obs;
  if (!p_.obs_mean.empty()) {
    const size_t n = size_t(rows) * od;
    if (normed_.size() < n) normed_.resize(n);
    for (int r = 0; r < rows; ++r) {
      for (int i = 0; i < od; ++i) {
        const size_t k = size_t(r) * od + i;
        normed_[k] = (obs[k] - p_.obs_mean[i]) / p_.obs_std[i];
      }
    }
    x = normed_.data();
  }
  const size_t n_out = size_t(rows) * p_.layout.sizes.back();
  if (out_.size() < n_out) out_.resize(n_out);
  net_.forward(x, rows, out_.data());
  if (p_.head == PolicyHead::kDiscreteQ) {
    act_discrete(rows, rngs, rng_stride, deterministic, actions, log_prob);
    return;
  }
  if (p_.head == PolicyHead::kGaussian) {
    act_gaussian(rows, rngs, rng_stride, deterministic, actions, log_prob);
    return;
  }

  for (int r = 0; r < rows; ++r) {
    const float* mean = out_.data() + size_t(r) * 2 * ad;
    const float* log_std_raw = mean + ad;
    float* a = actions + size_t(r) * ad;
    if (deterministic) {
      for (int i = 0; i < ad; ++i) a[i] = std::tanh(mean[i]);
      if (log_prob) log_prob[r] = 0.f;
      continue;
    }
    std::mt19937_64& rng = rngs[r * rng_stride];
    // A fresh distribution per row: libstdc++'s normal caches its second draw, and a row's
    // noise must come from that row's generator only.
    std::normal_distribution<float> normal(0.f, 1.f);
    float lp = 0.f;
    for (int i = 0; i < ad; ++i) {
      const float log_std = std::clamp(log_std_raw[i], p_.log_std_min, p_.log_std_max);
      const float eps = normal(rng);
      const float u = mean[i] + std::exp(log_std) * eps;
      const float t = std::tanh(u);
      a[i] = t;
      lp += -0.5f * eps * eps - log_std - kHalfLog2Pi - std::log(1.f - t * t + kTanhLogEps);
    }
    if (log_prob) log_prob[r] = lp;
  }
}

double gaussian_log_cdf(double z) {
  // Below -20 erfc underflows in double precision; the asymptotic series' first term is exact
  // there to better than 0.3 %.
  if (z > -20.0) return std::log(0.5 * std::erfc(-z / std::sqrt(2.0)));
  return -0.5 * z * z - std::log(-z) - 0.91893853320467274178;
}

void Policy::act_gaussian(int rows, std::mt19937_64* rngs, size_t rng_stride, bool deterministic, float* actions,
                          float* log_prob) {
  const int ad = act_dim();
  for (int r = 0; r < rows; ++r) {
    const float* mean = out_.data() + size_t(r) * ad;
    float* a = actions + size_t(r) * ad;
    if (deterministic) {
      for (int i = 0; i < ad; ++i) a[i] = std::clamp(mean[i], -1.f, 1.f);
      if (log_prob) log_prob[r] = 0.f;
      continue;
    }
    std::mt19937_64& rng = rngs[r * rng_stride];
    std::normal_distribution<float> normal(0.f, 1.f);
    float lp = 0.f;
    for (int i = 0; i < ad; ++i) {
      const float log_std = std::clamp(p_.log_std[i], p_.log_std_min, p_.log_std_max);
      const float std = std::exp(log_std);
      const float eps = normal(rng);
      const float u = mean[i] + std * eps;
      // The env takes actions in [-1, 1]: a sample beyond a bound runs as the bound, and its
      // probability is the Gaussian mass beyond it (clipped action policy gradient, Fujita and
      // Maeda 2018), so the learner's ratios stay finite when the mean leaves [-1, 1].
      if (u >= 1.f) {
        a[i] = 1.f;
        lp += float(gaussian_log_cdf((double(mean[i]) - 1.0) / std));
      } else if (u <= -1.f) {
        a[i] = -1.f;
        lp += float(gaussian_log_cdf((-1.0 - double(mean[i])) / std));
      } else {
        a[i] = u;
        lp += -0.5f * eps * eps - log_std - kHalfLog2Pi;
      }
    }
    if (log_prob) log_prob[r] = lp;
  }
}

void Policy::act_discrete(int rows, std::mt19937_64* rngs, size_t rng_stride, bool deterministic, float* actions,
                          float* log_prob) {
  const int n = p_.layout.sizes.back();
  const float eps = deterministic ? 0.f : p_.epsilon;
  for (int r = 0; r < rows; ++r) {
    const float* q = out_.data() + size_t(r) * n;
    const int greedy = int(std::max_element(q, q + n) - q);
    int a = greedy;
    if (eps > 0.f) {
      std::mt19937_64& rng = rngs[r * rng_stride];
      if (std::uniform_real_distribution<float>(0.f, 1.f)(rng) < eps) {
        a = std::uniform_int_distribution<int>(0, n - 1)(rng);
      }
    }
    actions[r] = float(a);
    // The behaviour probability of the chosen index under epsilon-greedy.
    if (log_prob) log_prob[r] = std::log(eps / n + (a == greedy ? 1.f - eps : 0.f));
  }
}

}  // namespace farm
