#include "checkpoint.h"

#include <google/protobuf/text_format.h>

#include <filesystem>
#include <fstream>
#include <sstream>

namespace farm {

namespace fs = std::filesystem;

namespace {

// Networks are written by save_nets(folder) into the sub-folder `name`.
template <class SaveNets>
void save_checkpoint_with(const std::string& dir, const config::CheckpointManifest& manifest,
                          const std::string& name, SaveNets save_nets, const ReplayBuffer& replay) {
  const fs::path final_dir(dir), tmp = final_dir.string() + ".tmp", old = final_dir.string() + ".old";
  fs::remove_all(tmp);
  fs::create_directories(tmp / name);
  save_nets((tmp / name).string());
  replay.save((tmp / "replay.pt").string());
  std::string text;
  google::protobuf::TextFormat::PrintToString(manifest, &text);
  {
    std::ofstream out(tmp / "manifest.txtpb");
    out << text;
    if (!out) throw std::runtime_error("cannot write " + (tmp / "manifest.txtpb").string());
  }
  fs::remove_all(old);
  if (fs::exists(final_dir)) fs::rename(final_dir, old);
  fs::rename(tmp, final_dir);
  fs::remove_all(old);
}

}  // namespace

void save_checkpoint(const std::string& dir, const config::CheckpointManifest& manifest, const Sac& sac,
                     const ReplayBuffer& replay) {
  save_checkpoint_with(dir, manifest, "sac", [&](const std::string& d) { sac.save(d); }, replay);
}

void save_checkpoint(const std::string& dir, const config::CheckpointManifest& manifest,
                     const OffPolicy& algo, const ReplayBuffer& replay) {
  save_checkpoint_with(dir, manifest, algo.name(), [&](const std::string& d) { algo.save(d); },
                       replay);
}

// A crash between the two renames of a save leaves only DIR.old, which is complete: use it.
static fs::path usable_checkpoint(const std::string& dir) {
  if (!fs::exists(fs::path(dir) / "manifest.txtpb") && fs::exists(fs::path(dir + ".old") / "manifest.txtpb"))
    return fs::path(dir + ".old");
  return fs::path(dir);
}

bool checkpoint_exists(const std::string& dir) { return fs::exists(usable_checkpoint(dir) / "manifest.txtpb"); }

namespace {

template <class LoadNets>
config::CheckpointManifest load_checkpoint_with(const std::string& dir, const std::string& experiment_id,
                                                const std::string& name, LoadNets load_nets,
                                                ReplayBuffer& replay) {
  const fs::path mpath = usable_checkpoint(dir) / "manifest.txtpb";
  std::ifstream in(mpath);
  if (!in) throw std::runtime_error("no checkpoint manifest at " + mpath.string());
  std::stringstream ss;
  ss << in.rdbuf();
  config::CheckpointManifest m;
  if (!google::protobuf::TextFormat::ParseFromString(ss.str(), &m))
    throw std::runtime_error("cannot parse checkpoint manifest " + mpath.string());
  if (m.experiment_id() != experiment_id)
    throw std::runtime_error(mpath.string() + ": checkpoint is of experiment '" + m.experiment_id() +
                             "', the config says '" + experiment_id + "'");
  load_nets((usable_checkpoint(dir) / name).string());
  replay.load((usable_checkpoint(dir) / "replay.pt").string());
  return m;
}

}  // namespace

config::CheckpointManifest load_checkpoint(const std::string& dir, const std::string& experiment_id, Sac& sac,
                                           ReplayBuffer& replay) {
  return load_checkpoint_with(dir, experiment_id, "sac", [&](const std::string& d) { sac.load(d); },
                              replay);
}

config::CheckpointManifest load_checkpoint(const std::string& dir, const std::string& experiment_id,
                                           OffPolicy& algo, ReplayBuffer& replay) {
  return load_checkpoint_with(dir, experiment_id, algo.name(),
                              [&](const std::string& d) { algo.load(d); }, replay);
}

void accounts_to_manifest(const Ingest& ingest, config::CheckpointManifest& m) {
  m.clear_workers();
  for (const auto& [key, w] : ingest.workers()) {
    auto* r = m.add_workers();
    r->set_worker_id(w.worker_id);
    r->set_session(w.session);
    r->set_next_sequence(w.next_sequence);
    r->set_received(w.received);
    r->set_lost(w.lost);
    r->set_duplicates(w.duplicates);
    r->set_invalid(w.invalid);
    r->set_env_steps(w.env_steps);
    r->set_ended(w.ended);
  }
  const auto& c = ingest.counters();
  m.set_batches_ok(c.ok);
  m.set_batches_lost(c.lost);
  m.set_batches_duplicate(c.duplicate);
  m.set_batches_invalid(c.invalid);
  m.set_env_steps(c.env_steps);
}

void accounts_from_manifest(const config::CheckpointManifest& m, Ingest& ingest) {
  std::map<Ingest::Key, WorkerAccount> workers;
  for (const auto& r : m.workers()) {
    WorkerAccount w;
    w.worker_id = r.worker_id();
    w.session = r.session();
    w.next_sequence = r.next_sequence();
    w.received = r.received();
    w.lost = r.lost();
    w.duplicates = r.duplicates();
    w.invalid = r.invalid();
    w.env_steps = r.env_steps();
    w.ended = r.ended();
    workers[{w.worker_id, w.session}] = w;
  }
  IngestCounters c;
  c.ok = m.batches_ok();
  c.lost = m.batches_lost();
  c.duplicate = m.batches_duplicate();
  c.invalid = m.batches_invalid();
  c.env_steps = m.env_steps();
  ingest.restore(workers, c);
}

}  // namespace farm
