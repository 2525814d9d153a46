// The table and the JSON log line of farm-monitor (monitor_snapshot.h), written from one snapshot.
#include "monitor_snapshot.h"

#include <time.h>

#include <cmath>
#include <cstdio>
#include <ctime>
#include <sstream>

#include "printable.h"

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
// A typed field's JSON value: a count as a whole number, a real as json_num.
std::string json_value(double v) { return json_num(v); }
std::string json_value(uint64_t v) { return std::to_string(v); }
std::string json_value(uint32_t v) { return std::to_string(v); }

// 2026-11-23T09:53:45.737Z
std::string iso_time(int64_t unix_ms) {
  time_t sec = time_t(unix_ms / 1000);
  tm t;
  gmtime_r(&sec, &t);
  char buf[64];
  std::strftime(buf, sizeof(buf), "%Y-%m-%dT%H:%M:%S", &t);
  char ms[24];
  std::snprintf(ms, sizeof(ms), ".%03dZ", int(unix_ms % 1000));
  return std::string(buf) + ms;
}

// Seconds since 1970 with milliseconds, for plotting logs from several runs on one axis.
std::string unix_time(int64_t unix_ms) {
  char buf[48];
  std::snprintf(buf, sizeof(buf), "%lld.%03d", static_cast<long long>(unix_ms / 1000), int(unix_ms % 1000));
  return buf;
}

}  // namespace

std::string render_table(const MonitorSnapshot& s) {
  std::ostringstream o;
  char line[512];
  o << "farm-monitor  domain " << s.domain << (s.experiment.empty() ? "" : "  experiment " + s.experiment) << "  "
    << iso_time(s.unix_ms) << "  (dead after " << fmt("%.0f", s.timeout) << " s silent)\n\n";
  std::snprintf(line, sizeof(line), "%-16s %-20s %6s %10s %9s %7s %-20s %6s\n", "HOST", "WORKER", "ENVS", "STEPS/S",
                "BATCHES", "POLICY", "STATE", "AGE");
  o << line;
  for (const WorkerRow& w : s.workers) {
    // Hosts, ids, states and errors come from heartbeats: escaped and cut (printable.h), so no
    // escape sequence reaches the operator's terminal.
    std::string st = printable(w.state, 40);
    if (w.alive && !w.last_error.empty()) st += " (" + printable(w.last_error, 200) + ")";
    std::snprintf(line, sizeof(line), "%-16s %-20s %6u %10.0f %9llu %7s %-20s %5.1fs\n", printable(w.host, 64).c_str(),
                  printable(w.id, 64).c_str(), w.envs, w.steps_per_second,
                  static_cast<unsigned long long>(w.batches_sent), ("v" + std::to_string(w.policy_version)).c_str(),
                  st.c_str(), w.age_s);
    o << line;
  }
  if (s.workers.empty()) o << "(no worker heartbeats yet)\n";
  const WorkerTotals& t = s.totals;
  std::snprintf(line, sizeof(line), "%-16s %-20s %6llu %10.0f %9llu\n", "TOTAL",
                (std::to_string(t.live) + " live, " + std::to_string(t.dead) + " dead" +
                 (t.finished ? ", " + std::to_string(t.finished) + " done" : ""))
                    .c_str(),
                static_cast<unsigned long long>(t.envs), t.steps_per_second,
                static_cast<unsigned long long>(t.batches));
  o << line << "\n";
  if (s.latest_learner < 0) {
    o << "learner: no LearnerStats yet\n";
  } else {
    const LearnerRow& l = s.learners[s.latest_learner];
    o << "learner  experiment " << printable(l.experiment, 64) << ", " << fmt("%.0f", l.elapsed_seconds)
      << " s, last stats " << fmt("%.1f", l.age_s) << " s ago, " << l.workers << " live workers\n"
      << "  ingest   " << fmt("%.0f", l.env_steps_per_second) << " steps/s (" << l.env_steps << " env steps)\n"
      << "  updates  " << fmt("%.0f", l.updates_per_second) << " upd/s (" << l.updates << ")\n"
      << "  buffer   " << fmt("%.1f", 100.0 * l.buffer_fill) << "%   policy lag " << fmt("%.1f", l.policy_lag) << "\n"
      << "  losses   critic " << fmt("%.4g", l.critic_loss) << "   actor " << fmt("%.4g", l.actor_loss) << "\n"
      << "  return   mean " << fmt("%.1f", l.mean_return) << "   eval " << fmt("%.1f", l.eval_return) << "\n"
      << "  batches  ok " << l.batches_ok << ", lost " << l.batches_lost << ", duplicate " << l.batches_duplicate
      << ", invalid " << l.batches_invalid << "\n";
  }
  return o.str();
}

std::string render_json_line(const MonitorSnapshot& s) {
  std::ostringstream o;
  o << "{\"time\":" << json_str(iso_time(s.unix_ms)) << ",\"unix_time\":" << unix_time(s.unix_ms)
    << ",\"elapsed_s\":" << json_num(s.elapsed_s) << ",\"domain\":" << s.domain << ",\"workers\":[";
  bool first = true;
  for (const WorkerRow& w : s.workers) {
    o << (first ? "" : ",") << "{\"id\":" << json_str(w.id) << ",\"session\":" << w.session
      << ",\"host\":" << json_str(w.host) << ",\"experiment\":" << json_str(w.experiment) << ",\"envs\":" << w.envs
      << ",\"threads\":" << w.threads << ",\"steps_per_s\":" << json_num(w.steps_per_second)
      << ",\"env_steps\":" << w.env_steps << ",\"batches_sent\":" << w.batches_sent
      << ",\"policy_version\":" << w.policy_version << ",\"state\":" << json_str(w.state)
      << ",\"alive\":" << (w.alive ? "true" : "false") << ",\"age_s\":" << json_num(w.age_s)
      << ",\"last_error\":" << json_str(w.last_error) << "}";
    first = false;
  }
  o << "],\"learner\":";
  if (s.latest_learner >= 0) {
    const LearnerRow& l = s.learners[s.latest_learner];
    o << "{\"experiment\":" << json_str(l.experiment) << ",\"age_s\":" << json_num(l.age_s);
#define FARM_JSON(name, member, type) o << ",\"" #name "\":" << json_value(l.member);
    FARM_LEARNER_STATS_FIELDS(FARM_JSON)
#undef FARM_JSON
    o << "}";
  } else {
    o << "null";
  }
  const WorkerTotals& t = s.totals;
  o << ",\"totals\":{\"live\":" << t.live << ",\"dead\":" << t.dead << ",\"finished\":" << t.finished
    << ",\"envs\":" << t.envs << ",\"steps_per_s\":" << json_num(t.steps_per_second) << ",\"env_steps\":" << t.env_steps
    << ",\"batches_sent\":" << t.batches << "}}\n";
  return o.str();
}

}  // namespace farm
