#include "compute.h"

#include <dlfcn.h>
#ifdef __GLIBC__
#include <malloc.h>
#endif

#include <cstdio>
#include <stdexcept>
#include <string>

#include "config.h"

namespace farm {

void configure_compute(int threads) {
  torch::set_num_threads(threads);
  // Looked up at run time: torch may be linked against a BLAS without this entry point.
  using SetThreads = void (*)(int);
  if (auto f = reinterpret_cast<SetThreads>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"))) f(threads);
#ifdef __GLIBC__
  // Fixed thresholds (which also turn off glibc's adaptive ones): tensors below 64 MiB come from
  // the heap, and up to 256 MiB of free heap is kept rather than trimmed.
  mallopt(M_MMAP_THRESHOLD, 64 << 20);
  mallopt(M_TRIM_THRESHOLD, 256 << 20);
#endif
}

// The device a config names, checked against what this LibTorch build and machine offer.
torch::Device learner_device(const std::string& name, const std::string& field) {
  if (!valid_device_name(name))
    throw std::invalid_argument(field + ": expected \"cpu\", \"cuda\", \"cuda:N\" or \"auto\", got \"" + name + "\"");
  if (name == "auto") {
    // Said once per network set, so a run's log tells where it trained.
    const bool gpu = torch::cuda::is_available();
    std::printf("[learner] %s \"auto\": %s\n", field.c_str(),
                gpu ? ("cuda (" + std::to_string(torch::cuda::device_count()) + " GPU(s) visible, using GPU 0)").c_str()
                    : "cpu (this learner's LibTorch has no CUDA or sees no GPU)");
    std::fflush(stdout);
    return gpu ? torch::Device(torch::kCUDA, 0) : torch::Device(torch::kCPU);
  }
  torch::Device d(name);
  if (d.is_cuda()) {
    if (!torch::cuda::is_available())
      throw std::runtime_error(field + " is \"" + name +
                               "\" but this learner's LibTorch has no CUDA or sees no GPU "
                               "(build with deploy/build-gpu.sh on a GPU host, or use \"cpu\")");
    if (d.has_index() && d.index() >= int(torch::cuda::device_count()))
      throw std::runtime_error(field + " is \"" + name + "\" but only " + std::to_string(torch::cuda::device_count()) +
                               " GPU(s) are visible");
  }
  return d;
}

}  // namespace farm
