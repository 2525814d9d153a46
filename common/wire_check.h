// The shape of each wire type (idl/farm.idl) as plain CDR, and a check of a serialized sample against
// it that runs before the generated code decodes it. fastcdr decodes a sample by trusting it: a
// boolean byte other than 0 or 1 throws an exception that no Fast DDS 2.9 reader catches (the
// process aborts), and a sequence's element count is allocated before its elements are read (a
// count that claims every remaining byte makes the reader allocate several times the sample). The
// check walks the sample field by field, bounds every count by the bytes that are really there and
// names the first field that is wrong, so a malformed sample is refused before any memory is taken
// for it.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

namespace farm::wire {

enum class Kind : uint8_t {
  Bool,       // one byte, 0 or 1
  U32,        // unsigned long, long (4 bytes, aligned to 4)
  U64,        // unsigned long long (8 bytes, aligned to 8)
  F32,        // float
  F64,        // double
  String,     // u32 length (terminator included), the characters, a terminating 0
  SeqOctet,   // sequence<octet>
  SeqU32,     // sequence<unsigned long>, sequence<long>
  SeqF32,     // sequence<float>
  Struct,     // a nested struct (Field::nested)
  SeqStruct,  // sequence<struct>
};

struct Layout;

struct Field {
  const char* name;
  Kind kind;
  const Layout* nested = nullptr;  // Struct and SeqStruct
};

struct Layout {
  const char* name;  // the IDL type name, e.g. farm::msg::TransitionBatch
  std::vector<Field> fields;
};

// One field met by walk(): its dotted path (episodes[3].metrics) and the offset of its first byte
// (a sequence's or string's count) from the start of the payload, encapsulation included.
using Visit = std::function<void(const std::string& path, Kind kind, size_t offset)>;

// What a walk found wrong, if anything.
enum class Fault : uint8_t {
  None,
  NoHeader,       // shorter than the encapsulation header
  Encapsulation,  // not plain CDR
  Truncated,      // ends inside a field
  Count,          // a sequence's or string's count claims more than the bytes left
  Bool,           // a boolean byte other than 0 or 1
  Terminator,     // a string without its terminating 0
  Trailing,       // more than padding after the last field
  UnknownKind,    // a layout of an unknown kind
};

struct Check {
  Fault fault = Fault::None;
  std::string field;   // the dotted path of the field at fault (episodes[3].terminated); "" for the whole
  size_t offset = 0;   // its byte in the payload, encapsulation included
  std::string detail;  // what is wrong, in words
  bool ok() const { return fault == Fault::None; }
  // "" when ok; else "field 'PATH' at byte N: DETAIL" (or DETAIL alone for the whole sample).
  std::string text() const;
};

// Checks `data` (a serialized payload: the 4-byte encapsulation header, then plain CDR in either
// byte order) against `layout`: ok, or the first fault with its field and offset. At most 3 bytes may follow the last
// field (alignment padding). Every count is checked against the bytes left before anything is read past it, so the walk
// takes time and memory proportional to `size` alone. visit, if given, is called for every field reached; end, if
// given, receives the offset just past the last field of a well-formed sample.
Check walk(const Layout& layout, const uint8_t* data, size_t size, const Visit& visit = {}, size_t* end = nullptr);

// The layouts of the wire types, one per struct of idl/farm.idl, in its field order.
const Layout& experiment_spec();
const Layout& transition_batch();
const Layout& policy_weights();
const Layout& evaluation_request();
const Layout& evaluation_answer();
const Layout& worker_status();
const Layout& learner_stats();

// The layout whose name is the IDL type name `type_name`; nullptr for an unknown one.
const Layout* layout_of(const std::string& type_name);

}  // namespace farm::wire
