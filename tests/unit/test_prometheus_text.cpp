// farm-monitor's Prometheus metrics (tools/prometheus_text.h) from snapshots: every family has its
// HELP and TYPE before its samples, the values are the snapshot's, counters end in _total, series
// of workers and learners that leave the snapshot leave the page, label values from the bus are
// bounded, valid UTF-8 and escaped on the page, and workers whose bounded labels repeat another's
// are left out and counted. Where promtool (Debian's prometheus package) is installed, it must
// accept the page.
#include <gtest/gtest.h>

#include <unistd.h>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "learner_stats_fields.h"
#include "monitor_snapshot.h"
#include "prometheus_text.h"

namespace {

farm::MonitorSnapshot sample_snapshot() {
  farm::MonitorSnapshot s;
  s.unix_ms = 1764115200123;
  s.domain = 7;
  s.timeout = 4;
  farm::WorkerRow a;
  a.id = "host-b";
  a.host = "vm";
  a.experiment = "pendulum_sac";
  a.envs = 8;
  a.threads = 1;
  a.steps_per_second = 70777.5;
  a.env_steps = 12345678901ull;
  a.batches_sent = 1664;
  a.policy_version = 87;
  a.state = "running";
  a.alive = true;
  a.age_s = 0.5;
  farm::WorkerRow b = a;
  b.id = "host-c";
  b.steps_per_second = 0;
  b.state = "dead";
  b.alive = false;
  b.age_s = 9.25;
  s.workers = {a, b};
  s.totals.live = 1;
  s.totals.dead = 1;
  s.totals.envs = 8;
  s.totals.env_steps = a.env_steps;
  s.totals.batches = a.batches_sent;
  s.totals.steps_per_second = a.steps_per_second;
  farm::LearnerRow l;
  l.experiment = "pendulum_sac";
  l.env_steps = 816600;
  l.updates = 3264;
  l.buffer_fill = 0.817;
  l.mean_return = -176;
  l.eval_return = NAN;  // no evaluation yet
  l.batches_ok = 3565;
  l.batches_lost = 2;
  l.batches_duplicate = 1;
  l.batches_invalid = 4;
  l.workers = 2;
  l.stats = {{"update_to_data", "updates/step", 0.25}, {"env_steps", "steps", 816600}, {"eval_return", "", NAN}};
  s.learners = {l};
  s.latest_learner = 0;
  return s;
}

using Labels = std::map<std::string, std::string>;

struct Page {
  std::map<std::string, std::string> type, help;               // by family
  std::map<std::string, std::map<Labels, std::string>> value;  // by family, then label set
  std::vector<std::string> order;                              // families in the order of their TYPE lines
  std::string problem;                                         // first structural fault found
};

// One sample line: name, label set (escapes undone) and value; false when it is not one.
bool parse_sample(const std::string& line, std::string& name, Labels& labels, std::string& value) {
  size_t i = line.find_first_of("{ ");
  if (i == std::string::npos) return false;
  name = line.substr(0, i);
  if (line[i] == '{') {
    ++i;
    while (i < line.size() && line[i] != '}') {
      const size_t eq = line.find("=\"", i);
      if (eq == std::string::npos) return false;
      const std::string key = line.substr(i, eq - i);
      std::string v;
      for (i = eq + 2; i < line.size() && line[i] != '"'; ++i) {
        if (line[i] != '\\') {
          v += line[i];
          continue;
        }
        if (++i == line.size()) return false;
        if (line[i] == 'n')
          v += '\n';
        else if (line[i] == '\\' || line[i] == '"')
          v += line[i];
        else
          return false;  // the text format knows no other escape
      }
      if (i == line.size() || labels.count(key)) return false;
      labels[key] = v;
      ++i;
      if (i < line.size() && line[i] == ',') ++i;
    }
    if (i == line.size()) return false;
    ++i;
  }
  if (i >= line.size() || line[i] != ' ') return false;
  value = line.substr(i + 1);
  return !value.empty() && value.find(' ') == std::string::npos;
}

// Reads the page the way the text format is defined: a family's HELP and TYPE, then its samples.
Page parse(const std::string& text) {
  Page p;
  std::istringstream in(text);
  std::string line, current;
  while (std::getline(in, line)) {
    if (line.rfind("# HELP ", 0) == 0) {
      std::string name = line.substr(7, line.find(' ', 7) - 7);
      p.help[name] = line.substr(8 + name.size());
      current = name;
    } else if (line.rfind("# TYPE ", 0) == 0) {
      std::string name = line.substr(7, line.find(' ', 7) - 7);
      if (name != current && p.problem.empty()) p.problem = "TYPE of " + name + " without its HELP first";
      if (p.type.count(name) && p.problem.empty()) p.problem = "family " + name + " twice";
      p.type[name] = line.substr(8 + name.size());
      p.order.push_back(name);
    } else if (!line.empty()) {
      std::string name, value;
      Labels labels;
      if (!parse_sample(line, name, labels, value)) {
        if (p.problem.empty()) p.problem = "not a sample: " + line;
        continue;
      }
      if (name != current && p.problem.empty()) p.problem = "sample " + line + " outside its family";
      if (p.value[name].count(labels) && p.problem.empty()) p.problem = "series " + line + " twice";
      p.value[name][labels] = value;
    }
  }
  return p;
}

const Labels kWorkerA = {{"worker", "host-b"}, {"host", "vm"}, {"experiment", "pendulum_sac"}};
const Labels kWorkerC = {{"worker", "host-c"}, {"host", "vm"}, {"experiment", "pendulum_sac"}};
const Labels kLearner = {{"experiment", "pendulum_sac"}};

Labels with(Labels l, const std::string& key, const std::string& value) {
  l[key] = value;
  return l;
}

// The sample's value as written, or "(absent)".
std::string at(const Page& p, const std::string& name, const Labels& labels = {}) {
  auto f = p.value.find(name);
  if (f == p.value.end()) return "(absent)";
  auto it = f->second.find(labels);
  return it == f->second.end() ? "(absent)" : it->second;
}

// The sample's value as a number (NaN when absent).
double num(const Page& p, const std::string& name, const Labels& labels = {}) {
  const std::string v = at(p, name, labels);
  return v == "(absent)" ? NAN : std::strtod(v.c_str(), nullptr);
}

}  // namespace

