// How a run of the learner ends (FarmService, farm_service.h): on Ctrl-C / SIGTERM the batches
// already on their way are taken before the checkpoint; at a stop rule, after the final
// evaluation, every worker stream is taken to its end, so that the summary (summary.txt: head,
// the algorithm's lines, evaluations, one line per worker stream) says exactly what was sent and
// what arrived.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <tuple>

#include "farm_service.h"
#include "meter.h"
#include "printable.h"

namespace farm {

namespace fs = std::filesystem;

std::string FarmService::summary_head(double elapsed, const std::string& reason) const {
  const IngestCounters c = intake_.counters();
  std::ostringstream o;
  o << "experiment        " << cfg_.experiment_id() << "\n"
    << "stopped because   " << reason << "\n"
    << "wall time         " << fmt("%.1f", elapsed) << " s\n"
    << "env steps         " << c.env_steps << " (" << fmt("%.0f", c.env_steps / std::max(elapsed, 1e-9))
    << " steps/s)\n";
  if (steps_at_stop_ > 0)
    o << "after the stop    " << (c.env_steps - steps_at_stop_)
      << " env steps arrived (workers held at the stop: their batches already made)\n";
  if (const std::string n = untrained_stop_note(reason); !n.empty()) o << "note              " << n << "\n";
  return o.str();
}

std::string FarmService::untrained_stop_note(const std::string& reason) const {
  const bool step_limit = reason.rfind("env step limit", 0) == 0 || reason.rfind("update limit", 0) == 0;
  if (!step_limit || evaluated_in_training_) return "";
  return "the run stopped on its " + reason.substr(0, reason.find(" limit")) +
         " limit before its first evaluation (eval.every_seconds " + fmt("%g", cfg_.eval().every_seconds()) +
         "): its policy was never evaluated while it trained, and more workers reach a step limit sooner; "
         "stop on time (stop.max_seconds) or on a target instead";
}

std::string FarmService::summary_workers(nlohmann::json& event) {
  std::ostringstream o;
  // The accounts as they are now (the ingest thread goes on): streams, retired and foreign.
  std::map<Ingest::Key, WorkerAccount> workers;
  uint64_t retired = 0, foreign = 0;
  intake_.with_ingest([&](const Ingest& in) {
    workers = in.workers();
    retired = in.retired();
    foreign = in.counters().foreign;
  });
  if (foreign > 0) o << "other experiments " << foreign << " batches of other experiments on the domain, not used\n";
  // One line per stream, the kMaxSummaryStreams with the most accepted batches (invented streams
  // may number thousands), then how many more.
  std::vector<const WorkerAccount*> shown;
  for (const auto& [k, w] : workers) shown.push_back(&w);
  std::stable_sort(shown.begin(), shown.end(),
                   [](const WorkerAccount* a, const WorkerAccount* b) { return a->received > b->received; });
  const size_t more = shown.size() > kMaxSummaryStreams ? shown.size() - kMaxSummaryStreams : 0;
  shown.resize(shown.size() - more);
  std::sort(shown.begin(), shown.end(), [](const WorkerAccount* a, const WorkerAccount* b) {
    return std::tie(a->worker_id, a->session) < std::tie(b->worker_id, b->session);
  });
  o << "streams           " << workers.size() << " open, " << retired
    << " retired (idle for account_expiry_seconds, or to make room)\n";
  nlohmann::json streams = nlohmann::json::array();
  for (const WorkerAccount* w : shown) {
    const uint64_t last_sequence = w->next_sequence ? w->next_sequence - 1 : 0;
    o << "worker            " << printable(w->worker_id, 100) << " session " << w->session << ": received "
      << w->received << " of sequence 0.." << last_sequence << ", lost " << w->lost << ", duplicate " << w->duplicates
      << ", invalid " << w->invalid << (w->ended ? ", stream closed" : ", stream open") << "\n";
    streams.push_back({{"worker_id", printable(w->worker_id, 100)},
                       {"session", w->session},
                       {"received", w->received},
                       {"last_sequence", last_sequence},
                       {"lost", w->lost},
                       {"duplicate", w->duplicates},
                       {"invalid", w->invalid},
                       {"closed", w->ended}});
  }
  if (more > 0) o << "streams           " << more << " more not listed\n";
  event["batches_other_experiments"] = foreign;
  event["streams_open"] = workers.size();
  event["streams_retired"] = retired;
  event["streams_not_listed"] = more;
  event["streams"] = std::move(streams);
  return o.str();
}

void FarmService::write_summary(double elapsed, const std::string& reason) {
  FarmFigures f = figures();
  const IngestCounters c = intake_.counters();
  nlohmann::json event = {
      {"reason", reason},
      {"wall_s", elapsed},
      {"env_steps", c.env_steps},
      {"batches_ok", c.ok},
      {"batches_lost", c.lost},
      {"batches_duplicate", c.duplicate},
      {"batches_invalid", c.invalid},
      {"updates", algo_->updates()},
      {"policy_version", algo_->version()},
      {"evals_asked", evaluator_.asked()},
      {"evals_answered", evaluator_.answered()},
      {"evals_lost", evaluator_.lost()},
      {"evals_invalid", evaluator_.invalid()},
      {"checkpoints_failed", checkpointer_.failed()},
      {"best_eval", std::isnan(f.best_eval) ? nlohmann::json(nullptr) : nlohmann::json(f.best_eval)},
      {"best_measure", f.best_measure},
      {"note", untrained_stop_note(reason)}};
  if (steps_at_stop_ > 0) event["env_steps_after_stop"] = c.env_steps - steps_at_stop_;
  event.update(algo_->summary_fields());
  const std::string text =
      summary_head(elapsed, reason) + algo_->summary(f, elapsed) + evaluator_.summary() + summary_workers(event);
  std::printf("\n===== summary =====\n%s===================\n", text.c_str());
  std::ofstream(fs::path(run_dir_) / "summary.txt") << text;
  event["events_unwritten"] = events_.failures();
  events_.write("summary", event);
  log("summary written to " + run_dir_ + "/summary.txt");
}

// The workers are told to hold (the current version re-sent with a quota of one batch; no new
// version follows), so each sends at most one more batch and then waits: take batches until none
// has come for 0.5 s and no live worker says it is running (or none for 3 s; 15 s at most).
void FarmService::drain_before_interrupted_stop() {
  algo_->hold_workers(*this);
  const double t0 = now_seconds(), t_end = t0 + 15.0;
  double last = t0;
  size_t taken = 0;
  while (now_seconds() < t_end) {
    const size_t got = drain_batches(1024);
    const double now = now_seconds();
    if (got > 0) {
      taken += got;
      last = now;
      continue;
    }
    bool running = false;
    for (const auto& w : roster_.workers()) running = running || (w.live && w.view.last.state() == "running");
    if (now - last >= 3.0 || (now - last >= 0.5 && !running)) break;
    intake_.wait(0.05);
  }
  log("took the " + std::to_string(taken) + " batches in flight (" + fmt("%.1f", now_seconds() - t0) + " s)");
}

// After announcing the end, every batch still in flight is taken and accounted, so the summary
// can say exactly what was sent and what arrived.
void FarmService::drain_until_workers_end() {
  // Waited for: the streams of workers heard within worker_timeout_seconds (a worker blocked for
  // weights still beats). A stream with no such worker (one gone, or a stream someone invented)
  // and no batch in that time is not.
  const double t_end = now_seconds() + 15.0, quiet = cfg_.worker_timeout_seconds();
  while (now_seconds() < t_end) {
    drain_batches(1024);
    const double now = now_seconds();
    const auto waited_for = [&](const WorkerAccount& w) {
      if (w.ended) return false;
      if (now - w.last_seen < quiet) return true;
      const auto v = roster_.find(w.worker_id + "#" + std::to_string(w.session));
      return v && now - v->view.seen < quiet;
    };
    bool all_ended = false;
    intake_.with_ingest([&](const Ingest& in) {
      all_ended = !in.workers().empty();
      for (auto& [k, w] : in.workers()) all_ended = all_ended && !waited_for(w);
    });
    if (all_ended && intake_.queued() == 0) break;
    intake_.wait(0.05);
  }
  drain_batches(SIZE_MAX);
  size_t open = 0;
  std::vector<std::string> lines;
  intake_.with_ingest([&](const Ingest& in) {
    for (auto& [k, w] : in.workers())
      if (!w.ended && ++open <= kMaxOpenStreamLines)
        lines.push_back("worker " + printable(w.worker_id, 100) + " did not close its stream; batches after " +
                        std::to_string(w.next_sequence) + " are unaccounted");
  });
  for (const auto& l : lines) log(l);
  if (open > kMaxOpenStreamLines)
    log("... and " + std::to_string(open - kMaxOpenStreamLines) + " more streams not closed (the summary lists them)");
}

}  // namespace farm
