// The policy file of a checkpoint folder (policy.bin): the policy in the workers' layout
// (PolicyParams), as a binary Protobuf PolicyFile (common/policy_file.proto). The learner writes it
// next to its networks in RUN/checkpoint and RUN/best; farm-export, farm-mobile-eval and the other
// programs that run a trained policy read it without LibTorch.
#pragma once

#include <string>

#include "mlp.h"

namespace farm {

inline constexpr const char* kPolicyFileName = "policy.bin";

// Writes p to path (a temporary file renamed over it, so a reader never sees half a file); throws
// std::runtime_error naming the file when it cannot.
void write_policy_file(const std::string& path, const PolicyParams& p);

// Reads and checks the policy at path: a PolicyFile of at most 256 MiB whose layout, sizes, head and
// normalizer are consistent (as a worker checks weights off the wire) and whose numbers are all
// finite. Throws std::runtime_error naming the file and what is wrong (missing, unreadable, not a
// PolicyFile, inconsistent, a number that is not finite).
PolicyParams read_policy_file(const std::string& path);

}  // namespace farm
