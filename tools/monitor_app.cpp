// The farm-monitor service (monitor_app.h): what it takes off the bus, the table it prints and
// the JSON lines it logs.
#include "monitor_app.h"

#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <sstream>
#include <stdexcept>

#include "meter.h"

namespace farm {

namespace {

std::string fmt(const char* f, double v) {
  if (std::isnan(v)) return "-";
  char buf[64];
  std::snprintf(buf, sizeof(buf), f, v);
  return buf;
}

std::string json_str(const std::string& s) {
  std::string o = "\"";
  for (unsigned char c : s) {
    if (c == '"' || c == '\\') {
      o += '\\';
      o += char(c);
    } else if (c == '\n')
      o += "\\n";
    else if (c == '\t')
      o += "\\t";
    else if (c < 0x20) {
      char b[8];
      std::snprintf(b, sizeof(b), "\\u%04x", c);
      o += b;
    } else
      o += char(c);
  }
  return o + "\"";
}

std::string json_num(double v) {
  if (!std::isfinite(v)) return "null";
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.6g", v);
  return buf;
}

std::string iso_now() {
  timespec ts;
  clock_gettime(CLOCK_REALTIME, &ts);
  tm t;
  gmtime_r(&ts.tv_sec, &t);
  char buf[64];
  std::strftime(buf, sizeof(buf), "%Y-%m-%dT%H:%M:%S", &t);
  char ms[24];
  std::snprintf(ms, sizeof(ms), ".%03ldZ", ts.tv_nsec / 1000000);
  return std::string(buf) + ms;
}

// Seconds since 1970 with milliseconds, for plotting logs from several runs on one axis.
std::string unix_time() {
  timespec ts;
  clock_gettime(CLOCK_REALTIME, &ts);
  char buf[48];
  std::snprintf(buf, sizeof(buf), "%lld.%03ld", static_cast<long long>(ts.tv_sec), ts.tv_nsec / 1000000);
  return buf;
}

}  // namespace

MonitorApp::MonitorApp(const MonitorOptions& o, const std::atomic<bool>& stop)
    : opt_(o),
      stop_(stop),
      bus_(o.bus, "farm-monitor " + farm::dds::hostname() + "-" + std::to_string(getpid())),
      status_in_(bus_, farm::dds::kWorkerStatusTopic, "status_reader"),
      stats_in_(bus_, farm::dds::kLearnerStatsTopic, "status_reader"),
      t0_(farm::now_seconds()) {
  if (!opt_.log_file.empty()) {
    log_.open(opt_.log_file, std::ios::app);
    if (!log_) throw std::runtime_error("cannot append to --log file " + opt_.log_file);
  }
}

int MonitorApp::run() {
  if (opt_.once) return run_once();
  const bool tty = isatty(STDOUT_FILENO);
  double next = farm::now_seconds();
  while (!stop_) {
    drain();
    const double now = farm::now_seconds();
    if (now >= next) {
      std::string table = render(now);
      if (tty)
        std::fputs("\033[H\033[2J", stdout);  // home, clear: the table refreshes in place
      else
        std::fputs("\n", stdout);
      std::fputs(table.c_str(), stdout);
      std::fflush(stdout);
      write_log(now);
      next += opt_.interval;
      if (next < now) next = now + opt_.interval;
    }
    status_in_.wait(std::min(0.2, std::max(0.01, next - farm::now_seconds())));
  }
  return 0;
}

int MonitorApp::run_once() {
  const double deadline = t0_ + opt_.wait;
  double first = -1;
  while (!stop_ && farm::now_seconds() < deadline) {
    drain();
    if (first < 0 && (!workers_.empty() || !learners_.empty())) first = farm::now_seconds();
    // One heartbeat round (every worker beats once a second), and a heartbeat from every status
    // writer discovered so far: participants are matched one by one, not all at once.
    if (first >= 0 && farm::now_seconds() - first >= 1.5 && int(heard_.size()) >= status_in_.matched()) break;
    status_in_.wait(0.1);
  }
  drain();
  const double now = farm::now_seconds();
  if (workers_.empty() && learners_.empty()) {
    std::fprintf(stderr,
                 "farm-monitor: nothing found on DDS domain %d within %.1f s: no WorkerStatus or LearnerStats%s "
                 "(check --domain, --dds-profiles %s and, with a discovery server, ROS_DISCOVERY_SERVER)\n",
                 bus_.domain(), opt_.wait,
                 opt_.experiment.empty() ? "" : (" of experiment '" + opt_.experiment + "'").c_str(),
                 bus_.profiles_file().c_str());
    write_log(now);
    return 1;
  }
  std::fputs(render(now).c_str(), stdout);
  std::fflush(stdout);
  write_log(now);
  return 0;
}

bool MonitorApp::wanted(const std::string& experiment) const {
  return opt_.experiment.empty() || experiment == opt_.experiment;
}

void MonitorApp::drain() {
  const double now = farm::now_seconds();
  farm::msg::WorkerStatus s;
  while (status_in_.take(s)) {
    heard_.insert(key(s));
    if (!wanted(s.experiment_id())) continue;
    // A restarted worker (same id, new session) replaces its earlier session.
    for (auto it = workers_.begin(); it != workers_.end();) {
      if (it->second.last.worker_id() == s.worker_id() && it->second.last.worker_session() != s.worker_session())
        it = workers_.erase(it);
      else
        ++it;
    }
    WorkerView& v = workers_[key(s)];
    if (v.first_seen == 0) v.first_seen = now;
    v.last = s;
    v.seen = now;
    v.history.emplace_back(now, s.env_steps());
    while (v.history.size() > 2 && now - v.history.front().first > 5.0) v.history.pop_front();
  }
  farm::msg::LearnerStats l;
  while (stats_in_.take(l)) {
    if (!wanted(l.experiment_id())) continue;
    LearnerView& v = learners_[l.experiment_id()];
    v.last = l;
    v.seen = now;
    latest_learner_ = l.experiment_id();
  }
  for (auto it = workers_.begin(); it != workers_.end();) {
    if (now - it->second.seen > opt_.timeout + opt_.forget)
      it = workers_.erase(it);
    else
      ++it;
  }
}

std::string MonitorApp::key(const farm::msg::WorkerStatus& s) {
  return s.worker_id() + "#" + std::to_string(s.worker_session());
}

bool MonitorApp::dead(const WorkerView& v, double now) const { return now - v.seen > opt_.timeout; }

// What the table and the log call the worker's state: its own, or dead when silent.
std::string MonitorApp::state(const WorkerView& v, double now) const { return dead(v, now) ? "dead" : v.last.state(); }

// Counts toward the totals: alive and not finished.
bool MonitorApp::live(const WorkerView& v, double now) const { return !dead(v, now) && v.last.state() != "finished"; }

double MonitorApp::rate(const WorkerView& v, double now) const {
  if (dead(v, now)) return 0.0;
  if (v.history.size() >= 2) {
    const auto& a = v.history.front();
    const auto& b = v.history.back();
    if (b.first - a.first >= 0.5 && b.second >= a.second) return double(b.second - a.second) / (b.first - a.first);
  }
  return v.last.steps_per_second();
}

MonitorApp::Totals MonitorApp::totals(double now) const {
  Totals t;
  for (auto& [k, v] : workers_) {
    if (dead(v, now)) {
      ++t.dead;
      continue;
    }
    if (v.last.state() == "finished") {
      ++t.finished;
      continue;
    }
    ++t.live;
    t.envs += v.last.envs();
    t.env_steps += v.last.env_steps();
    t.batches += v.last.batches_sent();
    t.steps_per_second += rate(v, now);
  }
  return t;
}

std::vector<const MonitorApp::WorkerView*> MonitorApp::sorted() const {
  std::vector<const WorkerView*> out;
  for (auto& [k, v] : workers_) out.push_back(&v);
  std::sort(out.begin(), out.end(), [](const WorkerView* a, const WorkerView* b) {
    if (a->last.host() != b->last.host()) return a->last.host() < b->last.host();
    return a->last.worker_id() < b->last.worker_id();
  });
  return out;
}

std::string MonitorApp::render(double now) const {
  std::ostringstream o;
  char line[512];
  o << "farm-monitor  domain " << bus_.domain() << (opt_.experiment.empty() ? "" : "  experiment " + opt_.experiment)
    << "  " << iso_now() << "  (dead after " << fmt("%.0f", opt_.timeout) << " s silent)\n\n";
  std::snprintf(line, sizeof(line), "%-16s %-20s %6s %10s %9s %7s %-20s %6s\n", "HOST", "WORKER", "ENVS", "STEPS/S",
                "BATCHES", "POLICY", "STATE", "AGE");
  o << line;
  for (const WorkerView* v : sorted()) {
    std::string st = state(*v, now);
    if (!dead(*v, now) && !v->last.last_error().empty()) st += " (" + v->last.last_error() + ")";
    std::snprintf(line, sizeof(line), "%-16s %-20s %6u %10.0f %9llu %7s %-20s %5.1fs\n", v->last.host().c_str(),
                  v->last.worker_id().c_str(), v->last.envs(), rate(*v, now),
                  static_cast<unsigned long long>(v->last.batches_sent()),
                  ("v" + std::to_string(v->last.policy_version())).c_str(), st.c_str(), now - v->seen);
    o << line;
  }
  if (workers_.empty()) o << "(no worker heartbeats yet)\n";
  Totals t = totals(now);
  std::snprintf(line, sizeof(line), "%-16s %-20s %6llu %10.0f %9llu\n", "TOTAL",
                (std::to_string(t.live) + " live, " + std::to_string(t.dead) + " dead" +
                 (t.finished ? ", " + std::to_string(t.finished) + " done" : ""))
                    .c_str(),
                static_cast<unsigned long long>(t.envs), t.steps_per_second,
                static_cast<unsigned long long>(t.batches));
  o << line << "\n";
  const LearnerView* l = learner();
  if (!l) {
    o << "learner: no LearnerStats yet\n";
  } else {
    const auto& s = l->last;
    o << "learner  experiment " << s.experiment_id() << ", " << fmt("%.0f", s.elapsed_seconds()) << " s, last stats "
      << fmt("%.1f", now - l->seen) << " s ago, " << s.workers() << " live workers\n"
      << "  ingest   " << fmt("%.0f", s.env_steps_per_second()) << " steps/s (" << s.env_steps() << " env steps)\n"
      << "  updates  " << fmt("%.0f", s.updates_per_second()) << " upd/s (" << s.updates() << ")\n"
      << "  buffer   " << fmt("%.1f", 100.0 * s.buffer_fill()) << "%   policy lag " << fmt("%.1f", s.policy_lag())
      << "\n"
      << "  losses   critic " << fmt("%.4g", s.critic_loss()) << "   actor " << fmt("%.4g", s.actor_loss()) << "\n"
      << "  return   mean " << fmt("%.1f", s.mean_return()) << "   eval " << fmt("%.1f", s.eval_return()) << "\n"
      << "  batches  ok " << s.batches_ok() << ", lost " << s.batches_lost() << ", duplicate " << s.batches_duplicate()
      << ", invalid " << s.batches_invalid() << "\n";
  }
  return o.str();
}

const MonitorApp::LearnerView* MonitorApp::learner() const {
  auto it = learners_.find(latest_learner_);
  return it == learners_.end() ? nullptr : &it->second;
}

void MonitorApp::write_log(double now) {
  if (!log_.is_open()) return;
  std::ostringstream o;
  o << "{\"time\":" << json_str(iso_now()) << ",\"unix_time\":" << unix_time()
    << ",\"elapsed_s\":" << json_num(now - t0_) << ",\"domain\":" << bus_.domain() << ",\"workers\":[";
  bool first = true;
  for (const WorkerView* v : sorted()) {
    const auto& s = v->last;
    o << (first ? "" : ",") << "{\"id\":" << json_str(s.worker_id()) << ",\"session\":" << s.worker_session()
      << ",\"host\":" << json_str(s.host()) << ",\"experiment\":" << json_str(s.experiment_id())
      << ",\"envs\":" << s.envs() << ",\"threads\":" << s.threads() << ",\"steps_per_s\":" << json_num(rate(*v, now))
      << ",\"env_steps\":" << s.env_steps() << ",\"batches_sent\":" << s.batches_sent()
      << ",\"policy_version\":" << s.policy_version() << ",\"state\":" << json_str(state(*v, now))
      << ",\"alive\":" << (dead(*v, now) ? "false" : "true") << ",\"age_s\":" << json_num(now - v->seen)
      << ",\"last_error\":" << json_str(s.last_error()) << "}";
    first = false;
  }
  o << "],\"learner\":";
  if (const LearnerView* l = learner()) {
    const auto& s = l->last;
    o << "{\"experiment\":" << json_str(s.experiment_id()) << ",\"age_s\":" << json_num(now - l->seen)
      << ",\"elapsed_s\":" << json_num(s.elapsed_seconds()) << ",\"env_steps\":" << s.env_steps()
      << ",\"env_steps_per_s\":" << json_num(s.env_steps_per_second()) << ",\"updates\":" << s.updates()
      << ",\"updates_per_s\":" << json_num(s.updates_per_second()) << ",\"buffer_fill\":" << json_num(s.buffer_fill())
      << ",\"policy_lag\":" << json_num(s.policy_lag()) << ",\"critic_loss\":" << json_num(s.critic_loss())
      << ",\"actor_loss\":" << json_num(s.actor_loss()) << ",\"mean_return\":" << json_num(s.mean_return())
      << ",\"eval_return\":" << json_num(s.eval_return()) << ",\"batches_ok\":" << s.batches_ok()
      << ",\"batches_lost\":" << s.batches_lost() << ",\"batches_duplicate\":" << s.batches_duplicate()
      << ",\"batches_invalid\":" << s.batches_invalid() << ",\"workers\":" << s.workers() << "}";
  } else {
    o << "null";
  }
  Totals t = totals(now);
  o << ",\"totals\":{\"live\":" << t.live << ",\"dead\":" << t.dead << ",\"finished\":" << t.finished
    << ",\"envs\":" << t.envs << ",\"steps_per_s\":" << json_num(t.steps_per_second) << ",\"env_steps\":" << t.env_steps
    << ",\"batches_sent\":" << t.batches << "}}\n";
  log_ << o.str();
  log_.flush();
}

}  // namespace farm