TEST(PrometheusText, FamiliesHaveHelpAndTypeAndCountersEndInTotal) {
  Page p = parse(farm::render_prometheus(sample_snapshot()));
  EXPECT_EQ(p.problem, "");
  ASSERT_GE(p.order.size(), 30u);
  for (const std::string& name : p.order) {
    EXPECT_EQ(name.rfind("farm_", 0), 0u) << name;
    EXPECT_FALSE(p.help[name].empty()) << name;
    const std::string& t = p.type[name];
    EXPECT_TRUE(t == "gauge" || t == "counter") << name << ": " << t;
    const bool total = name.size() > 6 && name.compare(name.size() - 6, 6, "_total") == 0;
    EXPECT_EQ(t == "counter", total) << name << " is a " << t;
  }
  EXPECT_EQ(p.type["farm_learner_eval_return"], "gauge") << "a family without a sample keeps its HELP and TYPE";
  EXPECT_EQ(p.type["farm_learner_batches_total"], "counter");
  EXPECT_EQ(p.help["farm_worker_up"], "1 while the worker's heartbeats arrive, 0 once it is silent past the timeout.");
}

TEST(PrometheusText, ValuesAreTheSnapshots) {
  const farm::MonitorSnapshot s = sample_snapshot();
  Page p = parse(farm::render_prometheus(s));
  EXPECT_EQ(p.problem, "");
  EXPECT_DOUBLE_EQ(num(p, "farm_monitor_snapshot_timestamp_seconds"), 1764115200.123);
  EXPECT_EQ(at(p, "farm_monitor_worker_timeout_seconds"), "4");
  EXPECT_EQ(at(p, "farm_worker_env_steps_per_second", kWorkerA), "70777.5");
  EXPECT_EQ(at(p, "farm_worker_env_steps_total", kWorkerA), "12345678901");  // integers as integers
  EXPECT_EQ(at(p, "farm_worker_batches_sent_total", kWorkerA), "1664");
  EXPECT_EQ(at(p, "farm_worker_policy_version", kWorkerA), "87");
  EXPECT_EQ(at(p, "farm_worker_envs", kWorkerA), "8");
  EXPECT_EQ(at(p, "farm_worker_up", kWorkerA), "1");
  EXPECT_EQ(at(p, "farm_worker_up", kWorkerC), "0");
  EXPECT_EQ(at(p, "farm_worker_env_steps_per_second", kWorkerC), "0");
  EXPECT_EQ(at(p, "farm_worker_last_heartbeat_age_seconds", kWorkerC), "9.25");
  // One state series per known state, exactly one of them 1.
  for (const Labels& w : {kWorkerA, kWorkerC}) {
    int on = 0, series = 0;
    for (const std::string& st : farm::prometheus_worker_states()) {
      on += at(p, "farm_worker_state", with(w, "state", st)) == "1";
      series += at(p, "farm_worker_state", with(w, "state", st)) != "(absent)";
    }
    EXPECT_EQ(on, 1) << w.at("worker");
    EXPECT_EQ(series, int(farm::prometheus_worker_states().size())) << w.at("worker");
  }
  EXPECT_EQ(at(p, "farm_worker_state", with(kWorkerA, "state", "running")), "1");
  EXPECT_EQ(at(p, "farm_worker_state", with(kWorkerC, "state", "dead")), "1");
  EXPECT_EQ(at(p, "farm_workers", {{"status", "live"}}), "1");
  EXPECT_EQ(at(p, "farm_workers", {{"status", "dead"}}), "1");
  EXPECT_EQ(at(p, "farm_workers", {{"status", "finished"}}), "0");
  EXPECT_EQ(at(p, "farm_total_env_steps_per_second"), "70777.5");
  EXPECT_EQ(at(p, "farm_total_batches_sent"), "1664");
  EXPECT_EQ(at(p, "farm_learner_env_steps_total", kLearner), "816600");
  EXPECT_DOUBLE_EQ(num(p, "farm_learner_buffer_fill_ratio", kLearner), 0.817);
  EXPECT_EQ(at(p, "farm_learner_mean_return", kLearner), "-176");
  EXPECT_EQ(at(p, "farm_learner_eval_return", kLearner), "(absent)") << "no evaluation yet: no sample, not NaN";
  EXPECT_EQ(at(p, "farm_learner_batches_total", with(kLearner, "result", "ok")), "3565");
  EXPECT_EQ(at(p, "farm_learner_batches_total", with(kLearner, "result", "lost")), "2");
  EXPECT_EQ(at(p, "farm_learner_batches_total", with(kLearner, "result", "duplicate")), "1");
  EXPECT_EQ(at(p, "farm_learner_batches_total", with(kLearner, "result", "invalid")), "4");
  EXPECT_EQ(at(p, "farm_learner_workers", kLearner), "2");
  EXPECT_EQ(at(p, "farm_monitor_workers_not_exported"), "0");
  // Every field of the learner's statistics record, by its name and unit; one without a value has
  // no sample.
  const auto stat = [&](const std::string& name, const std::string& unit) {
    return at(p, "farm_learner_stat", with(with(kLearner, "name", name), "unit", unit));
  };
  EXPECT_EQ(stat("update_to_data", "updates/step"), "0.25");
  EXPECT_EQ(stat("env_steps", "steps"), "816600");
  EXPECT_EQ(stat("eval_return", ""), "(absent)");
}

