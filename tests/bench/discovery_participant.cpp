// A cheap idle DDS participant for the discovery benchmark (tests/bench/bench_discovery.sh): one
// real Fast DDS participant with the farm's profiles, one writer and one reader of the farm's small
// status topics, publishing nothing. It records when it started and when both its endpoints have
// matched the expected number of remote endpoints, then idles until SIGTERM (or --max-seconds), so
// the others can match it.
//
//   discovery_participant --name NAME --role mesh|worker|learner --expect K [--max-seconds S]
//                         [--domain D] [--dds-profiles FILE] [--events FILE]
//
// mesh: writes and reads farm/WorkerStatus, so every participant matches every other one;
// worker: writes farm/WorkerStatus and reads farm/LearnerStats (a worker's side of the farm);
// learner: reads farm/WorkerStatus and writes farm/LearnerStats. --expect counts remote endpoints:
// N-1 for mesh and for the learner, 1 for a worker.
// With --events FILE its record for programs (common/event_log.h), one JSON object a line with
// "event" and "elapsed_s"; unix_s is the Unix time in seconds, so a script can compare processes:
//   started    name, unix_s: when it began to create its participant (written once it exists)
//   matched    name, expect, unix_s: both the writer and the reader have `expect` remote matches
//   unmatched  name, writer, reader, unix_s: at exit, if never matched (the writer's and reader's
//              counts)
// Its output says the same to people, one line each: "started NAME T", "matched NAME K T",
// "unmatched NAME W R T".
#include <signal.h>
#include <time.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <thread>

#include "cli.h"
#include "dds.h"
#include "event_log.h"
#include "meter.h"

namespace {

std::atomic<bool> g_stop{false};
void on_term(int) { g_stop = true; }

double unix_now() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return double(ts.tv_sec) + ts.tv_nsec * 1e-9;
}

struct Options {
  farm::dds::BusOptions bus;
  std::string name, role = "mesh";
  int expect = -1;
  double max_seconds = 600;
  std::string events;  // the events file (JSON lines); empty: none
};

// Declares the options into o; --name and --expect are required.
void add_options(CLI::App& app, Options& o) {
  app.description("One participant of the discovery benchmark: reports when its endpoints matched the others.");
  farm::dds::add_bus_options(app, o.bus);
  app.add_option("--name", o.name, "The participant's name")->required();
  app.add_option("--role", o.role, "mesh, worker or learner")
      ->check(CLI::IsMember({"mesh", "worker", "learner"}))
      ->capture_default_str();
  app.add_option("--expect", o.expect,
                 "Remote endpoints each of its writer and reader must match (mesh, learner: N-1; worker: 1)")
      ->required()
      ->check(CLI::Range(1, 100000));
  app.add_option("--max-seconds", o.max_seconds, "Longest wait for the matches")
      ->check(farm::cli::above(0, 86400))
      ->capture_default_str();
  app.add_option("--events", o.events, "Write its events (started, matched, unmatched) to FILE, one JSON object a line")
      ->check(farm::cli::non_empty("a file name"));
}

using StatusWriter = farm::dds::Writer<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType>;
using StatusReader = farm::dds::Reader<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType>;
using StatsWriter = farm::dds::Writer<farm::msg::LearnerStats, farm::msg::LearnerStatsPubSubType>;
using StatsReader = farm::dds::Reader<farm::msg::LearnerStats, farm::msg::LearnerStatsPubSubType>;

// Matched counts of the participant's writer and reader, remote endpoints only.
template <class W, class R>
int run(const Options& o, farm::dds::Bus& bus, farm::EventLog& events, const char* write_topic,
        const char* read_topic) {
  W writer(bus, write_topic, "status_writer");
  R reader(bus, read_topic, "status_reader");
  // In mesh, the participant's own writer and reader share a topic and match each other too.
  const int own = std::string(write_topic) == read_topic ? 1 : 0;
  const auto t0 = std::chrono::steady_clock::now();
  bool matched = false;
  while (!g_stop && std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() < o.max_seconds) {
    if (!matched && writer.matched() - own >= o.expect && reader.matched() - own >= o.expect) {
      matched = true;
      const double t = unix_now();
      events.write("matched", {{"name", o.name}, {"expect", o.expect}, {"unix_s", t}});
      std::printf("matched %s %d %.6f\n", o.name.c_str(), o.expect, t);
      std::fflush(stdout);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(matched ? 100 : 10));
  }
  if (!matched) {
    const int w = writer.matched() - own, r = reader.matched() - own;
    const double t = unix_now();
    events.write("unmatched", {{"name", o.name}, {"writer", w}, {"reader", r}, {"unix_s", t}});
    std::printf("unmatched %s %d %d %.6f\n", o.name.c_str(), w, r, t);
  }
  return matched ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  farm::cli::App app("discovery_participant");
  add_options(app, o);
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  try {
    signal(SIGTERM, on_term);
    signal(SIGINT, on_term);
    farm::EventLog events;
    events.set_start(farm::now_seconds());
    if (!o.events.empty()) events.open(o.events);
    const double start = unix_now();
    farm::dds::Bus bus(o.bus, "discovery_" + o.name);
    events.write("started", {{"name", o.name}, {"unix_s", start}});
    std::printf("started %s %.6f\n", o.name.c_str(), start);
    std::fflush(stdout);
    if (o.role == "mesh")
      return run<StatusWriter, StatusReader>(o, bus, events, farm::dds::kWorkerStatusTopic,
                                             farm::dds::kWorkerStatusTopic);
    if (o.role == "worker")
      return run<StatusWriter, StatsReader>(o, bus, events, farm::dds::kWorkerStatusTopic,
                                            farm::dds::kLearnerStatsTopic);
    return run<StatsWriter, StatusReader>(o, bus, events, farm::dds::kLearnerStatsTopic, farm::dds::kWorkerStatusTopic);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "discovery_participant: %s\n", e.what());
    return 2;
  }
}
