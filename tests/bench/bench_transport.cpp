// TransitionBatch transport between two real processes, against its limit measured in the same
// run: memcpy bandwidth on one host, or a plain TCP stream where the two processes sit in
// different network namespaces (tests/bench/transport_netns.sh sets that up).
//
//   bench_transport [--sizes BYTES[,BYTES...]] [--seconds S] [--domain D] [--dds-profiles FILE]
//                   [--writer-prefix "CMD ..."] [--tcp-limit HOST]
//
// This process is the reader (the learner's side, profile batch_reader); it starts a copy of
// itself as the writer (a worker's side, profile batch_writer), prefixed by --writer-prefix
// (e.g. "ip netns exec farm_b"). The writer sends batches of each size for S seconds, then an
// end_of_stream batch carrying the count; the reader checks that every sequence number arrived
// exactly once and reports MB/s and batches/s from the writer's first write to the reader's last
// arrival (both processes read the same monotonic clock; the writer sends its start time along in
// the batches' policy_version field).
#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "bench_options.h"
#include "dds.h"

namespace {

using Clock = std::chrono::steady_clock;
using farm::msg::TransitionBatch;
using BatchWriter = farm::dds::Writer<TransitionBatch, farm::msg::TransitionBatchPubSubType>;
using BatchReader = farm::dds::Reader<TransitionBatch, farm::msg::TransitionBatchPubSubType>;

constexpr int kTcpPort = 47611;

double since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }
uint64_t ticks(Clock::time_point t) { return uint64_t(t.time_since_epoch().count()); }

struct Options {
  farm::dds::BusOptions bus;
  std::vector<size_t> sizes{64 << 10, 1 << 20, 8 << 20};
  double seconds = 3.0;
  std::string role = "reader";  // reader | writer | tcp-writer
  std::string writer_prefix;
  std::string tcp_limit_host;  // reader: also measure a TCP stream from the writer's side
  std::string connect;         // tcp-writer: reader's address
};

// Declares the options into o.
void add_options(CLI::App& app, Options& o) {
  app.description("TransitionBatch throughput between two processes over DDS (and a plain TCP stream).");
  farm::dds::add_bus_options(app, o.bus);
  bench::add_list(app, "--sizes", o.sizes, "Sample sizes in bytes (>= 64)")->check(CLI::Range(size_t(64), SIZE_MAX));
  bench::add_seconds(app, o.seconds, "Seconds measured per size");
  app.add_option("--role", o.role, "reader, writer or tcp-writer")
      ->check(CLI::IsMember({"reader", "writer", "tcp-writer"}))
      ->capture_default_str();
  app.add_option("--writer-prefix", o.writer_prefix,
                 "The command the writer copy of this program runs under (e.g. \"ip netns exec farm_b\")");
  app.add_option("--tcp-limit", o.tcp_limit_host,
                 "Reader: also measure a plain TCP stream from a writer that connects to HOST, the limit across hosts");
  app.add_option("--connect", o.connect, "Tcp-writer: the reader's address");
}

// A batch whose serialized payload is about `bytes`: pendulum-shaped transitions (obs 3, act 1),
// as many steps of 16 envs as fit.
void make_batch(size_t bytes, TransitionBatch& b) {
  constexpr int N = 16, kObs = 3, kAct = 1;
  const size_t per_step = N * (4 * kObs + 4 * kAct + 4 + 1 + 1 + 4);
  const int T = int(std::max<size_t>(1, bytes / per_step));
  b.experiment_id("bench_transport");
  b.worker_id("bench_writer");
  b.num_steps(T);
  b.num_envs(N);
  b.obs_dim(kObs);
  b.act_dim(kAct);
  const size_t steps = size_t(T) * N;
  std::vector<float> obs(steps * kObs);
  for (size_t i = 0; i < obs.size(); ++i) obs[i] = float(i % 1000) * 1e-3f;
  b.observations(std::move(obs));
  b.actions(std::vector<float>(steps * kAct, 0.5f));
  b.rewards(std::vector<float>(steps, -1.f));
  b.terminated(std::vector<uint8_t>(steps, 0));
  b.truncated(std::vector<uint8_t>(steps, 0));
  b.log_probs(std::vector<float>(steps, -0.9f));
  b.next_observations(std::vector<float>(N * kObs, 0.f));
}

size_t payload_bytes(const TransitionBatch& b) {
  return 4 * (b.observations().size() + b.actions().size() + b.rewards().size() + b.log_probs().size() +
              b.next_observations().size()) +
         b.terminated().size() + b.truncated().size();
}

