// The book of malformed samples (dds.h, CheckedType): per IDL type, how many this process's readers
// refused and why the last one was refused.
#include <cstdio>
#include <map>
#include <mutex>

#include "dds.h"

namespace farm::dds {

namespace {

// Lines said on stderr per type; the count goes on (Reader::malformed), the learner's events too.
constexpr uint64_t kMaxMalformedLines = 5;

struct MalformedBook {
  uint64_t count = 0;
  std::string last;
};

std::mutex g_malformed_mu;
std::map<std::string, MalformedBook> g_malformed;
thread_local bool t_malformed_mark = false;

}  // namespace

void note_malformed(const std::string& type_name, const std::string& why) {
  t_malformed_mark = true;
  uint64_t n = 0;
  {
    std::lock_guard<std::mutex> lk(g_malformed_mu);
    MalformedBook& b = g_malformed[type_name];
    n = ++b.count;
    b.last = why;
  }
  if (n <= kMaxMalformedLines)
    std::fprintf(stderr, "refused a malformed %s sample: %s%s\n", type_name.c_str(), why.c_str(),
                 n == kMaxMalformedLines ? " (no more such lines for this type; they are counted)" : "");
}

uint64_t samples_malformed(const std::string& type_name) {
  std::lock_guard<std::mutex> lk(g_malformed_mu);
  const auto it = g_malformed.find(type_name);
  return it == g_malformed.end() ? 0 : it->second.count;
}

std::string last_malformed(const std::string& type_name) {
  std::lock_guard<std::mutex> lk(g_malformed_mu);
  const auto it = g_malformed.find(type_name);
  return it == g_malformed.end() ? "" : it->second.last;
}

bool take_malformed_mark() {
  const bool was = t_malformed_mark;
  t_malformed_mark = false;
  return was;
}

}  // namespace farm::dds
