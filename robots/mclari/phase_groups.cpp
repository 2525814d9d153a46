#include "mclari/phase_groups.h"

#include <stdexcept>

namespace farm::robots::mclari {

namespace {
constexpr double kHalfPi = 1.57079632679489661923;

int group_of(int i1, int i2, int i3) { return 9 * i1 + 3 * i2 + i3; }
}  // namespace

std::array<double, 3> group_phases(int g) {
  if (g < 0 || g >= kNumGroups) {
    throw std::out_of_range("mclari phase group " + std::to_string(g) + " is not in [0, 27)");
  }
  return {kHalfPi * (g / 9), kHalfPi * ((g / 3) % 3), kHalfPi * (g % 3)};
}

std::string group_name(int g) {
  group_phases(g);  // range check
  static const char* names[3] = {"0", "pi/2", "pi"};
  return std::string("(") + names[g / 9] + ", " + names[(g / 3) % 3] + ", " + names[g % 3] + ")";
}

const std::vector<int>& reduced_groups() {
  static const std::vector<int> groups = [] {
    std::vector<int> v{group_of(0, 0, 0)};
    for (int a = 1; a <= 2; ++a) {
      v.push_back(group_of(0, a, a));  // legs {0, 1} and {2, 3}
      v.push_back(group_of(a, 0, a));  // legs {0, 2} and {1, 3}
      v.push_back(group_of(a, a, 0));  // legs {0, 3} and {1, 2}
    }
    v.push_back(group_of(2, 2, 2));
    return v;
  }();
  return groups;
}

}  // namespace farm::robots::mclari
