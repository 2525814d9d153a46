// What the algorithms share of algorithm.h: number formatting and the evaluation counts.
#include "algorithm.h"

#include <algorithm>
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

std::string best_eval_line(const FarmFigures& f) {
  std::string label = "best eval " + f.best_measure;
  label.resize(std::max<size_t>(label.size() + 1, 18), ' ');  // the summary's value column
  return label + fmt(f.best_measure == "return" ? "%.1f" : "%.4f", f.best_eval);
}

}  // namespace farm
