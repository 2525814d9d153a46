// farm-intruder: a participant that tries to feed a farm made-up batches and to read its spec and
// weights. Used by the security test: with DDS Security on, a participant without a valid
// certificate must get nothing through either way.
//   farm_intruder --domain D --experiment ID --id NAME --obs N --act M --seconds S [--security DIR]
//                 [--hostile 1] [--oversize 1] [--spec-config FILE [--spec-steps T]] [--try-writers 1]
//                 [--heartbeat 1] [--eval-requests WORKER] [--spec-finished 1] [--spec-max-batches N]
//                 [--spec-only 1] [--status-host TEXT] [--status-error TEXT] [--events FILE]
// --id NAME names the participant and the worker id of its batches; with --security DIR of another
// participant's certificate it is a modified sender writing under an id that is not its own.
// --heartbeat 1: also publish a WorkerStatus heartbeat (worker NAME, state running) with each batch
// of the plain stream, as a worker would; --status-host and --status-error set its host (default:
// this host's name) and last_error.
// --spec-config FILE: also publish an ExperimentSpec for the experiment whose config text is FILE's
// (a learner's impostor: what a worker does with a spec it did not ask for). --spec-finished 1 marks
// it as the end of the experiment, --spec-max-batches N sets its max_batches_per_version (default
// 4), and --spec-only 1 sends no batch: the participant publishes its spec and stays --seconds.
// --hostile 1: instead of a plain stream, every 20 ms one batch claiming a sequence number near
// 2^64 or 2^63 and 50 batches of invented sessions with sequence numbers drawn from the whole 64-bit
// range, all well-formed otherwise (the attack that once set a learner's lost count to 2^63).
// --oversize 1: instead of a plain stream, every 500 ms one batch of 256 steps x 4096 envs (2^20
// transitions, tens of MB serialized) of a stream of its own, consistent in every field: each
// dimension within its bound (kMaxStepsPerBatch, kMaxEnvsPerWorker, kMaxBatchTransitions), but far
// larger than any batch an experiment of a few steps per batch sends. Prints the serialized size.
// --try-writers 1: instead of a stream, try to create a writer on each of the five farm topics and
// print which ones DDS Security's access control let it create (`writers created [...], refused
// [...]`), then exit 0. A writer the permissions deny is refused by Fast DDS at creation, so no
// sample of it can reach anyone; the security test runs it with worker and monitor certificates.
// --token-name NAME: the participant's identity token, which every peer reads in its discovery data,
// says its certificate's subject has CN=NAME while it authenticates with the certificate of --security
// (a participant built to lie: Fast DDS 2.9.1 fills the token's dds.cert.sn from X509_NAME_oneline,
// which this program replaces for Fast DDS's calls, and no peer compares the token with the
// certificate). Its batch and heartbeat writers stay in the partition of its real certificate.
// --eval-requests WORKER: instead of a stream, rounds of six evaluation requests addressed to WORKER,
// 50 ms apart, each wrong in one way: 0 episodes, 2^32 - 1 episodes, a first episode of 2^32 - 1, a policy
// of another experiment, a policy of another version than the request's, and a policy whose layout
// ([3, 2^31 - 1 x 4, 2^31 - 3, 1, 536870915, 2]) counts 2^64 + 8 parameters and carries 8. They
// name a learner session of their own, so a learner does not take the answers for its own.
// --forge-answers RETURN: instead of a stream, answer every evaluation request of the experiment
// the moment it is seen, as the worker asked would, every field copied from the request and that
// worker's last heartbeat, with each episode's return RETURN, length --forge-length (default 1)
// and --forge-metrics metrics (default 1) of value 1. With --heartbeat 1 it is a worker of its own
// instead: it beats as NAME (session 1, 4 envs, running), sends a well-formed one-step batch with
// each beat, and answers only what is asked of it; with --deliver 0 it sends no batch: it beats
// under the id NAME (a real worker's, from before that worker starts) and answers every request to
// NAME, the binding pre-emption.
// --flood-streams N: instead of a plain stream, N one-step batches once matched, each under an
// invented worker id and session, all well-formed.
// --flood-heartbeats N: instead of a plain stream, N heartbeats once matched, each of an invented
// worker session, with the host name --status-host (--status-host-bytes B: B characters instead);
// with --beat-every S the same N sessions beat again every S seconds while --seconds lasts.
// --malformed KIND [--fuzz-seed N] [--dump DIR]: instead of a stream, samples of every topic whose
// bytes do not decode, or (fuzz) mutated afresh each time (intruder_malformed.cpp).
// --forge-removal 1: instead of a stream, raw UDP and no DDS: once it has read the experiment's spec
// (which names the learner's GUID prefix), every --removal-every-ms (default 50) an SPDP DATA(p[UD])
// in the learner's name (RTPS header and key of the learner's prefix, status disposed and
// unregistered), the message a participant sends as it leaves, to the metatraffic unicast ports of
// participant ids 0..119 of the domain on 127.0.0.1 and to the domain's discovery multicast group.
// --steal-streams 1: instead of a stream, a thief: it reads the heartbeats of the experiment and, for
// each worker session it hears of (at most 16), writes well-formed one-step batches under that
// worker's id and session, numbered from 0, every 50 ms: whoever writes first would own the stream.
// --big-to-workers MB: instead of a stream, a spec, weights and an evaluation request (to a worker
// id no worker has) of MB MiB each, well-formed otherwise, published once a worker reads them.
// The floods (--flood-*, --hostile, --oversize, --big-to-workers) are in intruder_floods.cpp, the
// forgeries (--forge-*, --eval-requests, --steal-streams) in intruder_forgeries.cpp, --malformed in
// intruder_malformed.cpp; this file has the plain stream, the spec impostor and the options.
// What it did is printed for people; --events FILE also writes it for programs (common/event_log.h):
// one JSON object a line with "event" (its kind), "id" (--id) and "elapsed_s" (seconds since it
// started). The tests read this record. Kinds:
//   joined          domain, security (the --security folder; "" without): its participant exists
//   refused         what: the error that ended it, a certificate or profile refused among them (exit 3)
//   writers         created, refused: the farm topics of --try-writers, lists of names
//   spec_published  experiment_id, steps_per_batch, max_batches_per_version, finished (--spec-only)
//   serialized      steps, envs, bytes: one --oversize batch and its size serialized
//   sent            batches, batch_readers_matched (the most at once), weights_received,
//                   specs_received: the end of the plain stream, of --hostile or of --oversize
//   flooded         batches, heartbeats (--flood-streams, --flood-heartbeats)
//   big_sent        samples, mib (--big-to-workers)
//   eval_requests   worker, sent, readers_matched, answers_received (--eval-requests)
//   forged_answers  count (--forge-answers)
//   forged_weights  count, readers_matched (--forge-weights)
//   naming_learner  learner: the GUID prefix (hex) the --forge-removal messages name, before the first
//   no_learner      experiment_id: --forge-removal read no spec of it in 15 s, sent nothing (exit 4)
//   removals        sent, learner: the --forge-removal datagrams sent, at its end
//   stealing        worker_id, session: a stream --steal-streams writes under from then on
//   stolen          batches, sessions: the end of --steal-streams
//   not_permitted   topic: a topic --malformed may not write under its certificate, skipped
//   malformed       kind, seed, topic, written, matched: one a topic, at the end of --malformed
#include <dlfcn.h>
#include <openssl/x509.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <thread>