TEST(PrometheusText, AStateItDoesNotKnowIsOther) {
  farm::MonitorSnapshot s = sample_snapshot();
  s.workers[0].state = "dancing";
  Page p = parse(farm::render_prometheus(s));
  EXPECT_EQ(at(p, "farm_worker_state", with(kWorkerA, "state", "other")), "1");
  EXPECT_EQ(at(p, "farm_worker_state", with(kWorkerA, "state", "dancing")), "(absent)");
}

// One registry over several snapshots, as farm-monitor keeps it: a worker or learner that leaves
// the snapshot leaves every family; a value that becomes NaN leaves its family; a counter that
// starts over (a new session) shows the new count.
TEST(PrometheusText, SeriesFollowTheSnapshotsOfOneRegistry) {
  farm::PrometheusMetrics m;
  farm::MonitorSnapshot s = sample_snapshot();
  s.learners[0].eval_return = -150.5;
  m.update(s);
  Page p = parse(m.page());
  EXPECT_EQ(at(p, "farm_worker_up", kWorkerC), "0");
  EXPECT_EQ(at(p, "farm_learner_eval_return", kLearner), "-150.5");

  s.workers.pop_back();         // host-c is forgotten
  s.workers[0].env_steps = 10;  // host-b restarted: a new session counts from 0
  s.learners[0].eval_return = NAN;
  m.update(s);
  p = parse(m.page());
  EXPECT_EQ(p.problem, "");
  for (const auto& [family, series] : p.value)
    for (const auto& [labels, value] : series)
      EXPECT_FALSE(labels.count("worker") && labels.at("worker") == "host-c") << family << " still has host-c";
  EXPECT_EQ(at(p, "farm_worker_up", kWorkerA), "1");
  EXPECT_EQ(at(p, "farm_worker_env_steps_total", kWorkerA), "10");
  EXPECT_EQ(at(p, "farm_learner_eval_return", kLearner), "(absent)");
  EXPECT_EQ(p.type["farm_learner_eval_return"], "gauge");

  s.workers.clear();
  s.learners.clear();
  m.update(s);
  p = parse(m.page());
  EXPECT_EQ(p.problem, "");
  for (const auto& [family, series] : p.value)
    for (const auto& [labels, value] : series)
      EXPECT_FALSE(labels.count("worker") || labels.count("experiment")) << family << " keeps a series of a gone "
                                                                         << "worker or learner";
  EXPECT_EQ(p.type["farm_worker_up"], "gauge") << "an empty family keeps its HELP and TYPE";
  EXPECT_EQ(at(p, "farm_monitor_workers_not_exported"), "0");
}

