#include "removal_filter.h"

#include <fastdds/rtps/transport/ChainingTransport.h>
#include <fastdds/rtps/transport/UDPTransportDescriptor.h>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastdds/rtps/transport/shared_mem/SharedMemTransportDescriptor.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <utility>

namespace farm::dds {

namespace {
constexpr uint8_t kSubmsgPad = 0x01, kSubmsgInfoTs = 0x09, kSubmsgData = 0x15, kSubmsgDataFrag = 0x16;
constexpr uint16_t kPidSentinel = 0x0001, kPidStatusInfo = 0x0071;
}  // namespace

bool carries_participant_removal(const uint8_t* m, size_t n) {
  if (n < 20 || std::memcmp(m, "RTPS", 4) != 0) return false;
  size_t at = 20;  // past the header: protocol, version, vendor, GUID prefix
  while (at + 4 <= n) {
    const uint8_t id = m[at], flags = m[at + 1];
    const bool le = flags & 0x01;
    const auto u16 = [&](size_t p) { return le ? uint16_t(m[p] | m[p + 1] << 8) : uint16_t(m[p] << 8 | m[p + 1]); };
    const size_t body = at + 4;
    size_t len = u16(at + 2);
    if (len == 0 && id != kSubmsgPad && id != kSubmsgInfoTs) len = n - body;  // the last one: to the end
    if (len > n - body) return false;  // cut short: Fast DDS reads no further either
    static constexpr uint8_t kSpdpWriter[4] = {0x00, 0x01, 0x00, 0xc2};
    if ((id == kSubmsgData || id == kSubmsgDataFrag) && len >= 20 && std::memcmp(m + body + 8, kSpdpWriter, 4) == 0) {
      // DATA: Q 0x02, D 0x04, K 0x08; DATA_FRAG: Q 0x02, K 0x04. An announcement carries its data;
      // a key alone, or a status saying disposed or unregistered, is a removal.
      if (id == kSubmsgData ? !(flags & 0x04) : (flags & 0x04)) return true;
      if (flags & 0x02) {
        size_t q = body + 4 + u16(body + 2);  // octetsToInlineQos counts from the end of its own field
        while (q + 4 <= body + len) {
          const uint16_t pid = u16(q), plen = u16(q + 2);
          if (pid == kPidSentinel || q + 4 + plen > body + len) break;
          if (pid == kPidStatusInfo && plen >= 4 && (m[q + 7] & 0x03)) return true;
          q += 4 + plen;
        }
      }
    }
    at = body + len;
  }
  return false;
}

// Participant removals from the network are not believed. An SPDP DATA(p[UD]) (the message a
// participant sends as it leaves) carries no proof of its sender, with or without DDS Security in
// Fast DDS 2.9: anyone who can send a UDP datagram to a process's discovery port can name the
// learner in one, and Fast DDS then unmatches every endpoint of the learner at once (the workers
// stopped sending and waited; env steps/s fell to 621 of 8,860 without security and to 0 with it,
// where the learner must authenticate again). Every UDP datagram a farm process receives therefore
// passes this filter first, which drops one that carries such a removal: a participant is dropped
// only when its lease runs out (6 s in the shipped profiles), that is when its own traffic stops,
// which a forger cannot stop. Shared memory is not filtered: only this host's processes reach it.
namespace {

std::atomic<uint64_t> g_removals_dropped{0};
std::atomic<int64_t> g_removal_note_s{-1000000};

class RemovalFilterTransport : public eprosima::fastdds::rtps::ChainingTransport {
 public:
  explicit RemovalFilterTransport(const eprosima::fastdds::rtps::ChainingTransportDescriptor& d)
      : ChainingTransport(d) {}

  eprosima::fastdds::rtps::TransportDescriptorInterface* get_configuration() override {
    return low_level_transport_->get_configuration();
  }

  bool send(eprosima::fastrtps::rtps::SenderResource* low, const eprosima::fastrtps::rtps::octet* buffer, uint32_t size,
            eprosima::fastdds::rtps::LocatorsIterator* begin, eprosima::fastdds::rtps::LocatorsIterator* end,
            const std::chrono::steady_clock::time_point& timeout) override {
    return low->send(buffer, size, begin, end, timeout);
  }

  void receive(eprosima::fastdds::rtps::TransportReceiverInterface* next, const eprosima::fastrtps::rtps::octet* buffer,
               uint32_t size, const eprosima::fastrtps::rtps::Locator_t& local,
               const eprosima::fastrtps::rtps::Locator_t& remote) override {
    if (carries_participant_removal(buffer, size)) {
      // Counted, and said on stderr at most once per 10 s with the count so far.
      const uint64_t n = g_removals_dropped.fetch_add(1) + 1;
      const int64_t now_s =
          std::chrono::duration_cast<std::chrono::seconds>(std::chrono::steady_clock::now().time_since_epoch()).count();
      int64_t last = g_removal_note_s.load();
      if (now_s - last >= 10 && g_removal_note_s.compare_exchange_strong(last, now_s))
        std::fprintf(stderr,
                     "ignored %llu participant removal message(s) received over UDP so far: a participant is "
                     "dropped when its lease runs out\n",
                     static_cast<unsigned long long>(n));
      return;
    }
    next->OnDataReceived(buffer, size, local, remote);
  }
};

struct RemovalFilterDescriptor : eprosima::fastdds::rtps::ChainingTransportDescriptor {
  explicit RemovalFilterDescriptor(std::shared_ptr<eprosima::fastdds::rtps::TransportDescriptorInterface> low)
      : ChainingTransportDescriptor(std::move(low)) {}
  eprosima::fastdds::rtps::TransportInterface* create_transport() const override {
    return new RemovalFilterTransport(*this);
  }
};

}  // namespace

// Every UDP transport of the participant behind the filter. Only with Fast DDS's simple discovery,
// where each process checks every remote participant's lease: a Discovery Server's clients learn
// of a departure only from the server's relayed removal (that setting is for a trusted network).
// ROS_DISCOVERY_SERVER makes Fast DDS turn a participant of simple discovery into such a client
// when it is created, after these QoS are read, so a set variable counts as a Discovery Server.
void filter_participant_removals(eprosima::fastdds::dds::DomainParticipantQos& q) {
  using eprosima::fastdds::rtps::UDPTransportDescriptor;
  using eprosima::fastrtps::rtps::DiscoveryProtocol;
  if (q.wire_protocol().builtin.discovery_config.discoveryProtocol != DiscoveryProtocol::SIMPLE) return;
  if (const char* servers = std::getenv("ROS_DISCOVERY_SERVER"); servers && *servers) return;
  auto& t = q.transport();
  if (t.use_builtin_transports) {
    // Fast DDS's builtin set: shared memory and UDPv4, made explicit so that UDP can be wrapped.
    t.use_builtin_transports = false;
    t.user_transports.push_back(std::make_shared<eprosima::fastdds::rtps::SharedMemTransportDescriptor>());
    t.user_transports.push_back(std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>());
  }
  for (auto& d : t.user_transports)
    if (std::dynamic_pointer_cast<UDPTransportDescriptor>(d)) d = std::make_shared<RemovalFilterDescriptor>(d);
}

}  // namespace farm::dds
