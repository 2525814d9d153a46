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

// One batch into `ingest`: consistent transitions when accepted; whatever its sequence number and
// session (the whole 64-bit range), the loss it books stays within the bound on a jump, and a
// refused batch opens no account.
std::string run_on(farm::Ingest& ingest, const farm::msg::TransitionBatch& b, uint64_t version) {
  const int obs_dim = 3, act_dim = 1;
  farm::Transitions out;
  std::vector<farm::FinishedEpisode> eps;
  const uint64_t lost_before = ingest.counters().lost;
  const size_t accounts_before = ingest.workers().size();
  std::string why = ingest.accept(b, version, 0.0, out, eps);
  if (why.empty()) check_output(out, obs_dim, act_dim);
  if (ingest.counters().lost > lost_before + farm::Ingest::kMaxSequenceJump) {
    std::fprintf(stderr, "one batch booked %llu lost\n", (unsigned long long)(ingest.counters().lost - lost_before));
    std::abort();
  }
  if (!why.empty() && ingest.workers().size() != accounts_before) {
    std::fprintf(stderr, "a refused batch opened an account: %s\n", why.c_str());
    std::abort();
  }
  if (ingest.workers().size() > farm::Ingest::kMaxAccounts) std::abort();
  for (const auto& [k, w] : ingest.workers()) {
    if (w.next_sequence == 0 && w.received + w.invalid + w.duplicates > 0) {
      std::fprintf(stderr, "next_sequence wrapped to 0\n");
      std::abort();
    }
  }
  return why;
}

void run(const farm::msg::TransitionBatch& b, uint64_t version) {
  farm::Ingest ingest("fuzz", 3, 1, 0);
  const std::string why = run_on(ingest, b, version);
  // A second delivery of the same batch is a duplicate, never a second acceptance.
  farm::Transitions again;
  std::vector<farm::FinishedEpisode> eps;
  if (why.empty() && ingest.accept(b, version, 0.0, again, eps).empty()) {
    std::fprintf(stderr, "the same sequence number was accepted twice\n");
    std::abort();
  }
}

float value(FuzzedDataProvider& p) {
  switch (p.ConsumeIntegralInRange<int>(0, 7)) {
    case 0:
      return std::nanf("");
    case 1:
      return INFINITY;
    case 2:
      return p.ConsumeFloatingPoint<float>();
    default:
      return p.ConsumeFloatingPointInRange<float>(-2.f, 2.f);
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
  // Sessions and sequence numbers from the whole 64-bit range as well as the small ones a stream
  // starts with.
  b.worker_session(p.ConsumeBool() ? p.ConsumeIntegralInRange<uint64_t>(1, 2) : p.ConsumeIntegral<uint64_t>());
  b.sequence_number(p.ConsumeBool() ? p.ConsumeIntegralInRange<uint64_t>(0, 3) : p.ConsumeIntegral<uint64_t>());
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
  // Mostly one summary per episode end, as a worker sends them; now and then one more, or one off in
  // its env, flag, length or metrics.
  std::vector<farm::msg::EpisodeSummary> eps(finals.size());
  for (size_t j = 0; j < eps.size(); ++j) {
    const size_t end = finals[j];
    eps[j].env(N > 0 ? uint32_t(end % N) : 0);
    eps[j].terminated(end < TN && term[end] == 1);
    eps[j].episode_return(value(p));
    eps[j].length(p.ConsumeIntegralInRange<uint32_t>(1, 1000));
  }
  const int off = p.ConsumeIntegralInRange<int>(0, 9);
  if (off == 1) eps.emplace_back();
  if (!eps.empty() && off == 2) eps[0].env(p.ConsumeIntegralInRange<uint32_t>(0, 5));
  if (!eps.empty() && off == 3) eps[0].terminated(!eps[0].terminated());
  if (!eps.empty() && off == 4) eps[0].length(0);
  if (!eps.empty() && off == 5) eps[0].metrics({value(p)});
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
    // Up to four batches into one learner's door, so jumps and sessions meet earlier streams.
    FuzzedDataProvider p(data + 1, size - 1);
    farm::Ingest ingest("fuzz", 3, 1, 0);
    const int n = p.ConsumeIntegralInRange<int>(1, 4);
    for (int k = 0; k < n && p.remaining_bytes() > 0; ++k) run_on(ingest, build(p), data[0] >> 1);
  }
  return 0;
}