TEST(PrometheusText, LabelValuesAreBoundedAndValidUtf8) {
  EXPECT_EQ(farm::prometheus_label_value("a\"b\\c\nd", 64), "a\"b\\c\nd") << "the serializer escapes these";
  EXPECT_EQ(farm::prometheus_label_value("x\xff y\x01", 64), "x\xEF\xBF\xBD y\xEF\xBF\xBD");
  EXPECT_EQ(farm::prometheus_label_value("\xC0\xAF", 64), "\xEF\xBF\xBD\xEF\xBF\xBD") << "an overlong '/'";
  EXPECT_EQ(farm::prometheus_label_value("\xED\xA0\x80", 64), "\xEF\xBF\xBD\xEF\xBF\xBD\xEF\xBF\xBD") << "a surrogate";
  EXPECT_EQ(farm::prometheus_label_value("h\xC3\xA9llo", 64), "h\xC3\xA9llo");
  // Cut at the bound, never inside a character: 'é' is two bytes and does not fit after "abc" in 4.
  EXPECT_EQ(farm::prometheus_label_value("abc\xC3\xA9", 4), "abc");
  EXPECT_EQ(farm::prometheus_label_value(std::string(100000, 'w'), 128), std::string(128, 'w'));
}

// Quotes, backslashes and line feeds in labels from the bus are escaped on the page, so a worker id
// cannot end its label, start a line or add a series; read back, the label is the id itself.
TEST(PrometheusText, LabelValuesAreEscapedOnThePage) {
  farm::MonitorSnapshot s = sample_snapshot();
  s.workers[1].id = "evil\"} farm_worker_up 1\n# TYPE x counter\\";
  const std::string page = farm::render_prometheus(s);
  EXPECT_NE(page.find("worker=\"evil\\\"} farm_worker_up 1\\n# TYPE x counter\\\\\""), std::string::npos) << page;
  EXPECT_EQ(page.find("\n# TYPE x counter"), std::string::npos) << page;
  Page p = parse(page);
  EXPECT_EQ(p.problem, "");
  EXPECT_EQ(p.type.count("x"), 0u);
  EXPECT_EQ(at(p, "farm_worker_up", with(kWorkerC, "worker", s.workers[1].id)), "0");
  EXPECT_EQ(at(p, "farm_worker_up", kWorkerA), "1");
}

TEST(PrometheusText, WorkersWhoseBoundedLabelsRepeatAreLeftOutAndCounted) {
  farm::MonitorSnapshot s = sample_snapshot();
  farm::WorkerRow w = s.workers[0];
  w.id = std::string(200, 'z') + "-1";
  s.workers.push_back(w);
  w.id = std::string(200, 'z') + "-2";  // the same as the one before once cut at 128 bytes
  s.workers.push_back(w);
  Page p = parse(farm::render_prometheus(s));
  EXPECT_EQ(p.problem, "") << "a repeated series would make Prometheus refuse the whole scrape";
  EXPECT_EQ(at(p, "farm_monitor_workers_not_exported"), "1");
  EXPECT_EQ(at(p, "farm_worker_up", with(kWorkerA, "worker", std::string(128, 'z'))), "1");

  farm::PrometheusLimits limits;
  limits.max_workers = 1;
  p = parse(farm::render_prometheus(s, limits));
  EXPECT_EQ(at(p, "farm_monitor_workers_not_exported"), "3");
  EXPECT_EQ(at(p, "farm_worker_up", kWorkerA), "1");
  EXPECT_EQ(at(p, "farm_worker_up", kWorkerC), "(absent)");
}