#include "cli.h"
#include "config.h"
#include "dds.h"
#include "event_log.h"
#include "intruder_events.h"
#include "intruder_floods.h"
#include "intruder_forgeries.h"
#include "intruder_malformed.h"
#include "meter.h"

namespace {

std::string g_token_name;  // --token-name
std::string g_own_name;    // the CN of its own certificate, which the token's subject replaces
farm::EventLog g_events;   // --events
std::string g_id;          // --id, in every event

}  // namespace

void record(const std::string& kind, nlohmann::json fields) {
  fields["id"] = g_id;
  g_events.write(kind, std::move(fields));
}

// Replaces OpenSSL's X509_NAME_oneline for Fast DDS's calls (this program exports it: ENABLE_EXPORTS),
// so that with --token-name the subject of its own certificate, as Fast DDS puts it in this
// participant's identity token, has another CN. Other subjects (the CA's, the peers') stay as they
// are, Fast DDS's access control reads the subject in RFC 2253 form (X509_NAME_print_ex), which stays
// the certificate's, and so does every other caller of this function.
extern "C" char* X509_NAME_oneline(const X509_NAME* name, char* buf, int size) {
  using Fn = char* (*)(const X509_NAME*, char*, int);
  static const Fn real = reinterpret_cast<Fn>(dlsym(RTLD_NEXT, "X509_NAME_oneline"));
  char* text = real(name, buf, size);
  Dl_info caller{};
  if (g_token_name.empty() || !text || buf != nullptr || !dladdr(__builtin_return_address(0), &caller) ||
      !caller.dli_fname || !std::strstr(caller.dli_fname, "libfastrtps"))
    return text;
  std::string subject = text;
  const size_t cn = subject.find("/CN=" + g_own_name);
  const size_t end = cn + 4 + g_own_name.size();
  if (cn == std::string::npos || (end < subject.size() && subject[end] != '/')) return text;
  subject = subject.substr(0, cn + 4) + g_token_name + subject.substr(end);
  OPENSSL_free(text);
  return OPENSSL_strdup(subject.c_str());
}

