// Where a program finds the files and programs it ships with: next to its own binary first (an
// installed or copied folder), then the build tree it was built in.
#pragma once

#include <string>
#include <vector>

namespace farm {

// The folder of the running program's binary ("" when /proc/self/exe cannot be read).
std::string executable_dir();

// The first of `candidates` that is an executable regular file, else "". Every candidate
// tried is appended to `tried` (for the error message).
std::string first_executable(const std::vector<std::string>& candidates, std::vector<std::string>& tried);

// A companion program `name` (e.g. "farm-worker"): `given` if not empty (it must exist and be
// executable), else next to this program, then `relative` to this program's folder (its place in
// the build tree, e.g. "../worker/farm-worker"), then `built` (the path it was built at). Throws
// std::runtime_error naming every path tried when none is there.
std::string find_companion(const std::string& name, const std::string& given, const std::string& relative,
                           const std::string& built, const std::string& flag);

// Removes a folder tree (a missing one is fine) with POSIX nftw, never std::filesystem::remove_all,
// which crashes the GPU build (see paths.cpp); throws std::runtime_error naming the path.
void remove_tree(const std::string& dir);

}  // namespace farm
