// bp::transport::WallClockNs: the clock of every *_time_ns field of the wire (broadphase.proto):
// CLOCK_REALTIME in nanoseconds, so that times taken on different hosts compare (as well as
// their clocks agree).
//
// Thread safety: safe.
#pragma once

#include <cstdint>

namespace bp::transport {

/// Current CLOCK_REALTIME in nanoseconds.
uint64_t WallClockNs();

}  // namespace bp::transport
