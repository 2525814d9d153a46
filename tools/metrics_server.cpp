// farm-monitor's /metrics endpoint through civetweb (metrics_server.h).
#include "metrics_server.h"

#include <arpa/inet.h>
#include <civetweb.h>

#include <cstring>
#include <stdexcept>
#include <utility>

namespace farm {

namespace {

// civetweb reports why it could not start (the bind error) only to its log callback, which runs on
// the thread calling mg_start2: the messages are collected here while the server starts.
thread_local std::string* g_start_log = nullptr;

int on_log(const mg_connection*, const char* message) {
  if (g_start_log && message) {
    if (!g_start_log->empty()) *g_start_log += "; ";
    *g_start_log += message;
  }
  return 1;  // handled: civetweb writes nothing itself
}

void respond(mg_connection* conn, int code, const char* reason, const std::string& body, bool with_body,
             const char* extra_headers = "") {
  const std::string head =
      "HTTP/1.1 " + std::to_string(code) + " " + reason +
      "\r\nContent-Type: text/plain; charset=utf-8\r\nContent-Length: " + std::to_string(body.size()) +
      "\r\nCache-Control: no-store\r\n" + extra_headers + "Connection: close\r\n\r\n";
  mg_write(conn, head.data(), head.size());
  if (with_body) mg_write(conn, body.data(), body.size());
}

}  // namespace

std::string MetricsServer::parse_listen_address(const std::string& v) {
  const auto bad = [&](const std::string& why) {
    return std::invalid_argument("--prometheus '" + v + "': " + why +
                                 " (expected ADDR:PORT, ADDR an IPv4 address: 127.0.0.1 for this host only, "
                                 "0.0.0.0 for every interface; PORT in 1..65535)");
  };
  const size_t colon = v.rfind(':');
  if (colon == std::string::npos) throw bad("no port");
  const std::string addr = v.substr(0, colon), port = v.substr(colon + 1);
  in_addr a;
  if (addr.empty() || inet_pton(AF_INET, addr.c_str(), &a) != 1) throw bad("'" + addr + "' is not an IPv4 address");
  if (port.empty() || port.size() > 5 || port.find_first_not_of("0123456789") != std::string::npos)
    throw bad("port '" + port + "' is not a number");
  const long p = std::stol(port);
  if (p < 1 || p > 65535) throw bad("port " + port + " is out of range");
  char canonical[INET_ADDRSTRLEN];
  inet_ntop(AF_INET, &a, canonical, sizeof(canonical));
  return std::string(canonical) + ":" + std::to_string(p);
}

MetricsServer::MetricsServer(const std::string& addr_port) : listen_(parse_listen_address(addr_port)) {
  mg_init_library(0);
  // No document_root: civetweb serves no files, only the handler below. Connections are closed
  // after each answer and a request may take at most 10 s, so no client holds a thread long.
  const char* options[] = {"listening_ports", listen_.c_str(),     "num_threads", "4",    "request_timeout_ms",
                           "10000",           "enable_keep_alive", "no",          nullptr};
  mg_callbacks callbacks;
  std::memset(&callbacks, 0, sizeof(callbacks));
  callbacks.log_message = on_log;
  mg_init_data init;
  init.callbacks = &callbacks;
  init.user_data = this;
  init.configuration_options = options;
  unsigned code = 0;
  char text[256] = "";
  mg_error_data error{&code, text, sizeof(text)};
  std::string log;
  g_start_log = &log;
  ctx_ = mg_start2(&init, &error);
  g_start_log = nullptr;
  if (!ctx_) {
    mg_exit_library();
    throw std::runtime_error("--prometheus " + listen_ + ": cannot serve there: " + (log.empty() ? text : log));
  }
  mg_set_request_handler(ctx_, "/", &MetricsServer::handle, this);
}

MetricsServer::~MetricsServer() {
  mg_stop(ctx_);
  mg_exit_library();
}

void MetricsServer::publish(std::string page) {
  std::lock_guard<std::mutex> lk(mu_);
  page_ = std::move(page);
}

int MetricsServer::handle(mg_connection* conn, void* self_ptr) {
  auto* self = static_cast<MetricsServer*>(self_ptr);
  const mg_request_info* ri = mg_get_request_info(conn);
  const std::string method = ri && ri->request_method ? ri->request_method : "";
  const std::string uri = ri && ri->local_uri ? ri->local_uri : "";
  const bool head = method == "HEAD";
  if (uri != "/metrics") {
    respond(conn, 404, "Not Found", "farm-monitor serves /metrics only\n", !head);
    return 404;
  }
  if (method != "GET" && !head) {
    respond(conn, 405, "Method Not Allowed", "/metrics answers GET and HEAD only\n", true, "Allow: GET, HEAD\r\n");
    return 405;
  }
  std::string page;
  {
    std::lock_guard<std::mutex> lk(self->mu_);
    page = self->page_;
  }
  if (page.empty()) {
    respond(conn, 503, "Service Unavailable", "no snapshot of the farm yet\n", !head);
    return 503;
  }
  const std::string headers =
      "HTTP/1.1 200 OK\r\nContent-Type: text/plain; version=0.0.4; charset=utf-8\r\n"
      "Content-Length: " +
      std::to_string(page.size()) + "\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n";
  mg_write(conn, headers.data(), headers.size());
  if (!head) mg_write(conn, page.data(), page.size());
  return 200;
}

}  // namespace farm
