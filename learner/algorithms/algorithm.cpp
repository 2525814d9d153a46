#include "algorithm.h"

#include <cmath>

namespace farm {

double UpdateFigures::get(const std::string& name) const {
  for (const auto& [n, v] : values)
    if (n == name) return v;
  return NAN;
}

}  // namespace farm
