// EventChecker: compares the daemon's events with what the simulator expects, frame by frame.
//
// The producer states, for each frame it publishes, the pairs that began and ended in it (the
// set difference of Bullet's pairs between two steps). The daemon's event parts arrive on a
// listener thread, which stamps each with its arrival time and gathers a frame's parts until its
// last one; Collect then compares every frame both sides have finished, in frame order.
// A frame is matched by EventBatch.source_frame (the producer's frame number that closed it);
// events of frames another producer closed, snapshot parts and interest streams are ignored.
// Pairs are producer-local ids (a << 32 | b, a < b; ids below 2^32) on both sides. A frame whose
// events do not arrive while a later frame's do is reported as not received.
//
// Thread safety: Expect and Collect from one thread; the listener thread is internal.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "bp/client/subscriber.h"
#include "bp/status.h"

namespace bp::examples {

/// One frame compared.
struct FrameCheck {
  uint64_t frame = 0;
  uint64_t expected = 0;         ///< events expected (collides + uncollides)
  uint64_t received = 0;         ///< events received
  uint64_t missing = 0;          ///< expected events not received
  uint64_t unexpected = 0;       ///< received events not expected
  uint64_t foreign = 0;          ///< received events naming another producer's object (ignored)
  double latency_ms = 0;         ///< the frame's publication to its last part's arrival
  bool arrived = true;           ///< false: the frame's events never arrived
  std::string first_difference;  ///< "" when the frame matched
};

class EventChecker {
 public:
  /// Subscribes to the events on connection (which must outlive the checker) and starts
  /// listening; producer is the one whose frames are compared.
  static Status Start(client::Connection& connection, uint32_t producer,
                      std::unique_ptr<EventChecker>* out);
  ~EventChecker();
  /// Waits until the daemon's events writer has matched.
  Status WaitForDaemon(std::chrono::milliseconds timeout) const;
  /// The events expected for frame (sorted pair lists), published at sent_ns (CLOCK_REALTIME).
  void Expect(uint64_t frame, uint64_t sent_ns, std::vector<uint64_t> uncollide,
              std::vector<uint64_t> collide);
  /// Compares the frames that both sides have finished, oldest first, calling f for each.
  void Collect(const std::function<void(const FrameCheck&)>& f);
  /// Frames expected and not yet compared.
  size_t pending() const { return expected_.size(); }
  /// Envelopes lost between the daemon and this subscriber (then some frames never complete).
  uint64_t gaps() const { return subscriber_->gaps(); }
  /// Why the listener stopped (ok while it runs).
  Status listen_status() const { return subscriber_->listen_status(); }

 private:
  struct Received {
    std::vector<uint64_t> uncollide, collide;
    uint64_t foreign = 0;
    uint64_t arrived_ns = 0;
    bool complete = false;
  };
  struct Expected {
    uint64_t sent_ns = 0;
    std::vector<uint64_t> uncollide, collide;
  };
  EventChecker() = default;
  void OnPart(const wire::EventBatch& part);

  uint32_t producer_ = 0;
  std::unique_ptr<client::EventSubscriber> subscriber_;
  std::map<uint64_t, Expected> expected_;  // by the producer's frame
  std::mutex mutex_;                       // guards received_
  std::map<uint64_t, Received> received_;  // by source_frame
};

}  // namespace bp::examples
