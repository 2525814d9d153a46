#include "rng_state.h"

#include <ATen/CPUGeneratorImpl.h>
#include <torch/torch.h>

#include <cstring>
#include <mutex>
#include <sstream>
#include <stdexcept>

namespace farm {

void rng_to_manifest(const std::mt19937_64* sampler, config::CheckpointManifest& m) {
  if (sampler) {
    std::ostringstream s;
    s << *sampler;
    m.set_sampler_rng_state(s.str());
  }
  auto gen = at::detail::getDefaultCPUGenerator();
  torch::Tensor state;
  {
    std::lock_guard<std::mutex> lock(gen.mutex());
    state = gen.get_state().contiguous();
  }
  m.set_torch_rng_state(std::string(reinterpret_cast<const char*>(state.data_ptr<uint8_t>()), size_t(state.numel())));
}

void rng_from_manifest(const config::CheckpointManifest& m, std::mt19937_64* sampler) {
  if (sampler && m.has_sampler_rng_state()) {
    std::istringstream s(m.sampler_rng_state());
    std::mt19937_64 g;
    s >> g;
    if (!s) throw std::runtime_error("checkpoint manifest: sampler_rng_state is malformed");
    *sampler = g;
  }
  if (m.has_torch_rng_state()) {
    const std::string& bytes = m.torch_rng_state();
    auto state = torch::empty({int64_t(bytes.size())}, torch::kUInt8);
    std::memcpy(state.data_ptr<uint8_t>(), bytes.data(), bytes.size());
    auto gen = at::detail::getDefaultCPUGenerator();
    std::lock_guard<std::mutex> lock(gen.mutex());
    try {
      gen.set_state(state);
    } catch (const c10::Error& e) {
      throw std::runtime_error(std::string("checkpoint manifest: torch_rng_state is malformed: ") +
                               e.what_without_backtrace());
    }
  }
}

}  // namespace farm
