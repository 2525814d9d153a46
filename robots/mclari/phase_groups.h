// Inter-leg phase groups of the mCLARI thesis §2.2: leg 0 is the reference; legs 1, 2, 3 take a phase from
// {0, pi/2, pi}, 27 triples in all, numbered in the order of the thesis's figure 15:
// group g = 9 i1 + 3 i2 + i3 has phases (i1, i2, i3) x pi/2.
#pragma once

#include <array>
#include <string>
#include <vector>

namespace farm::robots::mclari {

constexpr int kNumGroups = 27;

// Phases of legs 1, 2, 3 (radians) for group g in [0, 27); throws std::out_of_range otherwise.
std::array<double, 3> group_phases(int g);

// "(0, pi/2, pi)" style name of group g.
std::string group_name(int g);

// The reduced set of 8 (mCLARI thesis §4.1.2: "a good gait is achieved when the legs have angles
// similar two at two"). The thesis does not list its 8. These are the seven distinct triples in
// which the four legs move in two in-phase pairs (all in phase, and each of the three pairings of
// legs with the other pair at pi/2 or pi), plus (pi, pi, pi), the reference leg against the other
// three; they include the three groups the thesis plots in figure 17.
const std::vector<int>& reduced_groups();

}  // namespace farm::robots::mclari
