// The policy network's dense-layer kernel (EigenMlp::forward's arithmetic): a layer's weights in
// panels of output columns, a block of rows per pass over each panel. Compiled twice, for
// baseline x86-64 and with AVX2 + FMA; the caller picks the path (MlpIsa) at construction.
#pragma once

#include <cstddef>
#include <vector>

#include "mlp.h"

namespace farm::mlp_kernel {

// Output columns per weight panel on a path (kBaseline or kAvx2Fma): two vectors' width.
int panel_width(MlpIsa isa);

// Whether this CPU (and its OS) runs AVX2 and FMA instructions.
bool cpu_has_avx2_fma();

// Packs one layer, w [out x in] row-major and b [out], for the kernel of `isa`: the output width
// rounded up to panel_width(isa) (the returned width); panel p holds w[p * P + c][k] at
// (p * in + k) * P + c, zero past the layer's outputs; bias zero-padded likewise.
int pack_layer(MlpIsa isa, const float* w, const float* b, int in, int out, std::vector<float>* panels,
               std::vector<float>* bias);

// y[r][c] = f(bias[c] + x[r][0] * W[c][0] + x[r][1] * W[c][1] + ... + x[r][in-1] * W[c][in-1]) for
// r < rows and c < width (a packed layer's padded width), summed in that order, one running float
// sum, in every kernel variant, so row r's result does not depend on `rows` or the other rows.
// f is the activation when `activate`, else the identity. Strides are in floats.
void dense(MlpIsa isa, Activation activation, bool activate, int in, int width, const float* panels, const float* bias,
           const float* x, size_t x_stride, int rows, float* y, size_t y_stride);

}  // namespace farm::mlp_kernel
