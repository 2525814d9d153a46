// What every algorithm of the learner shares about where and how it computes: the process's
// compute threads and allocator settings, and the device a config names.
#pragma once

#include <torch/torch.h>

#include <string>

namespace farm {

// Process-wide settings for a process whose time goes to updates; call once, early.
// - n compute threads for torch and for the OpenBLAS that torch calls for matmuls: OpenBLAS keeps
//   its own pool, sized to the machine, which torch::set_num_threads does not reach.
// - glibc malloc keeps freed memory instead of returning it to the kernel: an update allocates and
//   frees the same few hundred KiB of activations every time, and by default those come back as
//   fresh pages to fault in (measured: ~40% of an update on the pendulum shapes).
// With threads > 1 on a machine shared with other work, also start the process with
// OMP_WAIT_POLICY=PASSIVE (libgomp reads it only at start-up): spinning OpenMP workers otherwise
// starve OpenBLAS's threads, measured 3-10x slower than one thread.
void configure_compute(int threads);

// The device a config's `field` names ("cpu", "cuda", "cuda:N", or "auto": GPU 0 where one is seen,
// else the CPU, printed), checked against what this LibTorch build and machine offer; the errors
// name the field.
torch::Device learner_device(const std::string& name, const std::string& field);

}  // namespace farm
