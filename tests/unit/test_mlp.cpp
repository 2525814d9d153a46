#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "mlp.h"

namespace farm {
namespace {

// 2-2-1: W1 = [[1, -2], [0.5, 1]], b1 = [0.1, -0.3], W2 = [[2, -1]], b2 = [0.5].
std::vector<float> tiny_params() { return {1.f, -2.f, 0.5f, 1.f, 0.1f, -0.3f, 2.f, -1.f, 0.5f}; }

// The hidden activation in float: ELU with alpha 1 as torch::elu computes it (expm1 below 0).
float activate(float v, Activation act) {
  switch (act) {
    case Activation::kRelu:
      return std::max(v, 0.f);
    case Activation::kTanh:
      return std::tanh(v);
    case Activation::kElu:
      return v > 0.f ? v : std::expm1(v);
  }
  return NAN;
}

float tiny_by_hand(float x0, float x1, Activation act) {
  auto f = [act](float v) { return activate(v, act); };
  const float h0 = f(1.f * x0 - 2.f * x1 + 0.1f);
  const float h1 = f(0.5f * x0 + 1.f * x1 - 0.3f);
  return 2.f * h0 - 1.f * h1 + 0.5f;
}

TEST(MlpLayout, CountsAndDescribes) {
  MlpLayout l{{3, 64, 64, 2}, Activation::kRelu};
  EXPECT_EQ(l.num_params(), size_t(3 * 64 + 64 + 64 * 64 + 64 + 64 * 2 + 2));
  EXPECT_EQ(l.describe(), "3-64-64-2 relu");
  EXPECT_EQ((MlpLayout{{2, 2, 1}, Activation::kTanh}).describe(), "2-2-1 tanh");
  EXPECT_EQ((MlpLayout{{2, 2, 1}, Activation::kElu}).describe(), "2-2-1 elu");
}

TEST(EigenMlp, TinyNetMatchesHandComputation) {
  for (Activation act : {Activation::kRelu, Activation::kTanh, Activation::kElu}) {
    EigenMlp net(MlpLayout{{2, 2, 1}, act}, tiny_params());
    // The second row drives the first hidden unit negative, where relu, tanh and elu differ.
    const std::vector<float> in = {1.f, 0.5f, -1.f, 1.f, 0.3f, -0.7f};
    std::vector<float> out(3, -99.f);
    net.forward(in.data(), 3, out.data());
    for (int r = 0; r < 3; ++r) {
      EXPECT_NEAR(out[r], tiny_by_hand(in[2 * r], in[2 * r + 1], act), 1e-6)
          << "row " << r << " activation " << int(act);
    }
  }
  // Exact values for relu: row 2 gives hidden [0, 0.2], output 0.3.
  EigenMlp net(MlpLayout{{2, 2, 1}, Activation::kRelu}, tiny_params());
  const float in[2] = {-1.f, 1.f};
  float out = 0.f;
  net.forward(in, 1, &out);
  EXPECT_NEAR(out, 0.3f, 1e-6);
}

TEST(EigenMlp, WrongParamCountThrowsWithMessage) {
  std::vector<float> p = tiny_params();
  p.pop_back();
  try {
    EigenMlp net(MlpLayout{{2, 2, 1}, Activation::kRelu}, p);
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("expected 9"), std::string::npos) << msg;
    EXPECT_NE(msg.find("got 8"), std::string::npos) << msg;
    EXPECT_NE(msg.find("2-2-1 relu"), std::string::npos) << msg;
  }
  PolicyParams pp;
  pp.layout = {{3, 64, 64, 2}, Activation::kRelu};
  pp.params.assign(12, 0.f);
  try {
    Policy policy(pp);
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_STREQ(e.what(), "policy params: expected 4546 floats for layout 3-64-64-2 relu, got 12");
  }
}

TEST(EigenMlp, UnknownActivationIsRefused) {
  try {
    EigenMlp net(MlpLayout{{2, 2, 1}, static_cast<Activation>(3)}, tiny_params());
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_STREQ(e.what(), "mlp layout: unknown activation 3 (expected 0 relu, 1 tanh or 2 elu)");
  }
}

// ELU is x above 0 and expm1(x) at or below it, to the bit, on every kernel path: a 1-1-1 network
// with unit weights and zero biases passes its input through unchanged to the hidden unit and out
// again. exp(x) - 1 would lose most digits near 0 (-1e-6 gives -9.537e-07 in floats); far below 0
// ELU is -1.
TEST(EigenMlp, EluIsExpm1BelowZeroToTheBit) {
  const std::vector<float> xs = {-1e-6f, -3e-4f, -0.1f, -0.5f, -1.f, -2.5f, -20.f, -100.f, 0.f, 1e-7f, 0.3f, 2.f, 37.f};
  for (MlpIsa isa : {MlpIsa::kBaseline, MlpIsa::kAvx2Fma}) {
    if (!mlp_isa_supported(isa)) continue;
    SCOPED_TRACE(mlp_isa_name(isa));
    EigenMlp net(MlpLayout{{1, 1, 1}, Activation::kElu}, {1.f, 0.f, 1.f, 0.f}, isa);
    std::vector<float> out(xs.size());
    net.forward(xs.data(), int(xs.size()), out.data());
    for (size_t i = 0; i < xs.size(); ++i) {
      const float want = xs[i] > 0.f ? xs[i] : std::expm1(xs[i]);
      EXPECT_EQ(out[i], want) << "x = " << xs[i];
    }
    EXPECT_NEAR(out[0], -1e-6, 1e-12);  // -9.999995e-07
    EXPECT_EQ(out[7], -1.f);
  }
}

TEST(EigenMlp, RowResultsDoNotDependOnBatch) {
  std::mt19937 g(3);
  std::normal_distribution<float> n;
  MlpLayout layout{{5, 37, 64, 6}, Activation::kTanh};
  std::vector<float> params(layout.num_params());
  for (auto& v : params) v = 0.3f * n(g);
  EigenMlp net(layout, params);
  const int rows = 13;
  std::vector<float> in(rows * 5), all(rows * 6), one(6);
  for (auto& v : in) v = n(g);
  net.forward(in.data(), rows, all.data());
  for (int r = 0; r < rows; ++r) {
    net.forward(in.data() + r * 5, 1, one.data());
    for (int j = 0; j < 6; ++j) ASSERT_EQ(one[j], all[r * 6 + j]) << "row " << r;
  }
}

// The network in double precision, straight from the flat parameters (torch's layout).
std::vector<double> reference_forward(const MlpLayout& layout, const std::vector<float>& params, const float* in) {
  std::vector<double> x(in, in + layout.sizes.front());
  const float* p = params.data();
  for (size_t l = 0; l + 1 < layout.sizes.size(); ++l) {
    const int n_in = layout.sizes[l], n_out = layout.sizes[l + 1];
    const float* w = p;
    const float* b = p + size_t(n_out) * n_in;
    std::vector<double> y(n_out);
    for (int j = 0; j < n_out; ++j) {
      double s = b[j];
      for (int k = 0; k < n_in; ++k) s += double(w[size_t(j) * n_in + k]) * x[k];
      const bool hidden = l + 2 < layout.sizes.size();
      if (!hidden) {
        y[j] = s;
      } else if (layout.activation == Activation::kRelu) {
        y[j] = std::max(s, 0.0);
      } else if (layout.activation == Activation::kTanh) {
        y[j] = std::tanh(s);
      } else {
        y[j] = s > 0 ? s : std::expm1(s);  // ELU, alpha 1
      }
    }
    p = b + n_out;
    x = std::move(y);
  }
  return x;
}

// The kernel paths this CPU runs: the baseline one always, the AVX2 + FMA one where the CPU has it.
std::vector<MlpIsa> runnable_paths() {
  std::vector<MlpIsa> paths = {MlpIsa::kBaseline};
  if (mlp_isa_supported(MlpIsa::kAvx2Fma)) paths.push_back(MlpIsa::kAvx2Fma);
  return paths;
}

// Rows go through the network in blocks; a row's bits must not depend on how many rows share the
// call or where it sits in it (37 rows: full blocks and 1 left over; 10 + 27: 2 and 3 left over;
// one row alone), and must match a double-precision evaluation, on every kernel path this CPU
// runs. The A1 actor's shape (tanh, and ELU as legged_gym's), a relu one, and widths that are not a
// multiple of any vector or panel width, with each activation.
TEST(EigenMlp, BlockedRowsAreBitIdenticalAndAccurate) {
  const std::vector<MlpLayout> layouts = {{{48, 512, 256, 128, 12}, Activation::kTanh},
                                          {{48, 512, 256, 128, 12}, Activation::kElu},
                                          {{48, 64, 64, 24}, Activation::kRelu},
                                          {{7, 37, 19, 5}, Activation::kRelu},
                                          {{7, 37, 19, 5}, Activation::kElu},
                                          {{3, 9, 1}, Activation::kTanh},
                                          {{3, 9, 1}, Activation::kElu}};
  std::mt19937 g(17);
  std::normal_distribution<float> n;
  for (const MlpLayout& layout : layouts) {
    // Weights scaled by 1 / sqrt(fan-in), as the learners' initialization does, so the hidden
    // units are neither all saturated nor all near zero.
    std::vector<float> params;
    for (size_t l = 0; l + 1 < layout.sizes.size(); ++l) {
      const float scale = 1.5f / std::sqrt(float(layout.sizes[l]));
      for (int i = 0; i < layout.sizes[l + 1] * (layout.sizes[l] + 1); ++i) params.push_back(scale * n(g));
    }
    ASSERT_EQ(params.size(), layout.num_params());
    const int rows = 37, in_dim = layout.sizes.front(), out_dim = layout.sizes.back();
    std::vector<float> in(size_t(rows) * in_dim);
    for (auto& v : in) v = n(g);
    for (MlpIsa isa : runnable_paths()) {
      SCOPED_TRACE(layout.describe() + " on the " + mlp_isa_name(isa) + " path");
      EigenMlp net(layout, params, isa);
      ASSERT_EQ(net.isa(), isa);
      const size_t out_bytes = sizeof(float) * out_dim;
      std::vector<float> all(size_t(rows) * out_dim), split(all.size()), one(out_dim);
      net.forward(in.data(), rows, all.data());
      net.forward(in.data(), 10, split.data());
      net.forward(in.data() + 10 * in_dim, rows - 10, split.data() + 10 * out_dim);
      EXPECT_EQ(std::memcmp(all.data(), split.data(), all.size() * sizeof(float)), 0) << "rows 0..9 + 10..36";
      double worst = 0;
      for (int r = 0; r < rows; ++r) {
        net.forward(in.data() + r * in_dim, 1, one.data());
        EXPECT_EQ(std::memcmp(one.data(), all.data() + r * out_dim, out_bytes), 0) << "row " << r << " alone";
        const std::vector<double> ref = reference_forward(layout, params, in.data() + r * in_dim);
        for (int j = 0; j < out_dim; ++j) {
          const double err = std::abs(double(all[r * out_dim + j]) - ref[j]) / std::max(std::abs(ref[j]), 1.0);
          EXPECT_LE(err, 1e-5) << "row " << r << " output " << j << ": " << all[r * out_dim + j] << " vs " << ref[j];
          worst = std::max(worst, err);
        }
      }
      std::printf("%s, %s path: worst relative difference from double precision %.2e\n", layout.describe().c_str(),
                  mlp_isa_name(isa), worst);
      // After the single rows the scratch is reused, not regrown: the batch again gives the same bits.
      std::vector<float> again(all.size());
      net.forward(in.data(), rows, again.data());
      EXPECT_EQ(std::memcmp(all.data(), again.data(), all.size() * sizeof(float)), 0) << "second call";
    }
  }
}

// Sets an environment variable for one scope and restores what was there.
class ScopedEnv {
 public:
  ScopedEnv(const char* name, const char* value) : name_(name) {
    const char* old = std::getenv(name);
    had_ = old != nullptr;
    if (had_) old_ = old;
    setenv(name, value, 1);
  }
  ~ScopedEnv() {
    if (had_) {
      setenv(name_, old_.c_str(), 1);
    } else {
      unsetenv(name_);
    }
  }

