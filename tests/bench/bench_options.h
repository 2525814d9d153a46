// Options several benchmark programs share (tests/bench/*.cpp), declared once; each returns its
// CLI::Option so a program can change the default's wording or add a check.
#pragma once

#include <cstdlib>
#include <sstream>
#include <string>
#include <vector>

#include "cli.h"

namespace bench {

// --seconds S: measured time per figure, a number > 0.
inline CLI::Option* add_seconds(CLI::App& app, double& seconds,
                                const std::string& what = "Seconds measured per figure") {
  return app.add_option("--seconds", seconds, what)->check(farm::cli::positive())->capture_default_str();
}

// --threads N: a whole number >= 1.
inline CLI::Option* add_threads(CLI::App& app, int& threads, const std::string& what = "Torch threads") {
  return app.add_option("--threads", threads, what)->check(CLI::Range(1, 4096))->capture_default_str();
}

// --device cpu|cuda[:N]: where the networks run.
inline CLI::Option* add_device(CLI::App& app, std::string& device) {
  return app.add_option("--device", device, "Where the networks run: cpu or cuda[:N]")->capture_default_str();
}

// --batch B: samples per update, >= 1.
inline CLI::Option* add_batch(CLI::App& app, int& batch) {
  return app.add_option("--batch", batch, "Samples per update")->check(CLI::Range(1, 1 << 30))->capture_default_str();
}

// NAME V[,V...]: a comma-separated list whose values replace the default list.
template <typename T>
CLI::Option* add_list(CLI::App& app, const std::string& name, std::vector<T>& values, const std::string& what) {
  return app.add_option(name, values, what + ", comma-separated")->delimiter(',')->capture_default_str();
}

// --hidden H[,H...]: the hidden layer sizes, each >= 1.
inline CLI::Option* add_hidden(CLI::App& app, std::vector<int>& hidden) {
  return add_list(app, "--hidden", hidden, "Hidden layer sizes")->check(CLI::Range(1, 1 << 20));
}

// Networks as --hidden-sets gives them: "256,256;512,512,512" -> {{256,256},{512,512,512}}; empty on a malformed list.
inline std::vector<std::vector<int>> parse_hidden_sets(const std::string& text) {
  std::vector<std::vector<int>> sets;
  std::stringstream all(text);
  std::string one;
  while (std::getline(all, one, ';')) {
    std::vector<int> layers;
    std::stringstream items(one);
    std::string item;
    while (std::getline(items, item, ',')) {
      char* end = nullptr;
      const long v = std::strtol(item.c_str(), &end, 10);
      if (item.empty() || *end != '\0' || v < 1 || v > (1 << 20)) return {};
      layers.push_back(int(v));
    }
    if (layers.empty()) return {};
    sets.push_back(layers);
  }
  return sets;
}

}  // namespace bench
