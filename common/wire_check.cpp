#include "wire_check.h"

#include <map>

namespace farm::wire {

namespace {

// Plain CDR: each primitive aligned to its size, counted from the end of the encapsulation header.
constexpr size_t kHeader = 4;
constexpr size_t kMaxTrailing = 3;

size_t width(Kind k) {
  switch (k) {
    case Kind::Bool:
    case Kind::SeqOctet:
      return 1;
    case Kind::U64:
    case Kind::F64:
      return 8;
    default:
      return 4;
  }
}

class Walker {
 public:
  Walker(const uint8_t* data, size_t size, const Visit& visit) : d_(data), size_(size), visit_(visit) {}

  Check run(const Layout& layout, size_t* end) {
    if (size_ < kHeader)
      return fail(Fault::NoHeader, 0, "payload of " + std::to_string(size_) + " bytes has no encapsulation header");
    if (d_[0] != 0 || d_[1] > 1)
      return fail(Fault::Encapsulation, 0,
                  "encapsulation kind " + std::to_string(d_[0]) + "," + std::to_string(d_[1]) + " is not plain CDR");
    little_ = d_[1] == 1;
    pos_ = kHeader;
    if (!fields(layout)) return check_;
    if (size_ - pos_ > kMaxTrailing)
      return fail(Fault::Trailing, pos_,
                  std::to_string(size_ - pos_) + " bytes after the last field of " + layout.name + " (at most " +
                      std::to_string(kMaxTrailing) + " of padding)");
    if (end) *end = pos_;
    return check_;
  }

 private:
  // The dotted path of the field being walked (episodes[3].metrics), made only when it is needed:
  // a refusal or a visit, never for each field of a well-formed sample.
  std::string path() const {
    std::string p;
    for (const Step& s : path_) {
      if (!p.empty() && s.index < 0) p += '.';
      p += s.index < 0 ? std::string(s.name) : "[" + std::to_string(s.index) + "]";
    }
    return p;
  }
  Check fail(Fault fault, size_t at, std::string what) {
    check_.fault = fault;
    check_.field = path();
    check_.offset = at;
    check_.detail = std::move(what);
    return check_;
  }
  bool refuse(Fault fault, size_t at, std::string what) {
    fail(fault, at, std::move(what));
    return false;
  }
  bool align(size_t n) {
    const size_t pad = (n - (pos_ - kHeader) % n) % n;
    if (size_ - pos_ < pad) return refuse(Fault::Truncated, pos_, "ends before its alignment");
    pos_ += pad;
    return true;
  }
  uint32_t u32_at(size_t at) const {
    const uint8_t* p = d_ + at;
    return little_ ? uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24
                   : uint32_t(p[3]) | uint32_t(p[2]) << 8 | uint32_t(p[1]) << 16 | uint32_t(p[0]) << 24;
  }
  // A count (of a sequence or a string): aligned, read, and bounded by the bytes left, each element
  // taking at least min_bytes.
  bool count(Kind k, size_t min_bytes, uint32_t& n) {
    if (!align(4)) return false;
    if (size_ - pos_ < 4) return refuse(Fault::Truncated, pos_, "ends before its count");
    if (visit_) visit_(path(), k, pos_);
    n = u32_at(pos_);
    pos_ += 4;
    if (n > 0 && min_bytes > 1) {
      const size_t pad = (min_bytes - (pos_ - kHeader) % min_bytes) % min_bytes;
      if (pad > size_ - pos_ || uint64_t(n) * min_bytes > size_ - pos_ - pad)
        return refuse(Fault::Count, pos_ - 4,
                      std::to_string(n) + " elements of " + std::to_string(min_bytes) + " bytes claimed, " +
                          std::to_string(size_ - pos_) + " bytes left");
    } else if (uint64_t(n) > size_ - pos_) {
      return refuse(Fault::Count, pos_ - 4,
                    std::to_string(n) + " elements claimed, " + std::to_string(size_ - pos_) + " bytes left");
    }
    return true;
  }
  bool primitive(Kind k) {
    const size_t w = width(k);
    if (!align(w)) return false;
    if (size_ - pos_ < w) return refuse(Fault::Truncated, pos_, "ends before its " + std::to_string(w) + " bytes");
    if (visit_) visit_(path(), k, pos_);
    if (k == Kind::Bool && d_[pos_] > 1)
      return refuse(Fault::Bool, pos_, "boolean byte " + std::to_string(d_[pos_]) + " (0 or 1 expected)");
    pos_ += w;
    return true;
  }
  bool field(const Field& f) {
    uint32_t n = 0;
    switch (f.kind) {
      case Kind::Bool:
      case Kind::U32:
      case Kind::U64:
      case Kind::F32:
      case Kind::F64:
        return primitive(f.kind);
      case Kind::String:
        if (!count(f.kind, 1, n)) return false;
        if (n > 0 && d_[pos_ + n - 1] != 0)
          return refuse(Fault::Terminator, pos_ - 4,
                        "string of " + std::to_string(n) + " bytes without its terminating 0");
        pos_ += n;
        return true;
      case Kind::SeqOctet:
      case Kind::SeqU32:
      case Kind::SeqF32: {
        const size_t w = width(f.kind);
        if (!count(f.kind, w, n)) return false;
        if (n > 0 && !align(w)) return false;
        pos_ += size_t(n) * w;
        return true;
      }
      case Kind::Struct:
        return fields(*f.nested);
      case Kind::SeqStruct:
        // Each element takes at least one byte, so the count is bounded by the bytes left; each
        // element is then walked, so a false count runs out of bytes within `size` steps.
        if (!count(f.kind, 1, n)) return false;
        for (uint32_t i = 0; i < n; ++i) {
          path_.push_back({"", int64_t(i)});
          const bool ok = fields(*f.nested);
          path_.pop_back();
          if (!ok) return false;
        }
        return true;
    }
    return refuse(Fault::UnknownKind, pos_, "unknown kind");
  }
  bool fields(const Layout& layout) {
    for (const Field& f : layout.fields) {
      path_.push_back({f.name, -1});
      const bool ok = field(f);
      path_.pop_back();
      if (!ok) return false;
    }
    return true;
  }

