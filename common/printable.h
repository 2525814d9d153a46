// Text that came from the network, made safe to print on an operator's terminal or in a log:
// printable ASCII stays, a backslash is doubled, and every other byte (control characters such as
// ESC, which starts terminal escape sequences, DEL, and bytes of 0x80 and above, among them the
// 8-bit control codes) is written as \xNN. At most max_bytes of the input are kept; a longer
// text ends in "... (N bytes)". With escape_backslash false a backslash stays as it is: for a
// whole line whose remote parts were already made printable.
#pragma once

#include <cstddef>
#include <cstdio>
#include <string>
#include <string_view>

namespace farm {

inline std::string printable(std::string_view s, size_t max_bytes = 200, bool escape_backslash = true) {
  std::string o;
  const size_t n = s.size() < max_bytes ? s.size() : max_bytes;
  o.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    const unsigned char c = static_cast<unsigned char>(s[i]);
    if (c == '\\' && escape_backslash) {
      o += "\\\\";
    } else if (c >= 0x20 && c < 0x7f) {
      o += char(c);
    } else {
      char b[8];
      std::snprintf(b, sizeof b, "\\x%02x", c);
      o += b;
    }
  }
  if (s.size() > max_bytes) o += "... (" + std::to_string(s.size()) + " bytes)";
  return o;
}

}  // namespace farm
