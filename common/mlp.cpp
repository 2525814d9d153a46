#include "mlp.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <stdexcept>

#include "mlp_kernel.h"

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
    case Activation::kElu:
      return "elu";
  }
  return "unknown-activation";
}

// The path a network asked for runs on: kAuto by FARM_MLP_ISA, then the CPU.
MlpIsa resolve_isa(MlpIsa asked) {
  if (asked == MlpIsa::kAuto) {
    const char* env = std::getenv("FARM_MLP_ISA");
    const std::string v = env ? env : "";
    if (v.empty() || v == "auto") return mlp_kernel::cpu_has_avx2_fma() ? MlpIsa::kAvx2Fma : MlpIsa::kBaseline;
    if (v == "baseline") return MlpIsa::kBaseline;
    if (v != "avx2" && v != "avx2+fma") {
      throw std::invalid_argument("FARM_MLP_ISA is '" + v + "': expected baseline, avx2 or auto");
    }
    asked = MlpIsa::kAvx2Fma;
  }
  if (asked != MlpIsa::kBaseline && asked != MlpIsa::kAvx2Fma) {
    throw std::invalid_argument("mlp: unknown kernel path " + std::to_string(int(asked)));
  }
  if (!mlp_isa_supported(asked)) {
    throw std::invalid_argument(std::string("mlp: the ") + mlp_isa_name(asked) +
                                " kernel path needs a CPU with AVX2 and FMA, and this one lacks them "
                                "(FARM_MLP_ISA=baseline or auto runs the baseline path)");
  }
  return asked;
}

}  // namespace

bool activation_known(int32_t wire) {
  return wire == int32_t(Activation::kRelu) || wire == int32_t(Activation::kTanh) || wire == int32_t(Activation::kElu);
}

Activation activation_from_name(const std::string& name) {
  for (const Activation a : {Activation::kRelu, Activation::kTanh, Activation::kElu})
    if (name == activation_name(a)) return a;
  throw std::invalid_argument("activation must be \"tanh\", \"relu\" or \"elu\", got \"" + name + "\"");
}

const char* mlp_isa_name(MlpIsa isa) {
  switch (isa) {
    case MlpIsa::kAuto:
      return "auto";
    case MlpIsa::kBaseline:
      return "baseline";
    case MlpIsa::kAvx2Fma:
      return "avx2+fma";
  }
  return "unknown-isa";
}

bool mlp_isa_supported(MlpIsa isa) {
  switch (isa) {
    case MlpIsa::kAuto:
    case MlpIsa::kBaseline:
      return true;
    case MlpIsa::kAvx2Fma:
      return mlp_kernel::cpu_has_avx2_fma();
  }
  return false;
}

void MlpLayout::check() const {
  if (sizes.size() < 2)
    throw std::invalid_argument("layout '" + describe() + "': needs at least an input and an output size");
  if (sizes.size() > kMaxMlpLayers + 1)
    throw std::invalid_argument("layout of " + std::to_string(sizes.size()) + " sizes: at most " +
                                std::to_string(kMaxMlpLayers + 1) + " (" + std::to_string(kMaxMlpLayers) + " layers)");
  for (size_t i = 0; i < sizes.size(); ++i) {
    if (sizes[i] <= 0 || sizes[i] > kMaxMlpWidth)
      throw std::invalid_argument("layout '" + describe() + "': size " + std::to_string(i) + " is " +
                                  std::to_string(sizes[i]) + ", must be in 1.." + std::to_string(kMaxMlpWidth));
  }
}

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

EigenMlp::EigenMlp(const MlpLayout& layout, const std::vector<float>& params, MlpIsa isa) : layout_(layout) {
  layout.check();
  if (!activation_known(int32_t(layout.activation))) {
    throw std::invalid_argument("mlp layout: unknown activation " + std::to_string(int(layout.activation)) +
                                " (expected 0 relu, 1 tanh or 2 elu)");
  }
  if (params.size() != layout.num_params()) {
    throw std::invalid_argument("mlp params: expected " + std::to_string(layout.num_params()) + " floats for layout " +
                                layout.describe() + ", got " + std::to_string(params.size()));
  }
  isa_ = resolve_isa(isa);
  const size_t layers = layout.sizes.size() - 1;
  panels_.resize(layers);
  biases_.resize(layers);
  widths_.resize(layers);
  const float* p = params.data();
  for (size_t l = 0; l < layers; ++l) {
    const int in = layout.sizes[l], out = layout.sizes[l + 1];
    widths_[l] = mlp_kernel::pack_layer(isa_, p, p + size_t(out) * in, in, out, &panels_[l], &biases_[l]);
    p += size_t(out) * in + out;
  }
}

