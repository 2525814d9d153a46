// The dense-layer kernel of the policy network (see mlp_kernel.h): one template, instantiated for
// two vector types. Sse is baseline x86-64 (SSE2), what the whole build targets; Avx2Fma runs in
// functions marked target("avx2,fma"), entered only after cpu_has_avx2_fma() said yes, so the
// binaries need no -march flag and still run on any x86-64.
//
// Determinism: every output element is its bias plus x[0] * w[0], x[1] * w[1], ... added in input
// order into one running float sum, by the path's multiply-add, in every kernel variant: the
// variants differ only in how many rows (R) and panels (P) they keep in registers at once, never
// in an element's operations. A row's bits thus do not depend on how many rows share the call or
// which (rollouts do not depend on how envs are split over threads). The two paths may differ
// from each other in the last bits: Avx2Fma's multiply-add is fused (rounded once), Sse's is a
// multiply then an add (rounded twice). Built with -march=x86-64-v3 (FARM_MARCH), the compiler may
// fuse Sse's multiply and add as well; it then does so for every one alike, as each product feeds
// exactly one add.
#include "mlp_kernel.h"

#include <immintrin.h>

#include <cmath>
#include <stdexcept>

// Avx2Fma's helpers take and return 256-bit vectors, and GCC warns that such an ABI differs from
// code built without AVX. They only ever run inlined into the target("avx2,fma") functions at the
// bottom of this file (flatten), or called from them, both sides built with AVX; the generic
// templates pass no vector by value.
#pragma GCC diagnostic ignored "-Wpsabi"

