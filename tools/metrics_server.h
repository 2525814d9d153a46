// The HTTP endpoint of farm-monitor --prometheus ADDR:PORT: civetweb (Debian's libcivetweb-dev)
// serves GET /metrics with the latest page the monitor published (the Prometheus text format),
// and nothing else: no files, no other paths, no methods but GET and HEAD.
#pragma once

#include <mutex>
#include <string>

struct mg_connection;
struct mg_context;

namespace farm {

class MetricsServer {
 public:
  // ADDR:PORT as given to --prometheus: ADDR an IPv4 address (127.0.0.1: this host only; 0.0.0.0:
  // every interface), PORT in 1..65535. Throws std::invalid_argument naming what is wrong.
  static std::string parse_listen_address(const std::string& addr_port);

  // Listens on addr_port (checked as above); throws std::runtime_error with civetweb's reason
  // when it cannot (address in use, not an address of this host).
  explicit MetricsServer(const std::string& addr_port);
  ~MetricsServer();
  MetricsServer(const MetricsServer&) = delete;
  MetricsServer& operator=(const MetricsServer&) = delete;

  // The page /metrics answers with from now on.
  void publish(std::string page);

  // http://ADDR:PORT/metrics
  std::string url() const { return "http://" + listen_ + "/metrics"; }

 private:
  static int handle(mg_connection* conn, void* self);

  std::string listen_;
  mg_context* ctx_ = nullptr;
  std::mutex mu_;
  std::string page_;
};

}  // namespace farm