 private:
  const char* name_;
  bool had_ = false;
  std::string old_;
};

// kAuto takes the AVX2 path where the CPU has it; FARM_MLP_ISA=baseline forces the baseline one,
// and a value it does not know is an error naming the variable.
TEST(EigenMlp, KernelPathFollowsCpuAndEnvironment) {
  const MlpLayout layout{{2, 2, 1}, Activation::kRelu};
  {
    ScopedEnv env("FARM_MLP_ISA", "");
    EXPECT_EQ(EigenMlp(layout, tiny_params()).isa(),
              mlp_isa_supported(MlpIsa::kAvx2Fma) ? MlpIsa::kAvx2Fma : MlpIsa::kBaseline);
  }
  {
    ScopedEnv env("FARM_MLP_ISA", "baseline");
    EXPECT_EQ(EigenMlp(layout, tiny_params()).isa(), MlpIsa::kBaseline);
    // An explicit path is not overridden by the environment.
    EXPECT_EQ(EigenMlp(layout, tiny_params(), MlpIsa::kBaseline).isa(), MlpIsa::kBaseline);
  }
  {
    ScopedEnv env("FARM_MLP_ISA", "avx512");
    try {
      EigenMlp net(layout, tiny_params());
      FAIL() << "expected std::invalid_argument";
    } catch (const std::invalid_argument& e) {
      EXPECT_STREQ(e.what(), "FARM_MLP_ISA is 'avx512': expected baseline, avx2 or auto");
    }
  }
  if (!mlp_isa_supported(MlpIsa::kAvx2Fma)) {
    EXPECT_THROW(EigenMlp(layout, tiny_params(), MlpIsa::kAvx2Fma), std::invalid_argument);
  }
}

// 2-2-2 policy (act_dim 1): hidden = relu(W1 x + b1), out = [mean, log_std].
PolicyParams small_policy(float log_std_bias) {
  PolicyParams p;
  p.version = 7;
  p.layout = {{2, 2, 2}, Activation::kRelu};
  p.params = {0.5f,  -0.25f,      0.2f,  0.4f, 0.1f, 0.0f,  // W1, b1
              0.6f,  -0.3f,       0.05f, 0.1f,              // W2
              0.05f, log_std_bias};                         // b2
  return p;
}

void mean_and_log_std(const PolicyParams& p, float x0, float x1, float* mean, float* log_std) {
  const float* w = p.params.data();
  const float h0 = std::max(0.f, w[0] * x0 + w[1] * x1 + w[4]);
  const float h1 = std::max(0.f, w[2] * x0 + w[3] * x1 + w[5]);
  *mean = w[6] * h0 + w[7] * h1 + w[10];
  *log_std = w[8] * h0 + w[9] * h1 + w[11];
}

double gaussian_tanh_log_prob(double a, double mean, double log_std) {
  const double u = std::atanh(a);
  const double z = (u - mean) / std::exp(log_std);
  return -0.5 * z * z - log_std - 0.5 * std::log(2 * M_PI) - std::log(1 - a * a + 1e-6);
}

TEST(Policy, SquashedGaussianLogProbMatchesDirectComputation) {
  const PolicyParams p = small_policy(-0.7f);
  Policy policy(p);
  EXPECT_EQ(policy.obs_dim(), 2);
  EXPECT_EQ(policy.act_dim(), 1);
  EXPECT_EQ(policy.version(), 7u);
  std::mt19937_64 rng(11);
  const int rows = 4000;
  std::vector<float> obs(rows * 2), act(rows), lp(rows);
  for (int r = 0; r < rows; ++r) {
    obs[2 * r] = 0.8f;
    obs[2 * r + 1] = -0.4f;
  }
  policy.act(obs.data(), rows, rng, false, act.data(), lp.data());
  float mean, log_std;
  mean_and_log_std(p, 0.8f, -0.4f, &mean, &log_std);
  double sum = 0, sum2 = 0;
  for (int r = 0; r < rows; ++r) {
    ASSERT_GT(act[r], -1.f);
    ASSERT_LT(act[r], 1.f);
    EXPECT_NEAR(lp[r], gaussian_tanh_log_prob(act[r], mean, log_std), 2e-3) << "row " << r;
    const double u = std::atanh(double(act[r]));
    sum += u;
    sum2 += u * u;
  }
  // The pre-tanh samples are N(mean, exp(log_std)): checks the noise is actually applied.
  const double m = sum / rows, sd = std::sqrt(sum2 / rows - m * m);
  EXPECT_NEAR(m, mean, 0.03);
  EXPECT_NEAR(sd, std::exp(log_std), 0.03);
}

TEST(Policy, LogStdIsClamped) {
  PolicyParams p = small_policy(5.f);  // log_std > log_std_max
  p.log_std_max = -1.f;
  Policy policy(p);
  std::mt19937_64 rng(5);
  const int rows = 4000;
  std::vector<float> obs(rows * 2, 0.f), act(rows), lp(rows);
  policy.act(obs.data(), rows, rng, false, act.data(), lp.data());
  float mean, log_std;
  mean_and_log_std(p, 0.f, 0.f, &mean, &log_std);
  double sum2 = 0;
  for (int r = 0; r < rows; ++r) {
    EXPECT_NEAR(lp[r], gaussian_tanh_log_prob(act[r], mean, -1.0), 2e-3);
    const double u = std::atanh(double(act[r])) - mean;
    sum2 += u * u;
  }
  EXPECT_NEAR(std::sqrt(sum2 / rows), std::exp(-1.0), 0.02);
}

TEST(Policy, DeterministicIsTanhOfMean) {
  const PolicyParams p = small_policy(0.3f);
  Policy policy(p);
  std::mt19937_64 rng(1);
  const std::vector<float> obs = {0.8f, -0.4f, -2.f, 3.f};
  float act[2], lp[2] = {9.f, 9.f};
  policy.act(obs.data(), 2, rng, true, act, lp);
  for (int r = 0; r < 2; ++r) {
    float mean, log_std;
    mean_and_log_std(p, obs[2 * r], obs[2 * r + 1], &mean, &log_std);
    EXPECT_NEAR(act[r], std::tanh(mean), 1e-6);
    EXPECT_EQ(lp[r], 0.f);
  }
}

TEST(Policy, NormalizerIsApplied) {
  PolicyParams p = small_policy(0.f);
  p.obs_mean = {1.f, -2.f};
  p.obs_std = {2.f, 0.5f};
  Policy normalized(p);
  Policy plain(small_policy(0.f));
  std::mt19937_64 rng(1);
  const float obs[2] = {3.f, -1.5f};
  const float pre_normalized[2] = {(3.f - 1.f) / 2.f, (-1.5f + 2.f) / 0.5f};
  float a = 0, b = 0;
  normalized.act(obs, 1, rng, true, &a, nullptr);
  plain.act(pre_normalized, 1, rng, true, &b, nullptr);
  EXPECT_FLOAT_EQ(a, b);
  float c = 0;
  plain.act(obs, 1, rng, true, &c, nullptr);
  EXPECT_NE(a, c);
}

TEST(Policy, PerRowNoiseDoesNotDependOnBatch) {
  Policy policy(small_policy(-0.5f));
  const int rows = 6;
  std::vector<float> obs(rows * 2);
  for (int i = 0; i < rows * 2; ++i) obs[i] = 0.1f * i - 0.5f;
  std::vector<std::mt19937_64> rngs_a, rngs_b;
  for (int r = 0; r < rows; ++r) {
    rngs_a.emplace_back(100 + r);
    rngs_b.emplace_back(100 + r);
  }
  std::vector<float> act_a(rows), lp_a(rows), act_b(rows), lp_b(rows);
  policy.act_per_row(obs.data(), rows, rngs_a.data(), false, act_a.data(), lp_a.data());
  policy.act_per_row(obs.data(), 2, rngs_b.data(), false, act_b.data(), lp_b.data());
  policy.act_per_row(obs.data() + 4, rows - 2, rngs_b.data() + 2, false, act_b.data() + 2, lp_b.data() + 2);
  for (int r = 0; r < rows; ++r) {
    EXPECT_EQ(act_a[r], act_b[r]);
    EXPECT_EQ(lp_a[r], lp_b[r]);
  }
  EXPECT_NE(act_a[0], act_a[1]);
}

// worker.exploration_scale_min/max: row r's pre-tanh noise is the policy's times row_scale[r],
// from the same draws (atanh(a) - mean doubles with a scale of 2, row by row), and its log_prob is
// the scaled Gaussian's; no scale is a scale of 1.
TEST(Policy, RowScalesMultiplyTheNoiseOfTheirRowsOnly) {
  const PolicyParams p = small_policy(-0.9f);
  Policy policy(p);
  const int rows = 3;
  const std::vector<float> obs = {0.8f, -0.4f, 0.8f, -0.4f, 0.8f, -0.4f};
  float mean, log_std;
  mean_and_log_std(p, 0.8f, -0.4f, &mean, &log_std);
  auto draw = [&](const float* scale, float* act, float* lp) {
    std::vector<std::mt19937_64> rngs{std::mt19937_64(1), std::mt19937_64(2), std::mt19937_64(3)};
    policy.act_per_row(obs.data(), rows, rngs.data(), false, act, lp, scale);
  };
  float plain[3], lp_plain[3], ones[3], lp_ones[3], scaled[3], lp_scaled[3];
  const float one[3] = {1.f, 1.f, 1.f}, scale[3] = {2.f, 1.f, 0.5f};
  draw(nullptr, plain, lp_plain);
  draw(one, ones, lp_ones);
  draw(scale, scaled, lp_scaled);
  for (int r = 0; r < rows; ++r) {
    SCOPED_TRACE("row " + std::to_string(r));
    EXPECT_EQ(plain[r], ones[r]);
    EXPECT_EQ(lp_plain[r], lp_ones[r]);
    const double noise = std::atanh(double(plain[r])) - mean;
    EXPECT_NEAR(std::atanh(double(scaled[r])) - mean, scale[r] * noise, 1e-4);
    EXPECT_NEAR(lp_scaled[r], gaussian_tanh_log_prob(scaled[r], mean, log_std + std::log(scale[r])), 2e-3);
  }
  EXPECT_NE(plain[0], scaled[0]);
}

TEST(Policy, RejectsInconsistentParams) {
  PolicyParams odd = small_policy(0.f);
  odd.layout = {{2, 2, 3}, Activation::kRelu};
  odd.params.assign(odd.layout.num_params(), 0.f);
  EXPECT_THROW(Policy{odd}, std::invalid_argument);

  PolicyParams bad_norm = small_policy(0.f);
  bad_norm.obs_mean = {0.f, 0.f, 0.f};
  bad_norm.obs_std = {1.f, 1.f, 1.f};
  EXPECT_THROW(Policy{bad_norm}, std::invalid_argument);

  PolicyParams zero_std = small_policy(0.f);
  zero_std.obs_mean = {0.f, 0.f};
  zero_std.obs_std = {1.f, 0.f};
  try {
    Policy policy(zero_std);
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("obs_std[1]"), std::string::npos) << e.what();
  }
}

