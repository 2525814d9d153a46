// The machinery of the config checks in config.cpp: the parser's first error with its place, and
// the Validator and Section that name an out-of-range field by FILE:LINE:COL and its path. Included
// by config.cpp and by the checks of each task's section (robots/<robot>/*_spec.cpp).
#pragma once

#include <google/protobuf/io/tokenizer.h>
#include <google/protobuf/text_format.h>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "mlp.h"

#include "config.h"

namespace farm::config_checks {

namespace pb = google::protobuf;

class Collector : public pb::io::ErrorCollector {
 public:
  explicit Collector(std::string source) : source_(std::move(source)) {}
  void AddError(int line, pb::io::ColumnNumber column, const std::string& message) override {
    if (!first_.empty()) return;
    first_ = source_ + ":" + std::to_string(line + 1) + ":" + std::to_string(column + 1) + ": " + message;
  }
  void AddWarning(int, pb::io::ColumnNumber, const std::string&) override {}
  const std::string& first() const { return first_; }

 private:
  std::string source_;
  std::string first_;
};

// Walks the parsed message with the parser's location tree so a range error can name the line
// where the offending value was written. For a section built in code (no file) errors name the
// field path alone and are std::invalid_argument, as other bad arguments are.
class Validator {
 public:
  Validator() = default;  // a section built in code
  Validator(std::string source, const pb::TextFormat::ParseInfoTree* tree)
      : in_code_(false), source_(std::move(source)), tree_(tree) {}

  // index: the offending entry of a repeated field (its first entry when -1).
  [[noreturn]] void fail(const pb::Message& msg, const std::string& field, const std::string& path,
                         const std::string& what, int index = -1) const {
    if (in_code_) throw std::invalid_argument("field '" + path + "': " + what);
    const pb::FieldDescriptor* fd = msg.GetDescriptor()->FindFieldByName(field);
    const Node n = node_for(msg);
    pb::TextFormat::ParseLocation loc;
    if (fd && n.tree) loc = n.tree->GetLocation(fd, fd->is_repeated() ? std::max(index, 0) : -1);
    // A field left at its default is named by its section, where the file writes one: a value
    // out of range against another field (max_obstacles < min_obstacles) may be the default.
    if (loc.line < 0) loc = n.at;
    std::string where = source_;
    if (loc.line >= 0) where += ":" + std::to_string(loc.line + 1) + ":" + std::to_string(loc.column + 1);
    throw ConfigError(where + ": field '" + path + "': " + what);
  }

  // Location trees of nested messages, found by identity of the message object.
  // index: the entry of a repeated message field (-1 for a singular one).
  void nest(const pb::Message& parent, const std::string& field, const pb::Message& child, int index = -1) {
    const Node p = node_for(parent);
    const pb::FieldDescriptor* fd = parent.GetDescriptor()->FindFieldByName(field);
    Node n{&child, nullptr, {}};
    if (p.tree && fd) {
      n.tree = p.tree->GetTreeForNested(fd, index);
      n.at = p.tree->GetLocation(fd, index);
    }
    nodes_.push_back(n);
  }

 private:
  struct Node {
    const pb::Message* msg;
    const pb::TextFormat::ParseInfoTree* tree;
    pb::TextFormat::ParseLocation at;  // where the file opens the message, if it does
  };
  Node node_for(const pb::Message& m) const {
    for (const Node& n : nodes_)
      if (n.msg == &m) return n;
    return {&m, tree_, {}};  // the root
  }
  bool in_code_ = true;
  std::string source_;
  const pb::TextFormat::ParseInfoTree* tree_ = nullptr;
  std::vector<Node> nodes_;
};

inline std::string num(double v) {
  std::ostringstream o;
  o << v;
  return o.str();
}

// One message of the config and its path ("task.terms"): a check names the field by its path and,
// through the Validator, by where the file wrote it.
class Section {
 public:
  Section(Validator& v, const pb::Message& msg, std::string path) : v_(v), msg_(msg), path_(std::move(path)) {}