// promtool, Prometheus's own checker, reads the page (hostile labels included) as valid.
TEST(PrometheusText, PromtoolAcceptsThePage) {
  if (std::system("command -v promtool >/dev/null 2>&1") != 0) GTEST_SKIP() << "promtool not installed";
  farm::MonitorSnapshot s = sample_snapshot();
  s.workers[1].id = "evil\"} farm_worker_up 1\n# TYPE x counter\n\xff";
  s.workers[1].host = std::string(300, '\\');
  char path[] = "/tmp/farm-prometheus-text-XXXXXX";
  const int fd = mkstemp(path);
  ASSERT_GE(fd, 0);
  const std::string page = farm::render_prometheus(s);
  ASSERT_EQ(write(fd, page.data(), page.size()), ssize_t(page.size()));
  close(fd);
  const std::string cmd = std::string("promtool check metrics < ") + path + " 2>&1";
  FILE* f = popen(cmd.c_str(), "r");
  ASSERT_NE(f, nullptr);
  std::string out;
  char buf[512];
  while (fgets(buf, sizeof(buf), f)) out += buf;
  const int rc = pclose(f);
  unlink(path);
  EXPECT_EQ(rc, 0) << out;
  EXPECT_EQ(out, "") << "promtool's lint found something";
}

namespace {

// farm-monitor's table (render_table): hosts, ids, states and errors from heartbeats reach the
// operator's terminal escaped, so no escape sequence (ESC, BEL, the 8-bit CSI 0x9b) and no cursor
// control passes through, and a 60,000-byte host is cut.
TEST(MonitorTable, HeartbeatTextIsEscapedAndCut) {
  farm::MonitorSnapshot s = sample_snapshot();
  s.workers[0].host = std::string("evil\x1b]0;owned\x07\x1b[2J") + std::string(60000, 'h');
  s.workers[0].id =
      "w\x9b"
      "31mred\r\n";
  s.workers[0].state = "running\x1b[A";
  s.workers[0].last_error = "boom\x1b[1;1H\x7f";
  const std::string table = farm::render_table(s);
  for (size_t i = 0; i < table.size(); ++i) {
    const unsigned char c = static_cast<unsigned char>(table[i]);
    ASSERT_TRUE(c == '\n' || (c >= 0x20 && c < 0x7f)) << "byte " << int(c) << " at " << i << " of:\n" << table;
  }
  EXPECT_NE(table.find("evil\\x1b]0;owned\\x07\\x1b[2J"), std::string::npos) << table;
  EXPECT_NE(table.find("w\\x9b31mred\\x0d\\x0a"), std::string::npos) << table;
  EXPECT_NE(table.find("running\\x1b[A (boom\\x1b[1;1H\\x7f)"), std::string::npos) << table;
  EXPECT_LT(table.size(), 4000u) << "the 60,000-byte host was not cut";
}

}  // namespace

// The --log line's learner object has LearnerStats' typed fields under the names the learner's
// record gives them (common/learner_stats_fields.h), a count as a whole number, a NaN as null.
TEST(MonitorJson, LearnerFieldsHaveTheRecordsNames) {
  farm::MonitorSnapshot s = sample_snapshot();
  s.learners[0].elapsed_seconds = 12.5;
  const nlohmann::json line = nlohmann::json::parse(farm::render_json_line(s));
  const nlohmann::json& l = line.at("learner");
  EXPECT_EQ(l.at("experiment"), "pendulum_sac");
  EXPECT_DOUBLE_EQ(l.at("elapsed_s").get<double>(), 12.5);
  EXPECT_TRUE(l.at("env_steps").is_number_integer());
  EXPECT_EQ(l.at("env_steps").get<uint64_t>(), 816600u);
  EXPECT_DOUBLE_EQ(l.at("buffer_fill").get<double>(), 0.817);
  EXPECT_TRUE(l.at("eval_return").is_null());
  EXPECT_EQ(l.at("batches_duplicate").get<uint64_t>(), 1u);
  EXPECT_EQ(l.at("workers").get<uint32_t>(), 2u);
  std::vector<std::string> keys;
#define FARM_KEY(name, member, type) keys.push_back(#name);
  FARM_LEARNER_STATS_FIELDS(FARM_KEY)
#undef FARM_KEY
  EXPECT_EQ(l.size(), keys.size() + 2);  // and experiment, age_s
  for (const std::string& k : keys) EXPECT_TRUE(l.contains(k)) << k;
}