std::vector<std::string> bus_args(const Options& o) {
  std::vector<std::string> a{"--domain", std::to_string(o.bus.domain)};
  if (!o.bus.profiles_file.empty()) a.insert(a.end(), {"--dds-profiles", o.bus.profiles_file});
  return a;
}

std::string self_exe() {
  char exe[4096] = {0};
  const ssize_t n = readlink("/proc/self/exe", exe, sizeof(exe) - 1);
  if (n <= 0) throw std::runtime_error("cannot read /proc/self/exe");
  return std::string(exe, size_t(n));
}

std::string quoted(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

// Starts this program with `args`, under the writer prefix if any.
pid_t spawn_self(const Options& o, const std::vector<std::string>& args) {
  std::string cmd = o.writer_prefix.empty() ? "" : o.writer_prefix + " ";
  cmd += quoted(self_exe());
  for (const auto& a : args) cmd += " " + quoted(a);
  std::fflush(stdout);
  const pid_t pid = fork();
  if (pid == 0) {
    execl("/bin/sh", "sh", "-c", cmd.c_str(), static_cast<char*>(nullptr));
    _exit(127);
  }
  return pid;
}

int wait_child(pid_t pid, double timeout_s) {
  const auto t0 = Clock::now();
  int status = 0;
  while (waitpid(pid, &status, WNOHANG) != pid) {
    if (since(t0) > timeout_s) {
      kill(pid, SIGKILL);
      waitpid(pid, &status, 0);
      return -1;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

int run_writer(const Options& o) {
  farm::dds::Bus bus(o.bus, "bench_transport writer");
  BatchWriter out(bus, farm::dds::kBatchTopic, "batch_writer");
  const auto t_match = Clock::now();
  while (out.matched() == 0) {
    if (since(t_match) > 20) {
      std::fprintf(stderr, "writer: no reader matched in 20 s\n");
      return 3;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  TransitionBatch b;
  make_batch(o.sizes.at(0), b);
  uint64_t seq = 0;
  const auto t0 = Clock::now();
  b.policy_version(ticks(t0));
  while (since(t0) < o.seconds) {
    b.sequence_number(seq);
    while (!out.write(b)) {
      if (since(t0) > o.seconds + 30) {
        std::fprintf(stderr, "writer: history stayed full for 30 s\n");
        return 4;
      }
    }
    ++seq;
  }
  TransitionBatch end;
  end.experiment_id("bench_transport");
  end.end_of_stream(true);
  end.sequence_number(seq);
  while (!out.write(end)) {
  }
  if (!out.wait_for_acks(30)) std::fprintf(stderr, "writer: not every batch acknowledged in 30 s\n");
  return 0;
}

struct Result {
  uint64_t batches = 0, lost = 0, duplicates = 0;
  double seconds = 0, bytes_per_batch = 0;
  bool complete = false;
};

Result read_batches(BatchReader& in, pid_t writer, double timeout_s) {
  Result r;
  std::vector<uint8_t> seen;
  TransitionBatch b;
  Clock::time_point first{}, last{};
  uint64_t expected = 0, first_ticks = 0;
  const auto t0 = Clock::now();
  while (!r.complete && since(t0) < timeout_s) {
    in.wait(0.05);
    while (in.take(b)) {
      if (b.end_of_stream()) {
        expected = b.sequence_number();
        r.complete = true;
        continue;
      }
      const uint64_t s = b.sequence_number();
      if (s >= seen.size()) seen.resize(std::max<size_t>(s + 1, 2 * seen.size()), 0);
      if (seen[s]++) ++r.duplicates;
      const auto now = Clock::now();
      if (r.batches == 0) {
        first_ticks = b.policy_version();
        r.bytes_per_batch = double(payload_bytes(b));
      }
      last = now;
      ++r.batches;
    }
    int status = 0;
    if (!r.complete && waitpid(writer, &status, WNOHANG) == writer) {
      std::fprintf(stderr, "writer exited early (status %d)\n", status);
      break;
    }
  }
  seen.resize(std::max<size_t>(seen.size(), expected), 0);
  for (uint64_t s = 0; s < expected; ++s) r.lost += seen[s] == 0;
  first = Clock::time_point(Clock::duration(first_ticks));
  r.seconds = std::chrono::duration<double>(last - first).count();
  return r;
}

double memcpy_bytes_per_second(size_t bytes, double seconds) {
  std::vector<char> a(bytes, 1), b(bytes, 2);
  uint64_t n = 0;
  const auto t0 = Clock::now();
  double el = 0;
  do {
    std::memcpy((n & 1) ? a.data() : b.data(), (n & 1) ? b.data() : a.data(), bytes);
    ++n;
    el = since(t0);
  } while (el < seconds);
  return double(n) * double(bytes) / el;
}

int run_tcp_writer(const Options& o) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(kTcpPort);
  if (inet_pton(AF_INET, o.connect.c_str(), &addr.sin_addr) != 1) {
    std::fprintf(stderr, "tcp-writer: bad address '%s'\n", o.connect.c_str());
    return 2;
  }
  const auto t0 = Clock::now();
  while (connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    if (since(t0) > 10) {
      std::perror("tcp-writer: connect");
      return 3;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  std::vector<char> buf(o.sizes.at(0), 7);
  const auto t1 = Clock::now();
  while (since(t1) < o.seconds) {
    size_t off = 0;
    while (off < buf.size()) {
      const ssize_t k = send(fd, buf.data() + off, buf.size() - off, 0);
      if (k <= 0) return 4;
      off += size_t(k);
    }
  }
  close(fd);
  return 0;
}

// Bytes/s of a plain TCP stream from a writer started like the DDS writer (same prefix).
double tcp_bytes_per_second(const Options& o, size_t bytes) {
  const int ls = socket(AF_INET, SOCK_STREAM, 0);
  const int one = 1;
  setsockopt(ls, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(kTcpPort);
  addr.sin_addr.s_addr = htonl(INADDR_ANY);
  if (bind(ls, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0 || listen(ls, 1) != 0) {
    std::perror("tcp limit: bind/listen");
    return 0;
  }
  const pid_t w = spawn_self(o, {"--role", "tcp-writer", "--connect", o.tcp_limit_host, "--sizes",
                                 std::to_string(bytes), "--seconds", std::to_string(o.seconds)});
  const int fd = accept(ls, nullptr, nullptr);
  close(ls);
  std::vector<char> buf(1 << 20);
  uint64_t total = 0;
  Clock::time_point first{};
  for (;;) {
    const ssize_t k = recv(fd, buf.data(), buf.size(), 0);
    if (k <= 0) break;
    if (total == 0) first = Clock::now();
    total += uint64_t(k);
  }
  const double el = since(first);
  close(fd);
  wait_child(w, 30);
  return el > 0 ? double(total) / el : 0;
}

int run_reader(const Options& o) {
  farm::dds::Bus bus(o.bus, "bench_transport reader");
  BatchReader in(bus, farm::dds::kBatchTopic, "batch_reader");
  std::printf("bench_transport: profiles %s, %.1f s per size%s\n", bus.profiles_file().c_str(), o.seconds,
              o.writer_prefix.empty() ? "" : (", writer under: " + o.writer_prefix).c_str());
  std::printf("%10s %12s %10s %8s %6s %12s %12s %7s\n", "batch", "payload MB/s", "batches/s", "batches", "lost",
              "limit", "limit MB/s", "ratio");
  bool ok = true;
  for (size_t size : o.sizes) {
    std::vector<std::string> args{
        "--role", "writer", "--sizes", std::to_string(size), "--seconds", std::to_string(o.seconds)};
    const auto bus_a = bus_args(o);
    args.insert(args.end(), bus_a.begin(), bus_a.end());
    const pid_t w = spawn_self(o, args);
    const Result r = read_batches(in, w, o.seconds + 60);
    const int status = wait_child(w, 40);
    const double mbps = r.seconds > 0 ? r.batches * r.bytes_per_batch / r.seconds / 1e6 : 0;
    const double bps = r.seconds > 0 ? r.batches / r.seconds : 0;
    double limit = 0;
    const char* limit_name = "memcpy";
    if (!o.tcp_limit_host.empty()) {
      limit = tcp_bytes_per_second(o, size) / 1e6;
      limit_name = "tcp";
    } else {
      limit = memcpy_bytes_per_second(size, std::min(1.0, o.seconds)) / 1e6;
    }
    const bool good = r.complete && r.lost == 0 && r.duplicates == 0 && status == 0;
    ok = ok && good;
    std::printf("%10zu %12.1f %10.1f %8llu %6llu %12s %12.1f %7.3f%s\n", size, mbps, bps, (unsigned long long)r.batches,
                (unsigned long long)r.lost, limit_name, limit, limit > 0 ? mbps / limit : 0.0,
                good ? "" : (r.complete ? "  DUPLICATES OR WRITER ERROR" : "  INCOMPLETE"));
    std::fflush(stdout);
  }
  return ok ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  farm::cli::App app("bench_transport");
  add_options(app, o);
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  try {
    if (o.role == "writer") return run_writer(o);
    if (o.role == "tcp-writer") return run_tcp_writer(o);
    if (o.role == "reader") return run_reader(o);
    throw std::invalid_argument("--role must be reader, writer or tcp-writer");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_transport: %s\n", e.what());
    return 2;
  }
}
