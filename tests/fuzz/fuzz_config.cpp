// libFuzzer target for experiment-config parsing: any text either loads into a config whose
// values passed the range checks, or is refused with a ConfigError that names the source.
#include <cstdio>
#include <cstdlib>
#include <string>

#include "config.h"
#include "task_specs.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  std::string text(reinterpret_cast<const char*>(data), size);
  try {
    farm::config::ExperimentConfig cfg = farm::robots::parse_config_text(text, "fuzz.txtpb");
    // What loads must survive a round trip through the text form.
    farm::robots::parse_config_text(farm::config_to_text(cfg), "roundtrip.txtpb");
  } catch (const farm::ConfigError& e) {
    if (std::string(e.what()).find("fuzz.txtpb") == std::string::npos) {
      std::fprintf(stderr, "config error does not name its source: %s\n", e.what());
      std::abort();
    }
  }
  return 0;
}
