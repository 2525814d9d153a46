#include "divergence.h"

#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace farm {

void require_finite_update(const std::string& algorithm, int64_t update,
                           std::initializer_list<std::pair<const char*, double>> figures) {
  bool finite = true;
  for (const auto& f : figures) finite = finite && std::isfinite(f.second);
  if (finite) return;  // the common case, on every update: no formatting
  std::string list;
  for (const auto& [name, value] : figures) {
    char buf[96];
    std::snprintf(buf, sizeof buf, "%s%s %.4g", list.empty() ? "" : ", ", name, value);
    list += buf;
  }
  throw std::runtime_error(algorithm + " training diverged at update " + std::to_string(update) + " (" + list +
                           "): stopped before these weights reached a worker or a checkpoint; the last "
                           "checkpoint is kept. Lower the learning rates, or resume from the checkpoint.");
}

}  // namespace farm
