#include "paths.h"

#include <ftw.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <stdexcept>

namespace farm {

std::string executable_dir() {
  char exe[4096] = {0};
  const ssize_t n = readlink("/proc/self/exe", exe, sizeof(exe) - 1);
  if (n <= 0) return "";
  const std::string path(exe, static_cast<size_t>(n));
  return path.substr(0, path.rfind('/'));
}

std::string first_executable(const std::vector<std::string>& candidates, std::vector<std::string>& tried) {
  for (const auto& c : candidates) {
    if (c.empty()) continue;
    tried.push_back(c);
    struct stat st {};
    if (stat(c.c_str(), &st) == 0 && S_ISREG(st.st_mode) && access(c.c_str(), X_OK) == 0) return c;
  }
  return "";
}

std::string find_companion(const std::string& name, const std::string& given, const std::string& relative,
                           const std::string& built, const std::string& flag) {
  std::vector<std::string> tried;
  if (!given.empty()) {
    if (first_executable({given}, tried).empty())
      throw std::runtime_error(flag + " " + given + ": no executable file there");
    return given;
  }
  const std::string dir = executable_dir();
  std::vector<std::string> candidates;
  if (!dir.empty()) {
    candidates.push_back(dir + "/" + name);
    if (!relative.empty()) candidates.push_back(dir + "/" + relative);
  }
  candidates.push_back(built);
  const std::string found = first_executable(candidates, tried);
  if (!found.empty()) return found;
  std::string list;
  for (const auto& t : tried) list += (list.empty() ? "" : ", ") + t;
  throw std::runtime_error(name + " not found (tried " + list + "); give its path with " + flag + " PATH");
}

// Plain POSIX nftw, not std::filesystem::remove_all: the learner of the GPU build path (g++ 13
// against a host's CUDA LibTorch) died with SIGSEGV at its second checkpoint, the first that
// removes a previous one, where remove_all was called (and again when an evaluation's kept
// networks were dropped, and in test_sac's checkpoint tests); with nftw the same build
// checkpoints, resumes and evaluates.
void remove_tree(const std::string& dir) {
  // An entry gone meanwhile is removed all the same; the walk goes on past it.
  auto rm = [](const char* path, const struct stat*, int, struct FTW*) {
    return std::remove(path) == 0 || errno == ENOENT ? 0 : -1;
  };
  if (nftw(dir.c_str(), rm, 16, FTW_DEPTH | FTW_PHYS) != 0 && errno != ENOENT)
    throw std::runtime_error("cannot remove " + dir + ": " + std::strerror(errno));
}

}  // namespace farm
