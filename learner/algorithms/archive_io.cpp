#include "archive_io.h"

#include <torch/torch.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <sstream>
#include <stdexcept>

#include "obs_normalizer.h"

namespace farm {

void save_archive(torch::serialize::OutputArchive& archive, const std::string& path) {
  std::ostringstream bytes;
  archive.save_to(bytes);
  const std::string data = bytes.str();
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) throw std::runtime_error("cannot open " + path + " for writing: " + std::strerror(errno));
  const size_t wrote = std::fwrite(data.data(), 1, data.size(), f);
  int err = wrote == data.size() ? 0 : errno;
  if (std::fflush(f) != 0 && err == 0) err = errno;
  if (std::fclose(f) != 0 && err == 0) err = errno;
  if (wrote != data.size() || err != 0)
    throw std::runtime_error("cannot write " + path + ": " + std::strerror(err ? err : EIO));
}

std::string shape_str(c10::IntArrayRef shape) {
  std::ostringstream o;
  o << shape;
  return o.str();
}

std::string sizes_str(const std::vector<int64_t>& sizes) {
  std::string s;
  for (size_t i = 0; i < sizes.size(); ++i) s += (i ? "," : "") + std::to_string(sizes[i]);
  return s;
}

void write_params(torch::serialize::OutputArchive& root, const std::string& key, const torch::nn::Module& m) {
  torch::serialize::OutputArchive a;
  for (const auto& p : m.named_parameters()) a.write(p.key(), p.value().detach().to(torch::kCPU));
  root.write(key, a);
}

std::vector<torch::Tensor> read_params(torch::serialize::InputArchive& root, const std::string& key,
                                       const torch::nn::Module& m, const std::string& what, const std::string& file) {
  torch::serialize::InputArchive a;
  if (!root.try_read(key, a)) throw std::runtime_error(what + " " + file + ": no '" + key + "'");
  std::vector<torch::Tensor> out;
  for (const auto& p : m.named_parameters()) {
    torch::Tensor t;
    if (!a.try_read(p.key(), t)) throw std::runtime_error(what + " " + file + ": no '" + key + "." + p.key() + "'");
    if (t.sizes() != p.value().sizes() || t.scalar_type() != p.value().scalar_type())
      throw std::runtime_error(what + " " + file + ": '" + key + "." + p.key() + "' has shape " + shape_str(t.sizes()) +
                               ", expected " + shape_str(p.value().sizes()));
    out.push_back(t);
  }
  return out;
}

void copy_into(const std::vector<torch::Tensor>& dst, const std::vector<torch::Tensor>& src) {
  torch::NoGradGuard no_grad;
  for (size_t i = 0; i < dst.size(); ++i) dst[i].copy_(src[i]);
}

torch::Tensor doubles(const std::vector<double>& v) {
  return torch::tensor(v, torch::TensorOptions().dtype(torch::kDouble)).reshape({int64_t(v.size())});
}

std::vector<double> to_doubles(const torch::Tensor& t) {
  const auto c = t.to(torch::kCPU, torch::kDouble).contiguous();
  return std::vector<double>(c.data_ptr<double>(), c.data_ptr<double>() + c.numel());
}

void write_moments(torch::serialize::OutputArchive& root, const ObsNormalizer& n) {
  root.write("obs_count", doubles({n.count()}));
  root.write("obs_mean", doubles(n.raw_mean()));
  root.write("obs_m2", doubles(n.raw_m2()));
}

bool read_moments(torch::serialize::InputArchive& root, ObsNormalizer& n) {
  torch::Tensor count, mean, m2;
  if (!root.try_read("obs_count", count) || !root.try_read("obs_mean", mean) || !root.try_read("obs_m2", m2) ||
      count.numel() != 1 || mean.numel() != n.dim() || m2.numel() != n.dim())
    return false;
  n.set_state(to_doubles(count)[0], to_doubles(mean), to_doubles(m2));
  return true;
}

}  // namespace farm
