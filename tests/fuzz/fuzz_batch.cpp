// libFuzzer target for the learner's door: whatever arrives, Ingest must refuse it with a reason
// or accept it with consistent transitions, never crash, read out of bounds or let a non-finite
// number through. Two ways in: raw bytes as a CDR-encoded TransitionBatch (what the wire
// delivers), and batches built field by field from the input (to reach the deeper checks).
#include <fuzzer/FuzzedDataProvider.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include <fastcdr/Cdr.h>
#include <fastcdr/FastBuffer.h>

#include "farm.h"
#include "ingest.h"

namespace {

void check_output(const farm::Transitions& t, int obs_dim, int act_dim) {
  auto finite = [](const std::vector<float>& v) {
    for (float x : v)
      if (!std::isfinite(x)) return false;
    return true;
  };
  const size_t n = static_cast<size_t>(t.n);
  if (t.obs.size() != n * obs_dim || t.next_obs.size() != n * obs_dim || t.actions.size() != n * act_dim ||
      t.rewards.size() != n || t.terminated.size() != n || !finite(t.obs) || !finite(t.next_obs) ||
      !finite(t.actions) || !finite(t.rewards)) {
    std::fprintf(stderr, "accepted batch produced inconsistent or non-finite transitions\n");
    std::abort();
  }
}

void run(const farm::msg::TransitionBatch& b, uint64_t version) {
  const int obs_dim = 3, act_dim = 1;
  farm::Ingest ingest("fuzz", obs_dim, act_dim);
  farm::Transitions out;
  std::vector<farm::FinishedEpisode> eps;
  std::string why = ingest.accept(b, version, 0.0, out, eps);
  if (why.empty()) check_output(out, obs_dim, act_dim);
  // A second delivery of the same batch is a duplicate, never a second acceptance.
  farm::Transitions again;
  if (why.empty() && ingest.accept(b, version, 0.0, again, eps).empty()) {
    std::fprintf(stderr, "the same sequence number was accepted twice\n");
    std::abort();
  }
}

float value(FuzzedDataProvider& p) {
  switch (p.ConsumeIntegralInRange<int>(0, 7)) {
    case 0: return std::nanf("");
    case 1: return INFINITY;
    case 2: return p.ConsumeFloatingPoint<float>();
    default: return p.ConsumeFloatingPointInRange<float>(-2.f, 2.f);
  }
}

template <class T, class F>
std::vector<T> vec(FuzzedDataProvider& p, size_t expected, F make) {
  size_t n = expected;
  if (p.ConsumeIntegralInRange<int>(0, 15) == 0) n = p.ConsumeIntegralInRange<size_t>(0, expected + 3);
  std::vector<T> v(n);
  for (auto& x : v) x = make();
  return v;
}

farm::msg::TransitionBatch build(FuzzedDataProvider& p) {
  farm::msg::TransitionBatch b;
  b.experiment_id(p.ConsumeBool() ? "fuzz" : p.ConsumeRandomLengthString(8));
  b.worker_id("w");
  b.worker_session(1);
  b.sequence_number(p.ConsumeIntegralInRange<uint64_t>(0, 3));
  b.policy_version(p.ConsumeIntegralInRange<uint64_t>(0, 5));
  const uint32_t T = p.ConsumeIntegralInRange<uint32_t>(0, 4), N = p.ConsumeIntegralInRange<uint32_t>(0, 4);
  b.num_steps(T);
  b.num_envs(N);
  b.obs_dim(p.ConsumeIntegralInRange<int>(0, 7) == 0 ? p.ConsumeIntegral<uint32_t>() : 3);
  b.act_dim(p.ConsumeIntegralInRange<int>(0, 7) == 0 ? p.ConsumeIntegral<uint32_t>() : 1);
  b.end_of_stream(p.ConsumeIntegralInRange<int>(0, 9) == 0);
  const size_t TN = size_t(T) * N;
  b.observations(vec<float>(p, TN * 3, [&] { return value(p); }));
  b.actions(vec<float>(p, TN, [&] { return value(p); }));
  b.rewards(vec<float>(p, TN, [&] { return value(p); }));
  b.log_probs(vec<float>(p, TN, [&] { return value(p); }));
  std::vector<uint8_t> term(TN), trunc(TN);
  std::vector<uint32_t> finals;
  for (size_t i = 0; i < TN; ++i) {
    int f = p.ConsumeIntegralInRange<int>(0, 12);
    term[i] = f == 1 ? 1 : (f == 12 ? 2 : 0);
    trunc[i] = f == 2 ? 1 : 0;
    if (f == 1 || f == 2 || f == 11) finals.push_back(static_cast<uint32_t>(i));
  }
  if (p.ConsumeIntegralInRange<int>(0, 15) == 0 && !finals.empty()) finals.back() += p.ConsumeIntegral<uint8_t>();
  b.terminated(term);
  b.truncated(trunc);
  b.final_index(finals);
  b.next_observations(vec<float>(p, size_t(N) * 3, [&] { return value(p); }));
  b.final_observations(vec<float>(p, finals.size() * 3, [&] { return value(p); }));
  std::vector<farm::msg::EpisodeSummary> eps(p.ConsumeIntegralInRange<size_t>(0, 2));
  for (auto& e : eps) {
    e.env(p.ConsumeIntegralInRange<uint32_t>(0, 5));
    e.episode_return(value(p));
    e.length(p.ConsumeIntegral<uint16_t>());
  }
  b.episodes(eps);
  return b;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  if (data[0] & 1) {
    // The wire: CDR bytes as the DDS reader would hand them to the type.
    std::vector<char> buf(data + 1, data + size);
    eprosima::fastcdr::FastBuffer fb(buf.data(), buf.size());
    eprosima::fastcdr::Cdr cdr(fb, eprosima::fastcdr::Cdr::DEFAULT_ENDIAN, eprosima::fastcdr::Cdr::DDS_CDR);
    farm::msg::TransitionBatch b;
    try {
      b.deserialize(cdr);
    } catch (const std::exception&) {
      return 0;  // refused by the decoder
    }
    run(b, data[0] >> 1);
  } else {
    FuzzedDataProvider p(data + 1, size - 1);
    run(build(p), data[0] >> 1);
  }
  return 0;
}
