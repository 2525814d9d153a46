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

// What is wrong with the best policy a learner kept in <run>/best, given the run's summary: the
// folder must hold the algorithm's networks (sub-folder algo, not empty) and no buffers, and its
// manifest the best evaluation return the summary reports. "" when nothing is wrong.
inline std::string best_policy_problem(const std::string& run, const std::string& summary, const std::string& algo) {
  namespace fs = std::filesystem;
  const fs::path best = fs::path(run) / "best";
  if (!fs::is_directory(best / algo) || fs::is_empty(best / algo))
    return (best / algo).string() + " is missing or empty";
  if (fs::exists(best / "replay.pt")) return best.string() + " holds the replay buffer; it should hold networks only";
  std::smatch s, m;
  if (!std::regex_search(summary, s, std::regex(R"(best eval return\s+(-?[0-9.]+))")))
    return "the summary has no best eval return:\n" + summary;
  const std::string manifest = slurp((best / "manifest.txtpb").string());
  if (!std::regex_search(manifest, m, std::regex(R"(best_eval_return: (-?[0-9.eE+-]+))")))
    return (best / "manifest.txtpb").string() + " has no best_eval_return:\n" + manifest;
  if (std::fabs(std::stod(s[1]) - std::stod(m[1])) > 0.051)
    return "best/manifest.txtpb says " + std::string(m[1]) + ", the summary " + std::string(s[1]);
  return "";
}

// The events of one kind in RUN/events.jsonl, the learner's record for programs ("" kind: all),
// in order; a line that is not JSON is skipped.
inline std::vector<nlohmann::json> events(const std::string& run, const std::string& kind = "") {
  std::vector<nlohmann::json> out;
  std::ifstream in(run + "/events.jsonl");
  for (std::string line; std::getline(in, line);) {
    const nlohmann::json e = nlohmann::json::parse(line, nullptr, false);
    if (e.is_object() && (kind.empty() || e.value("event", "") == kind)) out.push_back(e);
  }
  return out;
}

// The first event of `kind` whose field `key` holds a text containing `part`; null when none.
inline nlohmann::json event_with(const std::string& run, const std::string& kind, const std::string& key,
                                 const std::string& part) {
  for (const auto& e : events(run, kind))
    if (e.contains(key) && e[key].is_string() && e[key].get<std::string>().find(part) != std::string::npos) return e;
  return nullptr;
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
  Proc& start(const std::vector<std::string>& argv, const std::string& name) {
    procs_.push_back(spawn(argv, dir_ + "/" + name + ".log"));
    return procs_.back();
  }
  std::string log(const std::string& name) const { return slurp(dir_ + "/" + name + ".log"); }
  const std::string& dir() const { return dir_; }
  std::deque<Proc>& procs() { return procs_; }

 private:
  std::string dir_;
  std::deque<Proc> procs_;  // deque: references stay valid as processes are added
};

}  // namespace farm::testing
