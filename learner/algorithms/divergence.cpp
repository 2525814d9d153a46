#include "divergence.h"

#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace farm {

namespace {

template <class Figures>
void require_finite(const std::string& algorithm, int64_t update, const Figures& figures) {
  bool finite = true;
  for (const auto& f : figures) finite = finite && std::isfinite(f.second);
  if (finite) return;  // the common case, on every update: no formatting
  std::string list;
  for (const auto& [name, value] : figures) {
    char buf[96];
    std::snprintf(buf, sizeof buf, "%s%s %.4g", list.empty() ? "" : ", ", std::string(name).c_str(), value);
    list += buf;
  }
  throw std::runtime_error(algorithm + " training diverged at update " + std::to_string(update) + " (" + list +
                           "): stopped before these weights reached a worker or a checkpoint; the last "
                           "checkpoint is kept. Lower the learning rates, or resume from the checkpoint.");
}

}  // namespace

void require_finite_update(const std::string& algorithm, int64_t update,
                           std::initializer_list<std::pair<const char*, double>> figures) {
  require_finite(algorithm, update, figures);
}

void require_finite_update(const std::string& algorithm, int64_t update,
                           const std::vector<std::pair<std::string, double>>& figures) {
  require_finite(algorithm, update, figures);
}

}  // namespace farm
