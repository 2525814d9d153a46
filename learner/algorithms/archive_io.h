// Writing a LibTorch archive to a file so that a full disk is an error the caller can handle:
// OutputArchive::save_to(path) reports a failed write from a destructor, which ends the process;
// here the archive is serialized to memory and the bytes written with every write checked.
#pragma once

#include <torch/serialize/output-archive.h>

#include <string>

namespace farm {

// Throws std::runtime_error naming the file and the system's reason.
void save_archive(torch::serialize::OutputArchive& archive, const std::string& path);

}  // namespace farm
