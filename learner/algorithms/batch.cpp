#include "batch.h"

#include <algorithm>
#include <stdexcept>

namespace farm {

void fold_n_step(int64_t T, int64_t N, const uint8_t* truncated, Transitions& rows, double gamma, int n_step) {
  const int64_t TN = T * N;
  const int64_t od = int64_t(rows.obs.size()) / std::max<int64_t>(1, rows.n);
  const int64_t base = rows.n - TN;
  if (base < 0) throw std::logic_error("fold_n_step: fewer rows than the batch holds");
  if (rows.horizon.size() < size_t(rows.n)) rows.horizon.resize(rows.n, 1.f);
  if (n_step <= 1) return;
  // Rows in increasing order: row i only reads rows j >= i, which are still one-step rows (so
  // their `terminated` is still the batch's own flag).
  for (int64_t t = 0; t < T; ++t) {
    for (int64_t e = 0; e < N; ++e) {
      const int64_t i = base + t * N + e;
      double ret = 0, discount = 1;
      int64_t j = i, m = 0;
      for (int64_t k = 0; k < n_step; ++k) {
        j = base + (t + k) * N + e;
        ret += discount * rows.rewards[j];
        discount *= gamma;
        m = k + 1;
        if (rows.terminated[j] || truncated[j - base] || t + k == T - 1) break;
      }
      rows.rewards[i] = float(ret);
      rows.terminated[i] = rows.terminated[j];
      rows.horizon[i] = float(m);
      if (j != i)
        std::copy(rows.next_obs.begin() + j * od, rows.next_obs.begin() + (j + 1) * od, rows.next_obs.begin() + i * od);
    }
  }
}

}  // namespace farm
