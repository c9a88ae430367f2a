// bp::client::Subscriber<Msg>: receives EventBatch or Status messages from the daemon.
//
// Poll waits up to a timeout for messages, parses them and appends them to the output. A
// payload that does not parse is counted (malformed()) and skipped, never handed out. Gaps in
// the envelope sequence (a slow subscriber's KEEP_LAST history overwrote batches) are counted
// in gaps() so the application can tell that it missed events.
//
// Thread safety: one thread at a time per subscriber (Listen's thread counts as that thread).
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <thread>
#include <unordered_map>
#include <vector>

#include "broadphase.pb.h"

#include "bp/client/connection.h"
#include "bp/status.h"

namespace bp::client {

template <class Msg>
class Subscriber {
 public:
  /// A subscriber on the events topic (Msg = wire::EventBatch) or the status topic
  /// (Msg = wire::DaemonStatus), keeping the newest depth messages until polled. With interest
  /// (events only), it receives that interest's stream (InterestClient), and nothing else.
  static Status Create(Connection& connection, int32_t depth, std::unique_ptr<Subscriber>* out,
                       uint64_t interest = 0);
  /// Waits until the daemon's writer has matched.
  Status WaitForDaemon(std::chrono::milliseconds timeout) const {
    return reader_.WaitForWriters(1, timeout);
  }
  /// Appends the messages available within timeout (possibly none) to out.
  Status Poll(std::chrono::milliseconds timeout, std::vector<Msg>* out);
  /// Calls f for each message on a thread of its own, until StopListening() or destruction
  /// (the callback style; do not Poll while listening). f must not throw. A transport error
  /// ends the listener; it is logged (spdlog) and kept in listen_status().
  Status Listen(std::function<void(const Msg&)> f);
  /// Stops the listening thread and waits for it (idempotent). Called from inside the callback,
  /// it only asks the thread to end (the thread cannot wait for itself); do not destroy the
  /// subscriber from its own callback.
  void StopListening();
  /// Why the listener thread ended early (ok while it runs or after StopListening()).
  Status listen_status() const;
  ~Subscriber() { StopListening(); }
  /// Payloads that did not parse.
  uint64_t malformed() const { return malformed_.load(); }
  /// Envelopes missing between consecutive sequence numbers received from one writer. Each
  /// writer (a restarted daemon is a new one) is counted from the first number it delivers.
  uint64_t gaps() const { return gaps_.load(); }

 private:
  Subscriber() = default;
  dds::Reader reader_;
  dds::WaitSet waitset_;
  std::thread listener_;
  std::atomic<bool> listening_{false};
  mutable std::mutex listen_mutex_;
  Status listen_status_;
  // The last sequence number received from each writer (by publication handle): a restarted
  // daemon is a new writer whose numbers start again.
  std::unordered_map<uint64_t, uint64_t> last_seq_;
  // Atomic: read by the application while the listener thread counts.
  std::atomic<uint64_t> malformed_{0};
  std::atomic<uint64_t> gaps_{0};
};

using EventSubscriber = Subscriber<wire::EventBatch>;
using StatusSubscriber = Subscriber<wire::DaemonStatus>;

extern template class Subscriber<wire::EventBatch>;
extern template class Subscriber<wire::DaemonStatus>;

}  // namespace bp::client
