// Starting and watching the farm's real processes from integration tests.
#pragma once

#include <fcntl.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "../wait_until.h"

namespace farm::testing {

struct Proc {
  pid_t pid = -1;
  std::string log;
};

// Starts argv[0] with stdout and stderr going to log_path.
inline Proc spawn(const std::vector<std::string>& argv, const std::string& log_path) {
  Proc p;
  p.log = log_path;
  p.pid = fork();
  if (p.pid == 0) {
    int fd = open(log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    dup2(fd, 1);
    dup2(fd, 2);
    close(fd);
    std::vector<char*> args;
    for (auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    execv(args[0], args.data());
    _exit(127);
  }
  return p;
}

// Exit status (128 + signal if killed by one), or -1 if it had to be killed after timeout_s.
inline int wait_for(Proc& p, double timeout_s) {
  auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  int status = 0;
  while (true) {
    pid_t r = waitpid(p.pid, &status, WNOHANG);
    if (r == p.pid) break;
    if (std::chrono::steady_clock::now() > deadline) {
      kill(p.pid, SIGKILL);
      waitpid(p.pid, &status, 0);
      p.pid = -1;
      return -1;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  p.pid = -1;
  return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

inline std::string slurp(const std::string& path) {
  std::ifstream f(path);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

inline void write_file(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

// Polls a log file every 200 ms until found(its text); false after timeout_s.
template <class Found>
bool poll_log(const std::string& path, Found found, double timeout_s) {
  auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (std::chrono::steady_clock::now() < deadline) {
    if (found(slurp(path))) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  return false;
}

// Polls a log file until it contains `needle`; false after timeout_s.
inline bool wait_for_text(const std::string& path, const std::string& needle, double timeout_s) {
  return poll_log(
      path, [&](const std::string& t) { return t.find(needle) != std::string::npos; }, timeout_s);
}

// Polls a log file until a line of it matches `pattern`; false after timeout_s.
inline bool wait_for_match(const std::string& path, const std::string& pattern, double timeout_s) {
  const std::regex re(pattern);
  return poll_log(
      path, [&](const std::string& t) { return std::regex_search(t, re); }, timeout_s);
}

// The events of one kind in an events file (JSON lines: the learner's RUN/events.jsonl, a worker's
// --events file) ("" kind: all), in order; a line that is not JSON is skipped.
inline std::vector<nlohmann::json> events_in(const std::string& file, const std::string& kind = "") {
  std::vector<nlohmann::json> out;
  std::ifstream in(file);
  for (std::string line; std::getline(in, line);) {
    const nlohmann::json e = nlohmann::json::parse(line, nullptr, false);
    if (e.is_object() && (kind.empty() || e.value("event", "") == kind)) out.push_back(e);
  }
  return out;
}

// The events of one kind in RUN/events.jsonl, the learner's record for programs.
inline std::vector<nlohmann::json> events(const std::string& run, const std::string& kind = "") {
  return events_in(run + "/events.jsonl", kind);
}

// The first event of `kind` whose field `key` holds a text containing `part`; null when none.
inline nlohmann::json event_with(const std::string& run, const std::string& kind, const std::string& key,
                                 const std::string& part) {
  for (const auto& e : events(run, kind))
    if (e.contains(key) && e[key].is_string() && e[key].get<std::string>().find(part) != std::string::npos) return e;
  return nullptr;
}

// The run's summary event (the last "summary" of RUN/events.jsonl: what summary.txt says, as data);
// an empty object when the run wrote none.
inline nlohmann::json summary_event(const std::string& run) {
  const auto all = events(run, "summary");
  return all.empty() ? nlohmann::json::object() : all.back();
}

// The summary's streams of worker `id`, one a session, in session order.
inline std::vector<nlohmann::json> streams_of(const nlohmann::json& summary, const std::string& id) {
  std::vector<nlohmann::json> out;
  for (const auto& s : summary.value("streams", nlohmann::json::array()))
    if (s.value("worker_id", "") == id) out.push_back(s);
  return out;
}

// The summary's batch counts: ok, lost, duplicate, invalid (-1 each without a summary event).
struct BatchCounts {
  long long ok = -1, lost = -1, duplicate = -1, invalid = -1;
};
inline BatchCounts batch_counts(const nlohmann::json& summary) {
  return {summary.value("batches_ok", -1LL), summary.value("batches_lost", -1LL),
          summary.value("batches_duplicate", -1LL), summary.value("batches_invalid", -1LL)};
}
// Whether the summary event counts no batch lost, duplicated or invalid (false without one).
inline bool no_batch_lost_or_refused(const nlohmann::json& summary) {
  const BatchCounts c = batch_counts(summary);
  return c.ok >= 0 && c.lost == 0 && c.duplicate == 0 && c.invalid == 0;
}

// The batches received on worker `id`'s one stream when the summary has exactly one, closed, that
// took sequence 0 on without a gap, a duplicate or an invalid batch; -1 otherwise.
inline long long closed_whole_stream(const nlohmann::json& summary, const std::string& id) {
  const auto s = streams_of(summary, id);
  if (s.size() != 1 || !s[0].value("closed", false)) return -1;
  const long long received = s[0].value("received", -1LL);
  if (s[0].value("lost", -1) != 0 || s[0].value("duplicate", -1) != 0 || s[0].value("invalid", -1) != 0 ||
      s[0].value("last_sequence", -2LL) != received - 1)
    return -1;
  return received;
}

// What is wrong with the best policy a learner kept in <run>/best, given the run's summary event:
// the folder must hold the algorithm's networks (sub-folder algo, not empty) and no buffers, and its
// manifest the best evaluation the summary reports (best_eval). "" when nothing is wrong.
inline std::string best_policy_problem(const std::string& run, const nlohmann::json& summary, const std::string& algo) {
  namespace fs = std::filesystem;
  const fs::path best = fs::path(run) / "best";
  if (!fs::is_directory(best / algo) || fs::is_empty(best / algo))
    return (best / algo).string() + " is missing or empty";
  if (fs::exists(best / "replay.pt")) return best.string() + " holds the replay buffer; it should hold networks only";
  if (!summary.contains("best_eval") || !summary["best_eval"].is_number())
    return "the summary event has no best evaluation: " + summary.dump();
  std::smatch m;
  const std::string manifest = slurp((best / "manifest.txtpb").string());
  if (!std::regex_search(manifest, m, std::regex(R"(best_eval_return: (-?[0-9.eE+-]+))")))
    return (best / "manifest.txtpb").string() + " has no best_eval_return:\n" + manifest;
  const double reported = summary["best_eval"].get<double>();
  if (std::fabs(reported - std::stod(m[1])) > 1e-3 * std::max(1.0, std::fabs(reported)))
    return "best/manifest.txtpb says " + std::string(m[1]) + ", the summary " + std::to_string(reported);
  return "";
}

// The workers the roster announced (worker events with change "joined"), by worker id, in order.
inline std::vector<std::string> workers_joined(const std::string& run) {
  std::vector<std::string> ids;
  for (const auto& e : events(run, "worker"))
    if (e.value("change", "") == "joined") ids.push_back(e.value("worker_id", ""));
  return ids;
}

inline bool joined(const std::string& run, const std::string& worker_id) {
  const auto ids = workers_joined(run);
  return std::find(ids.begin(), ids.end(), worker_id) != ids.end();
}

// Whether the roster marked worker_id dead (a worker event with change "dead").
inline bool marked_dead(const std::string& run, const std::string& worker_id) {
  for (const auto& e : events(run, "worker"))
    if (e.value("worker_id", "") == worker_id && e.value("change", "") == "dead") return true;
  return false;
}

// Polls RUN/events.jsonl until worker_id has joined; false after timeout_s.
inline bool wait_for_join(const std::string& run, const std::string& worker_id, double timeout_s) {
  return wait_until([&] { return joined(run, worker_id); }, timeout_s);
}

// Polls RUN/events.jsonl until it holds at least `count` events of `kind`; false after timeout_s.
inline bool wait_for_events(const std::string& run, const std::string& kind, size_t count, double timeout_s) {
  return wait_until([&] { return events(run, kind).size() >= count; }, timeout_s);
}

// A DDS domain of our own (offset keeps test suites apart), so parallel runs and a running farm
// do not see each other.
inline int private_domain(int offset) { return 20 + static_cast<int>((getpid() + offset) % 200); }

// A temporary directory with the processes started in it; everything is killed at the end and
// the directory removed unless the test failed (then its logs are kept and named).
class ProcessSet {
 public:
  ProcessSet() {
    char tmpl[] = "/tmp/farm-it-XXXXXX";
    if (!mkdtemp(tmpl)) throw std::runtime_error("mkdtemp failed");
    dir_ = tmpl;
  }
  ~ProcessSet() { kill_all(); }
  void kill_all() {
    for (auto& p : procs_)
      if (p.pid > 0) {
        kill(p.pid, SIGKILL);
        waitpid(p.pid, nullptr, 0);
        p.pid = -1;
      }
  }
  void cleanup(bool keep) {
    kill_all();
    if (!keep && !std::getenv("FARM_KEEP_LOGS"))
      std::filesystem::remove_all(dir_);
    else
      std::cerr << "logs kept in " << dir_ << "\n";
  }
  // Starts argv with its output in DIR/NAME.log; a farm-worker or a farm_intruder also writes its
  // events to DIR/NAME.jsonl (--events), read by worker_events and last_event.
  Proc& start(std::vector<std::string> argv, const std::string& name) {
    for (const std::string& a : argv)
      if (const auto program = std::filesystem::path(a).filename();
          program == "farm-worker" || program == "farm_intruder") {
        argv.insert(argv.end(), {"--events", dir_ + "/" + name + ".jsonl"});
        break;
      }
    procs_.push_back(spawn(argv, dir_ + "/" + name + ".log"));
    return procs_.back();
  }
  std::string log(const std::string& name) const { return slurp(dir_ + "/" + name + ".log"); }
  // The events of one kind of the worker started as NAME ("" kind: all).
  std::vector<nlohmann::json> worker_events(const std::string& name, const std::string& kind = "") const {
    return events_in(dir_ + "/" + name + ".jsonl", kind);
  }
  // The last event of one kind of the program started as NAME (a farm-worker's or a farm_intruder's
  // record: worker/worker_app.h and tests/integration/farm_intruder.cpp list their kinds); an empty
  // object when it wrote none.
  nlohmann::json last_event(const std::string& name, const std::string& kind) const {
    const auto all = worker_events(name, kind);
    return all.empty() ? nlohmann::json::object() : all.back();
  }
  // The batches the worker started as NAME sent in all, from its finished event; -1 before it.
  long long batches_sent(const std::string& name) const {
    const auto f = worker_events(name, "finished");
    return f.empty() ? -1 : f.back().value("batches_sent", -1LL);
  }
  const std::string& dir() const { return dir_; }
  std::deque<Proc>& procs() { return procs_; }

 private:
  std::string dir_;
  std::deque<Proc> procs_;  // deque: references stay valid as processes are added
};

}  // namespace farm::testing