  struct Step {
    const char* name;
    int64_t index;  // >= 0: an element of the sequence before it
  };
  const uint8_t* d_;
  size_t size_;
  const Visit& visit_;
  size_t pos_ = 0;
  bool little_ = true;
  std::vector<Step> path_;  // at most the layouts' depth plus one index each
  Check check_;
};

}  // namespace

std::string Check::text() const {
  if (ok()) return "";
  return field.empty() ? detail : "field '" + field + "' at byte " + std::to_string(offset) + ": " + detail;
}

Check walk(const Layout& layout, const uint8_t* data, size_t size, const Visit& visit, size_t* end) {
  return Walker(data, size, visit).run(layout, end);
}

// The layouts mirror idl/farm.idl field by field; the unit test wire_check serializes each type
// with the generated code and checks that the walk ends exactly at the sample's end.
namespace {

using K = Kind;

const Layout kEpisodeSummary{
    "farm::msg::EpisodeSummary",
    {{"env", K::U32}, {"episode_return", K::F32}, {"length", K::U32}, {"terminated", K::Bool}, {"metrics", K::SeqF32}}};

const Layout kEvaluationEpisode{
    "farm::msg::EvaluationEpisode",
    {{"episode_return", K::F32}, {"length", K::U32}, {"terminated", K::Bool}, {"metrics", K::SeqF32}}};

const Layout kExperimentSpec{"farm::msg::ExperimentSpec",
                             {{"experiment_id", K::String},
                              {"config_text", K::String},
                              {"task_name", K::String},
                              {"obs_dim", K::U32},
                              {"act_dim", K::U32},
                              {"steps_per_batch", K::U32},
                              {"max_batches_per_version", K::U32},
                              {"seed", K::U64},
                              {"learner_session", K::U64},
                              {"finished", K::Bool}}};

const Layout kTransitionBatch{"farm::msg::TransitionBatch",
                              {{"experiment_id", K::String},
                               {"worker_id", K::String},
                               {"worker_session", K::U64},
                               {"sequence_number", K::U64},
                               {"policy_version", K::U64},
                               {"num_steps", K::U32},
                               {"num_envs", K::U32},
                               {"obs_dim", K::U32},
                               {"act_dim", K::U32},
                               {"observations", K::SeqF32},
                               {"actions", K::SeqF32},
                               {"rewards", K::SeqF32},
                               {"terminated", K::SeqOctet},
                               {"truncated", K::SeqOctet},
                               {"log_probs", K::SeqF32},
                               {"next_observations", K::SeqF32},
                               {"final_index", K::SeqU32},
                               {"final_observations", K::SeqF32},
                               {"episodes", K::SeqStruct, &kEpisodeSummary},
                               {"end_of_stream", K::Bool}}};

const Layout kPolicyWeights{"farm::msg::PolicyWeights",
                            {{"experiment_id", K::String},
                             {"version", K::U64},
                             {"head", K::U32},
                             {"layer_sizes", K::SeqU32},
                             {"activation", K::U32},
                             {"log_std_min", K::F32},
                             {"log_std_max", K::F32},
                             {"obs_mean", K::SeqF32},
                             {"obs_std", K::SeqF32},
                             {"parameters", K::SeqF32},
                             {"epsilon", K::F32},
                             {"log_std", K::SeqF32},
                             {"batch_quota", K::U32}}};

const Layout kEvaluationRequest{"farm::msg::EvaluationRequest",
                                {{"experiment_id", K::String},
                                 {"learner_session", K::U64},
                                 {"request_id", K::U64},
                                 {"worker_id", K::String},
                                 {"policy_version", K::U64},
                                 {"episodes", K::U32},
                                 {"seed", K::U64},
                                 {"policy", K::Struct, &kPolicyWeights},
                                 {"first_episode", K::U32}}};

const Layout kEvaluationAnswer{"farm::msg::EvaluationAnswer",
                               {{"experiment_id", K::String},
                                {"learner_session", K::U64},
                                {"request_id", K::U64},
                                {"worker_id", K::String},
                                {"worker_session", K::U64},
                                {"policy_version", K::U64},
                                {"episodes", K::SeqStruct, &kEvaluationEpisode},
                                {"seconds", K::F64},
                                {"error", K::String}}};

const Layout kWorkerStatus{"farm::msg::WorkerStatus",
                           {{"worker_id", K::String},
                            {"worker_session", K::U64},
                            {"host", K::String},
                            {"experiment_id", K::String},
                            {"envs", K::U32},
                            {"threads", K::U32},
                            {"steps_per_second", K::F64},
                            {"env_steps", K::U64},
                            {"batches_sent", K::U64},
                            {"policy_version", K::U64},
                            {"state", K::String},
                            {"last_error", K::String}}};

const Layout kLearnerStat{"farm::msg::LearnerStat", {{"name", K::String}, {"unit", K::String}, {"value", K::F64}}};

const Layout kLearnerStats{"farm::msg::LearnerStats",
                           {{"experiment_id", K::String},
                            {"elapsed_seconds", K::F64},
                            {"env_steps", K::U64},
                            {"env_steps_per_second", K::F64},
                            {"updates", K::U64},
                            {"updates_per_second", K::F64},
                            {"buffer_fill", K::F64},
                            {"policy_lag", K::F64},
                            {"critic_loss", K::F64},
                            {"actor_loss", K::F64},
                            {"mean_return", K::F64},
                            {"eval_return", K::F64},
                            {"batches_ok", K::U64},
                            {"batches_lost", K::U64},
                            {"batches_duplicate", K::U64},
                            {"batches_invalid", K::U64},
                            {"workers", K::U32},
                            {"stats", K::SeqStruct, &kLearnerStat}}};

}  // namespace

const Layout& experiment_spec() { return kExperimentSpec; }
const Layout& transition_batch() { return kTransitionBatch; }
const Layout& policy_weights() { return kPolicyWeights; }
const Layout& evaluation_request() { return kEvaluationRequest; }
const Layout& evaluation_answer() { return kEvaluationAnswer; }
const Layout& worker_status() { return kWorkerStatus; }
const Layout& learner_stats() { return kLearnerStats; }

const Layout* layout_of(const std::string& type_name) {
  static const std::map<std::string, const Layout*> by_name = [] {
    std::map<std::string, const Layout*> m;
    for (const Layout* l : {&kExperimentSpec, &kTransitionBatch, &kPolicyWeights, &kEvaluationRequest,
                            &kEvaluationAnswer, &kWorkerStatus, &kLearnerStats})
      m[l->name] = l;
    return m;
  }();
  const auto it = by_name.find(type_name);
  return it == by_name.end() ? nullptr : it->second;
}

}  // namespace farm::wire