  // The message `field` of this one, e.g. task.nest("terms", t.terms()).
  Section nest(const std::string& field, const pb::Message& child) const {
    v_.nest(msg_, field, child);
    return Section(v_, child, path_of(field));
  }
  // Entry `index` of the repeated message field `field`, e.g. terms.nest_at("reward", 2, r): its
  // path reads "task.terms.reward[2]".
  Section nest_at(const std::string& field, int index, const pb::Message& child) const {
    v_.nest(msg_, field, child, index);
    return Section(v_, child, path_of(field) + "[" + std::to_string(index) + "]");
  }
  std::string path_of(const std::string& field) const { return path_.empty() ? field : path_ + "." + field; }

  [[noreturn]] void fail(const std::string& field, const std::string& what, int index = -1) const {
    v_.fail(msg_, field, path_of(field), what, index);
  }
  void check(bool ok, const std::string& field, const std::string& what) const {
    if (!ok) fail(field, what);
  }
  // The comparisons are written so that NaN fails them.
  void positive(const std::string& f, double x) const {
    if (!(x > 0)) fail(f, "expected > 0, got " + num(x));
  }
  void non_negative(const std::string& f, double x) const {
    if (!(x >= 0)) fail(f, "expected >= 0, got " + num(x));
  }
  void at_least(const std::string& f, double x, double lo) const {
    if (!(x >= lo)) fail(f, "expected >= " + num(lo) + ", got " + num(x));
  }
  void in_unit(const std::string& f, double x) const {  // (0, 1]
    if (!(x > 0 && x <= 1)) fail(f, "expected in (0, 1], got " + num(x));
  }
  void finite(const std::string& f, double x) const {
    if (!std::isfinite(x)) fail(f, "expected a finite value, got " + num(x));
  }
  // Physical constants of a model: an infinite one would make the simulation diverge.
  void finite_positive(const std::string& f, double x) const {
    positive(f, x);
    finite(f, x);
  }
  void finite_non_negative(const std::string& f, double x) const {
    non_negative(f, x);
    finite(f, x);
  }
  // Sizes of hidden layers: each in 1..kMaxMlpWidth, at most kMaxMlpLayers - 1 of them (with the
  // output layer, the bounds every process holds a network to: common/mlp.h).
  template <typename List>
  void layer_sizes(const std::string& f, const List& sizes) const {
    if (size_t(sizes.size()) > kMaxMlpLayers - 1)
      fail(f, "expected at most " + std::to_string(kMaxMlpLayers - 1) + " hidden layers, got " +
                  std::to_string(sizes.size()));
    for (int i = 0; i < sizes.size(); ++i)
      if (sizes.Get(i) <= 0 || sizes.Get(i) > kMaxMlpWidth)
        fail(f, "expected sizes in 1.." + std::to_string(kMaxMlpWidth) + ", got " + std::to_string(sizes.Get(i)), i);
  }
  // Entries in [lo, hi], none twice; `range` says the bounds, `name` how an entry reads ("group 3").
  template <typename List, typename Name>
  void distinct_in_range(const std::string& f, const List& list, int lo, int hi, const std::string& range,
                         Name name) const {
    for (int i = 0; i < list.size(); ++i) {
      const int v = list.Get(i);
      if (v < lo || v > hi) fail(f, "entries must be in " + range + ", got " + num(v), i);
      for (int j = 0; j < i; ++j)
        if (list.Get(j) == v) fail(f, "lists " + name(v) + " twice", i);
    }
  }

 private:
  Validator& v_;
  const pb::Message& msg_;
  std::string path_;
};

// A section checked in code (a config built by a program, not read from a file): errors name the
// path alone, as std::invalid_argument.
template <typename Msg, typename Check>
void check_in_code(const Msg& msg, const std::string& path, Check check) {
  Validator v;
  check(Section(v, msg, path), msg);
}

}  // namespace farm::config_checks