namespace {

// Tries one writer of type T on topic; true if Fast DDS created it.
template <class T, class PubSubType>
bool writer_created(farm::dds::Bus& bus, const char* topic, const char* profile) {
  try {
    farm::dds::Writer<T, PubSubType> w(bus, topic, profile);
    return true;
  } catch (const std::runtime_error&) {
    return false;
  }
}

int try_every_writer(farm::dds::Bus& bus, const std::string& id) {
  using namespace farm::msg;
  namespace d = farm::dds;
  const std::pair<const char*, bool> tries[] = {
      {d::kSpecTopic, writer_created<ExperimentSpec, ExperimentSpecPubSubType>(bus, d::kSpecTopic, "latest_writer")},
      {d::kWeightsTopic,
       writer_created<PolicyWeights, PolicyWeightsPubSubType>(bus, d::kWeightsTopic, "latest_writer")},
      {d::kLearnerStatsTopic,
       writer_created<LearnerStats, LearnerStatsPubSubType>(bus, d::kLearnerStatsTopic, "status_writer")},
      {d::kBatchTopic, writer_created<TransitionBatch, TransitionBatchPubSubType>(bus, d::kBatchTopic, "batch_writer")},
      {d::kWorkerStatusTopic,
       writer_created<WorkerStatus, WorkerStatusPubSubType>(bus, d::kWorkerStatusTopic, "status_writer")},
  };
  std::string created, refused;
  nlohmann::json created_list = nlohmann::json::array(), refused_list = nlohmann::json::array();
  for (const auto& [topic, ok] : tries) {
    std::string& list = ok ? created : refused;
    list += (list.empty() ? "" : " ") + std::string(topic);
    (ok ? created_list : refused_list).push_back(topic);
  }
  std::printf("%s: writers created [%s], refused [%s]\n", id.c_str(), created.c_str(), refused.c_str());
  record("writers", {{"created", created_list}, {"refused", refused_list}});
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  farm::dds::BusOptions bus_opts;
  std::string experiment = "pendulum_sac", id = "intruder";
  unsigned obs = 3, act = 1;
  double seconds = 10;
  bool hostile = false, forge_weights_on = false, oversize = false, try_writers = false, heartbeat = false;
  bool spec_finished = false, spec_only = false, forge_removal_on = false, steal = false, deliver = true;
  double removal_every_ms = 50;
  std::string spec_config, eval_worker, status_host = farm::dds::hostname(), status_error, malformed, dump_dir;
  std::string events_file;
  uint64_t fuzz_seed = 1;
  unsigned spec_steps = 4, spec_max_batches = 4;
  double forge_return = NAN, beat_every = 0;
  unsigned forge_length = 1, forge_metrics = 1, flood_streams = 0, flood_heartbeats = 0, host_bytes = 0, big_mib = 0;
  farm::cli::App app("farm_intruder");
  app.description("A participant that does what no farm program does, for the reliability and security tests.");
  farm::dds::add_bus_options(app, bus_opts);
  // A switch given as 1 (on) or anything else (off), as the tests' scripts pass it.
  auto add_switch = [&app](const char* name, bool& on, const char* what) {
    app.add_option_function<std::string>(
        name, [&on](const std::string& v) { on = v == "1"; }, what);
  };
  app.add_option("--experiment", experiment, "Experiment id of what it writes")->capture_default_str();
  app.add_option("--id", id, "Participant and worker id")->capture_default_str();
  app.add_option("--obs", obs, "Observation size of its batches")->capture_default_str();
  app.add_option("--act", act, "Action size of its batches")->capture_default_str();
  app.add_option("--seconds", seconds, "How long it runs")->capture_default_str();
  add_switch("--hostile", hostile,
             "1: batches of invented sessions and sequence numbers near 2^64 instead of a plain stream");
  add_switch("--oversize", oversize,
             "1: batches of 2^20 transitions, each dimension within its bound, instead of a plain stream");
  app.add_option("--spec-config", spec_config,
                 "Also publish an ExperimentSpec whose config text is this file's (a learner's impostor)");
  app.add_option("--spec-steps", spec_steps, "steps_per_batch of the --spec-config spec")->capture_default_str();
  add_switch("--spec-finished", spec_finished, "1: the spec marks the end of the experiment");
  app.add_option("--spec-max-batches", spec_max_batches, "max_batches_per_version of the spec")->capture_default_str();
  add_switch("--spec-only", spec_only, "1: send no batch: publish the spec and stay --seconds");
  app.add_option("--status-host", status_host, "Host of its heartbeats (default: this host's name)");
  app.add_option("--status-error", status_error, "last_error of its heartbeats");
  add_switch("--try-writers", try_writers,
             "1: try to create a writer on each farm topic, print which ones access control let it create, exit 0");
  add_switch("--heartbeat", heartbeat, "1: also publish a WorkerStatus heartbeat with each batch, as a worker would");
  app.add_option("--eval-requests", eval_worker,
                 "WORKER: rounds of six evaluation requests to WORKER, each wrong in one way, instead of a stream");
  app.add_option("--forge-answers", forge_return,
                 "RETURN: answer every evaluation request of the experiment with episodes of this return");
  app.add_option("--forge-length", forge_length, "Episode length of the forged answers")->capture_default_str();
  app.add_option("--forge-metrics", forge_metrics, "Metrics (of value 1) of each forged episode")
      ->capture_default_str();
  add_switch("--deliver", deliver,
             "0: with --forge-answers and --heartbeat 1, send no batch: beat under the id and answer");
  app.add_option("--flood-streams", flood_streams,
                 "N: one-step batches under N invented worker ids and sessions instead of a plain stream");
  app.add_option("--flood-heartbeats", flood_heartbeats,
                 "N: heartbeats of N invented worker sessions instead of a plain stream");
  app.add_option("--beat-every", beat_every,
                 "S > 0: the --flood-heartbeats sessions beat again every S seconds for --seconds (live workers)");
  app.add_option("--status-host-bytes", host_bytes, "B: a host name of B characters in the flood's heartbeats");
  add_switch("--forge-weights", forge_weights_on,
             "1: the experiment's weights as its learner publishes them, written again a million versions ahead");
  app.add_option("--malformed", malformed,
                 "bool, length, truncate or fuzz: broken samples of every topic instead of a stream");
  app.add_option("--fuzz-seed", fuzz_seed, "Seed of --malformed fuzz's mutations")->capture_default_str();
  app.add_option("--dump", dump_dir,
                 "DIR: --malformed writes each topic's broken sample to DIR/<type>_<kind>.hex, not to the bus");
  app.add_option("--big-to-workers", big_mib,
                 "MB: a spec, weights and an evaluation request of MB MiB each, instead of a stream");
  add_switch("--steal-streams", steal,
             "1: batches under each worker session its heartbeats name, numbered from 0 (a stream thief)");
  add_switch("--forge-removal", forge_removal_on,
             "1: raw UDP participant removals in the learner's name to every discovery port of the domain");
  app.add_option("--removal-every-ms", removal_every_ms, "Milliseconds between --forge-removal rounds")
      ->capture_default_str();
  app.add_option("--token-name", g_token_name,
                 "NAME: its identity token says CN=NAME while it authenticates with the certificate of --security");
  app.add_option("--events", events_file,
                 "FILE: also write what it did as JSON lines, one event a line (kinds: farm_intruder.cpp's top)");
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  g_id = id;
  g_events.set_start(farm::now_seconds());
  try {
    if (!events_file.empty()) g_events.open(events_file);
    if (!g_token_name.empty()) g_own_name = farm::dds::certificate_name(farm::dds::security_dir_of(bus_opts));
    farm::dds::Bus bus(bus_opts, id);
    // Said once the participant exists, so a test can tell a participant that ran and got nothing
    // from one that never started (a missing certificate file also ends in `refused:` below).
    const std::string how =
        bus.security_dir().empty() ? "without security" : "with security from " + bus.security_dir();
    std::printf("%s: joined domain %d %s\n", id.c_str(), bus.domain(), how.c_str());
    std::fflush(stdout);
    record("joined", {{"domain", bus.domain()}, {"security", bus.security_dir()}});
    if (try_writers) return try_every_writer(bus, id);
    if (!std::isnan(forge_return))
      return forge_answers(bus, id, experiment, seconds, forge_return, forge_length, forge_metrics, heartbeat, obs, act,
                           deliver);
    if (big_mib > 0) return big_to_workers(bus, id, experiment, big_mib, seconds);
    if (!malformed.empty())
      return send_malformed(bus, id, experiment, obs, act, malformed, seconds, fuzz_seed, dump_dir);
    if (forge_weights_on) return forge_weights(bus, id, experiment, seconds);
    if (forge_removal_on) return forge_removal(bus, id, experiment, seconds, removal_every_ms);
    if (steal) return steal_streams(bus, id, experiment, seconds, obs, act);
    if (host_bytes > 0) status_host = std::string(host_bytes, 'h');
    if (!eval_worker.empty()) return bad_eval_requests(bus, id, experiment, eval_worker, seconds);
    farm::dds::Writer<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType> out(bus, farm::dds::kBatchTopic,
                                                                                            "batch_writer");
    farm::dds::Reader<farm::msg::PolicyWeights, farm::msg::PolicyWeightsPubSubType> weights(
        bus, farm::dds::kWeightsTopic, "latest_reader");
    farm::dds::Reader<farm::msg::ExperimentSpec, farm::msg::ExperimentSpecPubSubType> spec(bus, farm::dds::kSpecTopic,
                                                                                           "latest_reader");
    using StatusWriter = farm::dds::Writer<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType>;
    std::unique_ptr<StatusWriter> status_out;
    if (heartbeat) status_out = std::make_unique<StatusWriter>(bus, farm::dds::kWorkerStatusTopic, "status_writer");
    // Only when asked: a worker's certificate may not even create a spec writer (access control).
    using SpecWriter = farm::dds::Writer<farm::msg::ExperimentSpec, farm::msg::ExperimentSpecPubSubType>;
    std::unique_ptr<SpecWriter> spec_out;
    if (!spec_config.empty()) {
      spec_out = std::make_unique<SpecWriter>(bus, farm::dds::kSpecTopic, "latest_writer");
      std::ifstream in(spec_config);
      if (!in) throw std::runtime_error("cannot read " + spec_config);
      std::stringstream text;
      text << in.rdbuf();
      farm::msg::ExperimentSpec s;
      s.experiment_id(experiment);
      s.config_text(text.str());
      s.obs_dim(obs);
      s.act_dim(act);
      s.steps_per_batch(spec_steps);
      s.max_batches_per_version(spec_max_batches);
      s.seed(1);
      s.learner_session(1);
      s.finished(spec_finished);
      spec_out->write(s);
      if (spec_only) {
        std::printf("%s: published a spec of experiment '%s' (steps_per_batch %u, max_batches_per_version %u%s)\n",
                    id.c_str(), experiment.c_str(), spec_steps, spec_max_batches, spec_finished ? ", finished" : "");
        std::fflush(stdout);
        record("spec_published", {{"experiment_id", experiment},
                                  {"steps_per_batch", spec_steps},
                                  {"max_batches_per_version", spec_max_batches},
                                  {"finished", spec_finished}});
        std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
        return 0;
      }
    }
    // A well-formed batch: if it got through, the learner would accept it.
    const unsigned N = 1;
    farm::msg::TransitionBatch b = one_step_batch(experiment, id, obs, act);
    uint64_t sent = 0, weights_seen = 0, specs_seen = 0;
    int max_matched = 0;
    const double t0 = farm::now_seconds();
    std::mt19937_64 rng(12345);
    // Hostile: wait to be matched, so that every batch counted as sent reaches the learner.
    while ((hostile || oversize) && out.matched() == 0 && farm::now_seconds() - t0 < 15)
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    if (oversize) make_oversized(b, rng, id, obs, act);
    if (flood_streams > 0 || flood_heartbeats > 0)
      return flood(bus, out, b, rng, id, experiment, Flood{flood_streams, flood_heartbeats, beat_every, status_host},
                   t0, seconds);
    if (oversize) send_oversized(out, b, t0, seconds, sent, max_matched);
    if (hostile) send_hostile(out, b, rng, t0, seconds, sent, max_matched);
    while (!hostile && !oversize && farm::now_seconds() - t0 < seconds) {
      b.sequence_number(sent);
      if (out.write(b)) ++sent;
      if (status_out) {
        farm::msg::WorkerStatus st;
        st.worker_id(id);
        st.worker_session(1);
        st.host(status_host);
        st.experiment_id(experiment);
        st.envs(N);
        st.threads(1);
        st.batches_sent(sent);
        st.state("running");
        st.last_error(status_error);
        status_out->write(st);
      }
      max_matched = std::max(max_matched, out.matched());
      farm::msg::PolicyWeights w;
      while (weights.take(w)) ++weights_seen;
      farm::msg::ExperimentSpec s;
      while (spec.take(s)) ++specs_seen;
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    std::printf("%s: sent %llu batches, batch readers matched %d, weights received %llu, specs received %llu\n",
                id.c_str(), (unsigned long long)sent, max_matched, (unsigned long long)weights_seen,
                (unsigned long long)specs_seen);
    record("sent", {{"batches", sent},
                    {"batch_readers_matched", max_matched},
                    {"weights_received", weights_seen},
                    {"specs_received", specs_seen}});
    return 0;
  } catch (const std::exception& e) {
    // A participant whose certificate is rejected cannot even be created: that is a refusal too.
    std::printf("%s: refused: %s\n", id.c_str(), e.what());
    record("refused", {{"what", e.what()}});
    return 3;
  }
}
