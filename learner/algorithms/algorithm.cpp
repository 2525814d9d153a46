// What the algorithms share of algorithm.h: number formatting and the evaluation counts.
#include "algorithm.h"

#include <cstdio>

namespace farm {

std::string fmt(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

std::string eval_counts(const FarmFigures& f) {
  return " | evals asked " + std::to_string(f.evals_asked) + " answered " + std::to_string(f.evals_answered) +
         " lost " + std::to_string(f.evals_lost) + " invalid " + std::to_string(f.evals_invalid);
}

}  // namespace farm
