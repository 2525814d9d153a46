#include "algorithm.h"

#include <cstdio>

namespace farm {

std::string fmt(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

}  // namespace farm
