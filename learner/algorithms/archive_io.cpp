#include "archive_io.h"

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <sstream>
#include <stdexcept>

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

}  // namespace farm
