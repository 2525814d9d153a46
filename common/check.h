// The one helper for checks in code: invariants that no config file states (a function's
// arguments, what a model must hold), and the rare check that needs more than the config.
// Range checks of config fields belong in common/config.cpp, where the error can name the file,
// the line and the field.
#pragma once

#include <stdexcept>
#include <string>

namespace farm {

// Throws std::invalid_argument(what) unless ok. `what` names what is wrong and the value seen.
inline void require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument(what);
}

}  // namespace farm