// Rows go through the network layer by layer, all rows of the call at once, in blocks of rows per
// pass over a layer's weights (mlp_kernel.h). Eigen's matrix product is not used: its blocking, and
// so the order in which it sums, depends on the batch's shape, so a row's result would change in
// its last bits with the batch size and its position in it, and a rollout would depend on how envs
// are split over threads. The kernel sums every output element in the same order whatever the
// block (a lone row's included), so a row's result is bit-identical wherever it sits.
void EigenMlp::forward(const float* in, int rows, float* out) {
  if (rows <= 0 || widths_.empty()) return;
  const size_t layers = widths_.size();
  // Two buffers of [rows x widest layer], each starting on a 64-byte boundary (speed only: the
  // kernel's results do not depend on alignment).
  const size_t buffer = (size_t(rows) * size_t(*std::max_element(widths_.begin(), widths_.end())) + 15) / 16 * 16;
  if (scratch_.size() < 2 * buffer + 16) scratch_.resize(2 * buffer + 16);
  float* base = scratch_.data() + (16 - (reinterpret_cast<uintptr_t>(scratch_.data()) / sizeof(float)) % 16) % 16;
  const float* x = in;
  size_t x_stride = size_t(layout_.sizes.front());
  for (size_t l = 0; l < layers; ++l) {
    float* y = base + (l % 2) * buffer;
    mlp_kernel::dense(isa_, layout_.activation, l + 1 < layers, layout_.sizes[l], widths_[l], panels_[l].data(),
                      biases_[l].data(), x, x_stride, rows, y, size_t(widths_[l]));
    x = y;
    x_stride = size_t(widths_[l]);
  }
  const int out_dim = layout_.sizes.back();
  for (int r = 0; r < rows; ++r) {
    std::memcpy(out + size_t(r) * out_dim, x + size_t(r) * x_stride, sizeof(float) * out_dim);
  }
}

Policy::Policy(const PolicyParams& p) : p_(p) {
  if (p.head != PolicyHead::kSquashedGaussian && p.head != PolicyHead::kDiscreteQ && p.head != PolicyHead::kGaussian) {
    throw std::invalid_argument("policy head: unknown head " + std::to_string(int(p.head)));
  }
  // Weights off the wire or from a file: one NaN would make every action NaN, and every batch of
  // them refused by the learner.
  for (const auto& [name, values] : {std::pair<const char*, const std::vector<float>*>{"parameters", &p.params},
                                     {"obs_mean", &p.obs_mean},
                                     {"obs_std", &p.obs_std},
                                     {"log_std", &p.log_std}}) {
    const auto bad = std::find_if(values->begin(), values->end(), [](float v) { return !std::isfinite(v); });
    if (bad != values->end())
      throw std::invalid_argument(std::string(name) + "[" + std::to_string(bad - values->begin()) + "] is " +
                                  std::to_string(*bad) + ", not a finite number");
  }
  if (!std::isfinite(p.log_std_min) || !std::isfinite(p.log_std_max) || !std::isfinite(p.epsilon))
    throw std::invalid_argument("log_std_min, log_std_max or epsilon is not a finite number");
  p.layout.check();
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
                         float* log_prob, const float* row_scale) {
  act_rows(obs, rows, row_rngs, 1, deterministic, actions, log_prob, row_scale);
}

void Policy::act_rows(const float* obs, int rows, std::mt19937_64* rngs, size_t rng_stride, bool deterministic,
                      float* actions, float* log_prob, const float* row_scale) {
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
    const float scale = row_scale ? row_scale[r] : 1.f;
    float lp = row_scale ? -float(ad) * std::log(scale) : 0.f;
    for (int i = 0; i < ad; ++i) {
      const float log_std = std::clamp(log_std_raw[i], p_.log_std_min, p_.log_std_max);
      const float eps = normal(rng);
      const float u = mean[i] + std::exp(log_std) * scale * eps;
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
