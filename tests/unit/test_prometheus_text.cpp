// farm-monitor's Prometheus page (tools/prometheus_text.h) from a snapshot: every family has its
// HELP and TYPE before its samples, the values are the snapshot's, counters end in _total, label
// values from the bus are bounded, valid UTF-8 and escaped, and workers whose bounded labels repeat
// another's are left out and counted. Where promtool (Debian's prometheus package) is installed, it
// must accept the page.
#include <gtest/gtest.h>

#include <unistd.h>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <set>
#include <sstream>
#include <string>

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
  s.learners = {l};
  s.latest_learner = 0;
  return s;
}

struct Page {
  std::map<std::string, std::string> type, help;  // by family
  std::map<std::string, std::string> value;       // by name{labels}
  std::vector<std::string> order;                 // families in the order of their TYPE lines
  std::string problem;                            // first structural fault found
};

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
      const size_t sp = line.rfind(' ');
      const std::string series = line.substr(0, sp);
      const std::string name = series.substr(0, series.find('{'));
      if (name != current && p.problem.empty()) p.problem = "sample " + series + " outside its family";
      if (p.value.count(series) && p.problem.empty()) p.problem = "series " + series + " twice";
      p.value[series] = line.substr(sp + 1);
    }
  }
  return p;
}

const char kWorkerA[] = "worker=\"host-b\",host=\"vm\",experiment=\"pendulum_sac\"";
const char kWorkerC[] = "worker=\"host-c\",host=\"vm\",experiment=\"pendulum_sac\"";
const char kLearner[] = "experiment=\"pendulum_sac\"";

std::string at(const Page& p, const std::string& name, const std::string& labels = "") {
  auto it = p.value.find(labels.empty() ? name : name + "{" + labels + "}");
  return it == p.value.end() ? "(absent)" : it->second;
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
}

TEST(PrometheusText, ValuesAreTheSnapshots) {
  const farm::MonitorSnapshot s = sample_snapshot();
  Page p = parse(farm::render_prometheus(s));
  EXPECT_EQ(at(p, "farm_monitor_snapshot_timestamp_seconds"), "1764115200.123");
  EXPECT_EQ(at(p, "farm_worker_env_steps_per_second", kWorkerA), "70777.5");
  EXPECT_EQ(at(p, "farm_worker_env_steps_total", kWorkerA), "12345678901");  // integers as integers
  EXPECT_EQ(at(p, "farm_worker_batches_sent_total", kWorkerA), "1664");
  EXPECT_EQ(at(p, "farm_worker_policy_version", kWorkerA), "87");
  EXPECT_EQ(at(p, "farm_worker_up", kWorkerA), "1");
  EXPECT_EQ(at(p, "farm_worker_up", kWorkerC), "0");
  EXPECT_EQ(at(p, "farm_worker_env_steps_per_second", kWorkerC), "0");
  EXPECT_EQ(at(p, "farm_worker_last_heartbeat_age_seconds", kWorkerC), "9.25");
  // One state series per known state, exactly one of them 1.
  for (const char* w : {kWorkerA, kWorkerC}) {
    int on = 0;
    for (const std::string& st : farm::prometheus_worker_states())
      on += at(p, "farm_worker_state", std::string(w) + ",state=\"" + st + "\"") == "1";
    EXPECT_EQ(on, 1) << w;
  }
  EXPECT_EQ(at(p, "farm_worker_state", std::string(kWorkerA) + ",state=\"running\""), "1");
  EXPECT_EQ(at(p, "farm_worker_state", std::string(kWorkerC) + ",state=\"dead\""), "1");
  EXPECT_EQ(at(p, "farm_workers", "status=\"live\""), "1");
  EXPECT_EQ(at(p, "farm_workers", "status=\"dead\""), "1");
  EXPECT_EQ(at(p, "farm_total_env_steps_per_second"), "70777.5");
  EXPECT_EQ(at(p, "farm_total_batches_sent"), "1664");
  EXPECT_EQ(at(p, "farm_learner_env_steps_total", kLearner), "816600");
  EXPECT_EQ(at(p, "farm_learner_buffer_fill_ratio", kLearner), "0.817");
  EXPECT_EQ(at(p, "farm_learner_mean_return", kLearner), "-176");
  EXPECT_EQ(at(p, "farm_learner_eval_return", kLearner), "(absent)") << "no evaluation yet: no sample, not NaN";
  EXPECT_EQ(at(p, "farm_learner_batches_total", std::string(kLearner) + ",result=\"ok\""), "3565");
  EXPECT_EQ(at(p, "farm_learner_batches_total", std::string(kLearner) + ",result=\"lost\""), "2");
  EXPECT_EQ(at(p, "farm_learner_batches_total", std::string(kLearner) + ",result=\"duplicate\""), "1");
  EXPECT_EQ(at(p, "farm_learner_batches_total", std::string(kLearner) + ",result=\"invalid\""), "4");
  EXPECT_EQ(at(p, "farm_monitor_workers_not_exported"), "0");
}

TEST(PrometheusText, AStateItDoesNotKnowIsOther) {
  farm::MonitorSnapshot s = sample_snapshot();
  s.workers[0].state = "dancing";
  Page p = parse(farm::render_prometheus(s));
  EXPECT_EQ(at(p, "farm_worker_state", std::string(kWorkerA) + ",state=\"other\""), "1");
  EXPECT_EQ(at(p, "farm_worker_state", std::string(kWorkerA) + ",state=\"dancing\""), "(absent)");
}

TEST(PrometheusText, LabelValuesAreBoundedValidUtf8AndEscaped) {
  EXPECT_EQ(farm::prometheus_label_value("a\"b\\c\nd", 64), "a\\\"b\\\\c\\nd");
  EXPECT_EQ(farm::prometheus_label_value("x\xff y\x01", 64), "x\xEF\xBF\xBD y\xEF\xBF\xBD");
  EXPECT_EQ(farm::prometheus_label_value("\xC0\xAF", 64), "\xEF\xBF\xBD\xEF\xBF\xBD") << "an overlong '/'";
  EXPECT_EQ(farm::prometheus_label_value("\xED\xA0\x80", 64), "\xEF\xBF\xBD\xEF\xBF\xBD\xEF\xBF\xBD") << "a surrogate";
  EXPECT_EQ(farm::prometheus_label_value("h\xC3\xA9llo", 64), "h\xC3\xA9llo");
  // Cut at the bound, never inside a character: 'é' is two bytes and does not fit after "abc" in 4.
  EXPECT_EQ(farm::prometheus_label_value("abc\xC3\xA9", 4), "abc");
  EXPECT_EQ(farm::prometheus_label_value(std::string(100000, 'w'), 128), std::string(128, 'w'));
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
  const std::string cut = "worker=\"" + std::string(128, 'z') + "\",host=\"vm\",experiment=\"pendulum_sac\"";
  EXPECT_EQ(at(p, "farm_worker_up", cut), "1");

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
