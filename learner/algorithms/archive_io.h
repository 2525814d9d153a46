// Writing a LibTorch archive to a file so that a full disk is an error the caller can handle:
// OutputArchive::save_to(path) reports a failed write from a destructor, which ends the process;
// here the archive is serialized to memory and the bytes written with every write checked.
#pragma once

#include <c10/util/ArrayRef.h>
#include <torch/serialize/output-archive.h>

#include <string>

namespace farm {

// Throws std::runtime_error naming the file and the system's reason.
void save_archive(torch::serialize::OutputArchive& archive, const std::string& path);

// A tensor shape as LibTorch prints it, "[64, 3]", for the errors of a checkpoint that does not fit.
std::string shape_str(c10::IntArrayRef shape);

}  // namespace farm