// Weights with a value that is not a finite number are refused by name, whether they came off the
// wire or from a file: before, a worker ran them and every action it sent was NaN.
TEST(Policy, RejectsValuesThatAreNotFiniteNumbers) {
  const auto refused = [](PolicyParams p, const std::string& why) {
    try {
      Policy policy(p);
      ADD_FAILURE() << "accepted: " << why;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(why), std::string::npos) << e.what();
    }
  };
  PolicyParams p = small_policy(0.f);
  p.params[3] = NAN;
  refused(p, "parameters[3] is nan, not a finite number");
  p = small_policy(0.f);
  p.obs_mean = {0.f, INFINITY};
  p.obs_std = {1.f, 1.f};
  refused(p, "obs_mean[1] is inf, not a finite number");
  p = small_policy(0.f);
  p.log_std_max = NAN;
  refused(p, "log_std_min, log_std_max or epsilon is not a finite number");
  EXPECT_NO_THROW(Policy{small_policy(0.f)});
}

// A layout from the network whose parameter count wraps around 2^64 to the few floats it carries
// ([3, 2^31 - 1 x 4, 2^31 - 3, 1, 536870915, 2] counts 2^64 + 8) passed the count check before the
// bounds on sizes, and only the allocator stopped the network's packing of it (std::length_error,
// after an int overflow). Refused now, by name, before anything is counted or allocated.
TEST(Policy, LayoutsBeyondTheBoundsAreRefusedBeforeTheirCount) {
  PolicyParams wrap = small_policy(0.f);
  const int big = 2147483647;
  wrap.layout = {{3, big, big, big, big, big - 2, 1, 536870915, 2}, Activation::kRelu};
  wrap.params.assign(8, 0.f);
  for (const bool eigen : {false, true}) {
    try {
      if (eigen)
        EigenMlp net(wrap.layout, wrap.params);
      else
        Policy policy(wrap);
      FAIL() << "expected std::invalid_argument";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("size 1 is 2147483647, must be in 1..1048576"), std::string::npos)
          << e.what();
    }
  }
  PolicyParams deep = small_policy(0.f);
  deep.layout.sizes.assign(kMaxMlpLayers + 2, 2);
  deep.params.assign(deep.layout.num_params(), 0.f);
  try {
    Policy policy(deep);
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("layout of 66 sizes: at most 65 (64 layers)"), std::string::npos) << e.what();
  }
  // The widest and deepest layout allowed is counted without overflow.
  MlpLayout widest{std::vector<int>(kMaxMlpLayers + 1, kMaxMlpWidth), Activation::kRelu};
  EXPECT_NO_THROW(widest.check());
  EXPECT_EQ(widest.num_params(), kMaxMlpLayers * (size_t(kMaxMlpWidth) * kMaxMlpWidth + kMaxMlpWidth));
}

}  // namespace
}  // namespace farm