namespace farm::mlp_kernel {
namespace {

// Baseline x86-64: SSE2, 4 floats a vector; multiply-add is a multiply and then an add.
struct Sse {
  using V = __m128;
  static constexpr int kLanes = 4;
  // Where the tanh approximation below reaches +-1 (Eigen's constant without FMA).
  static constexpr float kTanhClamp = 7.90531110763549805f;
  static V load(const float* p) { return _mm_loadu_ps(p); }
  static void store(float* p, V v) { _mm_storeu_ps(p, v); }
  static V set1(float f) { return _mm_set1_ps(f); }
  static V madd(V a, V b, V c) { return _mm_add_ps(_mm_mul_ps(a, b), c); }
  static V mul(V a, V b) { return _mm_mul_ps(a, b); }
  static V div(V a, V b) { return _mm_div_ps(a, b); }
  static V min(V a, V b) { return _mm_min_ps(a, b); }
  static V max(V a, V b) { return _mm_max_ps(a, b); }
  // a where |v| < t, else b.
  static V select_abs_below(V v, V t, V a, V b) {
    const V m = _mm_cmplt_ps(_mm_andnot_ps(_mm_set1_ps(-0.f), v), t);
    return _mm_or_ps(_mm_and_ps(m, a), _mm_andnot_ps(m, b));
  }
};

#define FARM_AVX2_FMA __attribute__((target("avx2,fma")))
// Clang checks the vector ABI of the generic templates below when it compiles them for Avx2Fma,
// before inlining them into the target("avx2,fma") function, and refuses; a Clang build (the
// fuzzers') keeps the baseline path alone, and cpu_has_avx2_fma() says no there.
#if defined(__clang__)
#define FARM_MLP_AVX2 0
#else
#define FARM_MLP_AVX2 1
#endif

// AVX2 + FMA: 8 floats a vector; multiply-add is fused.
struct Avx2Fma {
  using V = __m256;
  static constexpr int kLanes = 8;
  // Eigen's constant with FMA.
  static constexpr float kTanhClamp = 7.99881172180175781f;
  FARM_AVX2_FMA static V load(const float* p) { return _mm256_loadu_ps(p); }
  FARM_AVX2_FMA static void store(float* p, V v) { _mm256_storeu_ps(p, v); }
  FARM_AVX2_FMA static V set1(float f) { return _mm256_set1_ps(f); }
  FARM_AVX2_FMA static V madd(V a, V b, V c) { return _mm256_fmadd_ps(a, b, c); }
  FARM_AVX2_FMA static V mul(V a, V b) { return _mm256_mul_ps(a, b); }
  FARM_AVX2_FMA static V div(V a, V b) { return _mm256_div_ps(a, b); }
  FARM_AVX2_FMA static V min(V a, V b) { return _mm256_min_ps(a, b); }
  FARM_AVX2_FMA static V max(V a, V b) { return _mm256_max_ps(a, b); }
  FARM_AVX2_FMA static V select_abs_below(V v, V t, V a, V b) {
    const V m = _mm256_cmp_ps(_mm256_andnot_ps(_mm256_set1_ps(-0.f), v), t, _CMP_LT_OQ);
    return _mm256_blendv_ps(b, a, m);
  }
};

// tanh as Eigen computes it for floats (generic_fast_tanh_float): a 13/6 rational function of
// the input clamped to where it reaches +-1, the input itself below 4e-4 in magnitude; a few
// float ulps from the true value. In place, one vector at y.
template <class O>
void tanh_rational_at(float* y) {
  using V = typename O::V;
  const V v = O::load(y);
  const V x = O::max(O::min(v, O::set1(O::kTanhClamp)), O::set1(-O::kTanhClamp));
  const V x2 = O::mul(x, x);
  V p = O::madd(x2, O::set1(-2.76076847742355e-16f), O::set1(2.00018790482477e-13f));
  p = O::madd(x2, p, O::set1(-8.60467152213735e-11f));
  p = O::madd(x2, p, O::set1(5.12229709037114e-08f));
  p = O::madd(x2, p, O::set1(1.48572235717979e-05f));
  p = O::madd(x2, p, O::set1(6.37261928875436e-04f));
  p = O::madd(x2, p, O::set1(4.89352455891786e-03f));
  p = O::mul(x, p);
  V q = O::madd(x2, O::set1(1.19825839466702e-06f), O::set1(1.18534705686654e-04f));
  q = O::madd(x2, q, O::set1(2.26843463243900e-03f));
  q = O::madd(x2, q, O::set1(4.89352518554385e-03f));
  O::store(y, O::select_abs_below(v, O::set1(0.0004f), x, O::div(p, q)));
}

// ELU with alpha 1, as torch::elu: x where x > 0, else exp(x) - 1, computed as std::expm1(x) (no
// cancellation near 0). One lane at a time through the C library's expm1f, the same scalar function
// for every element on either path and in every kernel variant, so a row's bits still do not
// depend on the batch; both paths give the same ELU of the same sum. In place, one vector at y.
template <class O>
void elu_at(float* y) {
  for (int i = 0; i < O::kLanes; ++i) y[i] = y[i] > 0.f ? y[i] : std::expm1(y[i]);
}

// The hidden layers' activation, in place on one vector at y: the one place a new Activation
// needs code (besides its name and checks in mlp.h and mlp.cpp).
template <class O>
void activate_at(Activation a, float* y) {
  switch (a) {
    case Activation::kRelu:
      O::store(y, O::max(O::load(y), O::set1(0.f)));
      return;
    case Activation::kTanh:
      tanh_rational_at<O>(y);
      return;
    case Activation::kElu:
      elu_at<O>(y);
      return;
  }
}

// R rows x P panels of one layer (each panel 2 vectors wide, panel_floats apart in w), their
// sums in registers while the weights pass once: y[r][c] = b[c] + sum over k, in order, of
// x[r][k] * w[k][c].
template <class O, int R, int P>
inline void block(const float* x, size_t x_stride, int in, const float* w, size_t panel_floats, const float* b,
                  float* y, size_t y_stride) {
  using V = typename O::V;
  constexpr int L = O::kLanes;
  V acc[R][P][2];
#pragma GCC unroll 4
  for (int p = 0; p < P; ++p) {
    const V b0 = O::load(b + p * 2 * L), b1 = O::load(b + p * 2 * L + L);
#pragma GCC unroll 4
    for (int r = 0; r < R; ++r) {
      acc[r][p][0] = b0;
      acc[r][p][1] = b1;
    }
  }
  for (int k = 0; k < in; ++k) {
    V w0[P], w1[P];
#pragma GCC unroll 4
    for (int p = 0; p < P; ++p) {
      const float* wk = w + p * panel_floats + size_t(k) * 2 * L;
      w0[p] = O::load(wk);
      w1[p] = O::load(wk + L);
    }
#pragma GCC unroll 4
    for (int r = 0; r < R; ++r) {
      const V xr = O::set1(x[r * x_stride + k]);
#pragma GCC unroll 4
      for (int p = 0; p < P; ++p) {
        acc[r][p][0] = O::madd(xr, w0[p], acc[r][p][0]);
        acc[r][p][1] = O::madd(xr, w1[p], acc[r][p][1]);
      }
    }
  }
#pragma GCC unroll 4
  for (int r = 0; r < R; ++r) {
#pragma GCC unroll 4
    for (int p = 0; p < P; ++p) {
      O::store(y + r * y_stride + p * 2 * L, acc[r][p][0]);
      O::store(y + r * y_stride + p * 2 * L + L, acc[r][p][1]);
    }
  }
}

// R rows over all panels, P at a time, the last ones one by one.
template <class O, int R, int P>
inline void rows_by_panel_groups(const float* x, size_t x_stride, int in, int panels, const float* w, const float* b,
                                 float* y, size_t y_stride) {
  constexpr int kPanel = 2 * O::kLanes;
  const size_t panel_floats = size_t(in) * kPanel;
  int p = 0;
  for (; p + P <= panels; p += P) {
    block<O, R, P>(x, x_stride, in, w + p * panel_floats, panel_floats, b + p * kPanel, y + p * kPanel, y_stride);
  }
  for (; p < panels; ++p) {
    block<O, R, 1>(x, x_stride, in, w + p * panel_floats, panel_floats, b + p * kPanel, y + p * kPanel, y_stride);
  }
}

template <class O>
inline void dense_layer(Activation activation, bool activate_out, int in, int width, const float* w, const float* b,
                        const float* x, size_t x_stride, int rows, float* y, size_t y_stride) {
  constexpr int kPanel = 2 * O::kLanes;
  const int panels = width / kPanel;
  const size_t panel_floats = size_t(in) * kPanel;
  // Blocks of 4 rows (8 sums in flight), panel by panel: a panel stays in cache while every
  // block of the call passes it.
  const int full = rows / 4 * 4;
  for (int p = 0; p < panels; ++p) {
    for (int r0 = 0; r0 < full; r0 += 4) {
      block<O, 4, 1>(x + r0 * x_stride, x_stride, in, w + p * panel_floats, panel_floats, b + p * kPanel,
                     y + r0 * y_stride + p * kPanel, y_stride);
    }
  }
  // The last 1-3 rows (a lone row's call among them) take more panels at once instead, so that as
  // many sums are in flight; an element's sum is the same either way.
  const float* xr = x + full * x_stride;
  float* yr = y + full * y_stride;
  switch (rows - full) {
    case 1:
      rows_by_panel_groups<O, 1, 4>(xr, x_stride, in, panels, w, b, yr, y_stride);
      break;
    case 2:
      rows_by_panel_groups<O, 2, 2>(xr, x_stride, in, panels, w, b, yr, y_stride);
      break;
    case 3:
      rows_by_panel_groups<O, 3, 1>(xr, x_stride, in, panels, w, b, yr, y_stride);
      break;
    default:
      break;
  }
  if (!activate_out) return;
  for (int r = 0; r < rows; ++r) {
    float* yrow = y + r * y_stride;
    for (int c = 0; c < width; c += O::kLanes) activate_at<O>(activation, yrow + c);
  }
}

// The two compiled forms. flatten inlines the whole kernel into each, so the template above is
// built once per instruction set; the AVX2 one is entered only where the CPU has AVX2 and FMA.
__attribute__((flatten)) void dense_sse(Activation activation, bool activate_out, int in, int width, const float* w,
                                        const float* b, const float* x, size_t x_stride, int rows, float* y,
                                        size_t y_stride) {
  dense_layer<Sse>(activation, activate_out, in, width, w, b, x, x_stride, rows, y, y_stride);
}

#if FARM_MLP_AVX2
FARM_AVX2_FMA __attribute__((flatten)) void dense_avx2_fma(Activation activation, bool activate_out, int in, int width,
                                                           const float* w, const float* b, const float* x,
                                                           size_t x_stride, int rows, float* y, size_t y_stride) {
  dense_layer<Avx2Fma>(activation, activate_out, in, width, w, b, x, x_stride, rows, y, y_stride);
}
#endif

}  // namespace

int panel_width(MlpIsa isa) { return isa == MlpIsa::kAvx2Fma ? 2 * Avx2Fma::kLanes : 2 * Sse::kLanes; }

bool cpu_has_avx2_fma() {
  // GCC's and Clang's CPU tests also check that the OS saves the AVX registers (XGETBV).
  __builtin_cpu_init();
  return FARM_MLP_AVX2 && __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}

int pack_layer(MlpIsa isa, const float* w, const float* b, int in, int out, std::vector<float>* panels,
               std::vector<float>* bias) {
  const int kPanel = panel_width(isa);
  const int width = (out + kPanel - 1) / kPanel * kPanel;
  panels->assign(size_t(width) * in, 0.f);
  bias->assign(size_t(width), 0.f);
  for (int j = 0; j < out; ++j) {
    const int p = j / kPanel, c = j % kPanel;
    for (int k = 0; k < in; ++k) (*panels)[(size_t(p) * in + k) * kPanel + c] = w[size_t(j) * in + k];
    (*bias)[j] = b[j];
  }
  return width;
}

void dense(MlpIsa isa, Activation activation, bool activate, int in, int width, const float* panels, const float* bias,
           const float* x, size_t x_stride, int rows, float* y, size_t y_stride) {
  if (isa == MlpIsa::kAvx2Fma) {
#if FARM_MLP_AVX2
    dense_avx2_fma(activation, activate, in, width, panels, bias, x, x_stride, rows, y, y_stride);
#else
    throw std::logic_error("mlp kernel: the avx2 path is not in this build");
#endif
  } else {
    dense_sse(activation, activate, in, width, panels, bias, x, x_stride, rows, y, y_stride);
  }
}

}  // namespace farm::mlp_kernel
