// The filter every farm participant puts in front of its UDP transports: participant removals
// received from the network are dropped unread (removal_filter.cpp says why).
#pragma once

#include <fastdds/dds/domain/qos/DomainParticipantQos.hpp>

#include <cstddef>
#include <cstdint>

namespace farm::dds {

// Whether the RTPS message of n bytes at m carries a participant's removal (an SPDP DATA with a key
// alone, or with a status of disposed or unregistered). Every farm participant drops such a
// datagram from UDP unread (Bus): a participant is dropped only when its lease runs out.
bool carries_participant_removal(const uint8_t* m, size_t n);

// Puts every UDP transport of q behind the filter, where q uses Fast DDS's simple discovery.
void filter_participant_removals(eprosima::fastdds::dds::DomainParticipantQos& q);

}  // namespace farm::dds
