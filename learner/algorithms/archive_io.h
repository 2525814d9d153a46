// Writing a LibTorch archive to a file so that a full disk is an error the caller can handle:
// OutputArchive::save_to(path) reports a failed write from a destructor, which ends the process;
// here the archive is serialized to memory and the bytes written with every write checked.
#pragma once

#include <c10/util/ArrayRef.h>
#include <torch/nn/module.h>
#include <torch/serialize/input-archive.h>
#include <torch/serialize/output-archive.h>

#include <string>
#include <vector>

namespace farm {

class ObsNormalizer;

// Throws std::runtime_error naming the file and the system's reason.
void save_archive(torch::serialize::OutputArchive& archive, const std::string& path);

// A tensor shape as LibTorch prints it, "[64, 3]", for the errors of a checkpoint that does not fit.
std::string shape_str(c10::IntArrayRef shape);

// Layer sizes as "17,256,256,12", for a checkpoint's record of its networks.
std::string sizes_str(const std::vector<int64_t>& sizes);

// A module's parameters under `key` of `root`, each by its name, so that a file of other network
// sizes is refused by name and shape instead of being reinterpreted.
void write_params(torch::serialize::OutputArchive& root, const std::string& key, const torch::nn::Module& m);

// What write_params wrote, each tensor checked against the module's before anything is changed;
// in named_parameters order. Errors name `what` (e.g. "sac checkpoint"), the file and the tensor.
std::vector<torch::Tensor> read_params(torch::serialize::InputArchive& root, const std::string& key,
                                       const torch::nn::Module& m, const std::string& what, const std::string& file);

// A checkpoint's figures as a 1-D double tensor, and back (from any device and type).
torch::Tensor doubles(const std::vector<double>& v);
std::vector<double> to_doubles(const torch::Tensor& t);

// An observation normalizer's running moments under obs_count, obs_mean and obs_m2 of `root`.
// read_moments restores them and returns true, or returns false and changes nothing where one is
// missing or not of the normalizer's size.
void write_moments(torch::serialize::OutputArchive& root, const ObsNormalizer& n);
bool read_moments(torch::serialize::InputArchive& root, ObsNormalizer& n);

// dst[i] = src[i], outside autograd.
void copy_into(const std::vector<torch::Tensor>& dst, const std::vector<torch::Tensor>& src);

}  // namespace farm
