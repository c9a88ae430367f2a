// Shared pieces of the daemon tests: a loopback configuration with a partition of its own per
// test process (gtest_discover_tests runs each test as a process, two at a time, so the same
// domain id is shared by concurrent tests; the partition keeps them apart), collectors of events
// and status reports, and the brute-force oracle with the daemon's global keys.
#pragma once

#include <algorithm>
#include <chrono>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "config.h"
#include "daemon.h"
#include "engine_host.h"
#include <gtest/gtest.h>
#include <unistd.h>

#include "bp/brute_force.h"
#include "bp/client/batch_builder.h"
#include "bp/client/overlap_view.h"
#include "bp/client/subscriber.h"
#include "bp/client/update_publisher.h"
#include "bp/tools/scene_frame.h"
#include "bp/transport/connection.h"

namespace bp::test {

using namespace std::chrono_literals;
using namespace ::bp::workload;
using PairList = std::vector<std::pair<uint64_t, uint64_t>>;

#define BP_ASSERT_OK(expr)                                 \
  do {                                                     \
    const ::bp::Status bp_status_ = (expr);                \
    ASSERT_TRUE(bp_status_.ok()) << bp_status_.ToString(); \
  } while (0)

inline std::string SourcePath(const std::string& relative) {
  return std::string(BP_SOURCE_DIR) + "/" + relative;
}

/// A partition unique to this process and test.
inline std::string TestPartition() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  return "bp-test-" + std::to_string(getpid()) + "-" + (info ? info->name() : "none");
}

/// Daemon configuration for tests: loopback, this binary's domain, a partition of its own.
inline service::Config TestConfig(uint32_t domain) {
  service::Config config;
  config.dds.domain = domain;
  config.dds.cyclone_config = SourcePath("config/cyclonedds-loopback.xml");
  config.dds.partition = TestPartition();
  config.logging.summary_interval_s = 0;
  config.engine.algorithm = "segmented_sap";
  return config;
}

inline transport::ConnectionOptions ClientOptions(const service::Config& config) {
  transport::ConnectionOptions options;
  options.domain = config.dds.domain;
  EXPECT_TRUE(transport::ReadTextFile(config.dds.cyclone_config, &options.cyclone_xml).ok());
  options.partition = config.dds.partition;
  options.topics = {config.dds.topics.updates, config.dds.topics.events, config.dds.topics.status};
  return options;
}

/// The events of one daemon frame, merged over its parts.
struct FrameEvents {
  uint64_t frame = 0;
  uint32_t parts = 0;
  PairList uncollide;
  PairList collide;
  wire::EventBatch last;  // the final part (source fields, objects, overlaps)
};

/// Collects EventBatch parts into frames.
class EventCollector {
 public:
  explicit EventCollector(transport::Connection& connection) {
    EXPECT_TRUE(client::EventSubscriber::Create(connection, 1000, &sub_).ok());
  }
  client::EventSubscriber& subscriber() { return *sub_; }
  /// Waits for the complete frame `frame` (all parts), up to timeout.
  bool WaitFrame(uint64_t frame, FrameEvents* out, std::chrono::milliseconds timeout = 10s) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    for (;;) {
      auto it = complete_.find(frame);
      if (it != complete_.end()) {
        *out = it->second;
        return true;
      }
      if (std::chrono::steady_clock::now() > deadline) return false;
      std::vector<wire::EventBatch> batches;
      if (!sub_->Poll(50ms, &batches).ok()) return false;
      for (auto& b : batches) Add(b);
    }
  }
  /// Waits for the next complete frame after the last one this returned (whatever its number).
  bool NextFrame(FrameEvents* out, std::chrono::milliseconds timeout = 10s) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    for (;;) {
      auto it = complete_.upper_bound(last_returned_);
      if (it != complete_.end()) {
        last_returned_ = it->first;
        *out = it->second;
        return true;
      }
      if (std::chrono::steady_clock::now() > deadline) return false;
      std::vector<wire::EventBatch> batches;
      if (!sub_->Poll(50ms, &batches).ok()) return false;
      for (auto& b : batches) Add(b);
    }
  }
  /// Frames completed so far (received, not necessarily asked for).
  size_t completed() const { return complete_.size(); }
  /// Sequence numbers seen, in order.
  const std::vector<uint64_t>& sequences() const { return sequences_; }

 private:
  void Add(const wire::EventBatch& b) {
    sequences_.push_back(b.sequence());
    if (b.snapshot()) return;  // frames only (OverlapView takes snapshots)
    FrameEvents& f = partial_[b.frame()];
    f.frame = b.frame();
    EXPECT_EQ(b.part(), f.parts) << "parts of frame " << b.frame() << " out of order";
    ++f.parts;
    for (auto& p : client::Pairs(b.uncollide())) f.uncollide.push_back(p);
    for (auto& p : client::Pairs(b.collide())) f.collide.push_back(p);
    if (b.last_part()) {
      f.last = b;
      complete_[b.frame()] = std::move(f);
      partial_.erase(b.frame());
    }
  }
  std::unique_ptr<client::EventSubscriber> sub_;
  std::map<uint64_t, FrameEvents> partial_;
  std::map<uint64_t, FrameEvents> complete_;
  std::vector<uint64_t> sequences_;
  uint64_t last_returned_ = 0;
};

/// Collects rejections from status reports.
class RejectionCollector {
 public:
  explicit RejectionCollector(transport::Connection& connection) {
    EXPECT_TRUE(client::StatusSubscriber::Create(connection, 1000, &sub_).ok());
  }
  client::StatusSubscriber& subscriber() { return *sub_; }
  /// Waits until at least n rejections have arrived in total.
  bool WaitFor(size_t n, std::chrono::milliseconds timeout = 10s) {
    return PollUntil([&] { return rejections_.size() >= n; }, timeout);
  }
  /// Waits until some report (received now or before) satisfies pred.
  bool WaitUntil(const std::function<bool(const wire::DaemonStatus&)>& pred,
                 std::chrono::milliseconds timeout = 10s) {
    size_t checked = 0;
    return PollUntil(
        [&] {
          for (; checked < reports_.size(); ++checked) {
            if (pred(reports_[checked])) return true;
          }
          return false;
        },
        timeout);
  }
  /// Collects whatever arrives for the given time.
  void Collect(std::chrono::milliseconds duration) {
    (void)PollUntil([] { return false; }, duration);
  }
  const std::vector<wire::Rejection>& rejections() const { return rejections_; }
  const std::vector<wire::DaemonStatus>& reports() const { return reports_; }
  uint64_t not_listed() const { return not_listed_; }
  /// The rejection of (op, index), or null.
  const wire::Rejection* Find(wire::Op op, uint32_t index) const {
    for (auto& r : rejections_) {
      if (r.op() == op && r.index() == index) return &r;
    }
    return nullptr;
  }

 private:
  bool PollUntil(const std::function<bool()>& done, std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (!done()) {
      if (std::chrono::steady_clock::now() > deadline) return false;
      std::vector<wire::DaemonStatus> reports;
      if (!sub_->Poll(50ms, &reports).ok()) return false;
      for (auto& r : reports) {
        for (auto& j : r.rejections()) rejections_.push_back(j);
        not_listed_ += r.rejections_not_listed();
        reports_.push_back(r);
      }
    }
    return true;
  }

  std::unique_ptr<client::StatusSubscriber> sub_;
  std::vector<wire::Rejection> rejections_;
  std::vector<wire::DaemonStatus> reports_;
  uint64_t not_listed_ = 0;
};

/// The daemon on a thread of this process.
class InProcessDaemon {
 public:
  explicit InProcessDaemon(const service::Config& config) {
    Status s = service::Daemon::Create(config, &daemon_);
    EXPECT_TRUE(s.ok()) << s.ToString();
    if (!daemon_) return;
    thread_ = std::thread([this] { run_status_ = daemon_->Run(); });
    const auto deadline = std::chrono::steady_clock::now() + 10s;
    while (!daemon_->serving() && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(1ms);
    }
  }
  ~InProcessDaemon() { (void)Stop(); }
  service::Daemon& daemon() { return *daemon_; }
  /// Asks the daemon to stop and waits; the Status Run() returned.
  Status Stop() {
    if (thread_.joinable()) {
      daemon_->RequestStop();
      thread_.join();
    }
    return run_status_;
  }

 private:
  std::unique_ptr<service::Daemon> daemon_;
  std::thread thread_;
  Status run_status_;
};

/// The brute-force oracle keyed like the daemon (producer << 48 | id).
template <int K>
class Oracle {
 public:
  void Insert(uint32_t producer, const SceneBox& b) {
    EXPECT_TRUE(engine_.Insert(service::GlobalKey(producer, b.id), ToBox<K, float>(b, 1.0)).ok());
  }
  void Update(uint32_t producer, const SceneBox& b) {
    EXPECT_TRUE(engine_.Update(service::GlobalKey(producer, b.id), ToBox<K, float>(b, 1.0)).ok());
  }
  void Erase(uint32_t producer, uint64_t id) {
    EXPECT_TRUE(engine_.Erase(service::GlobalKey(producer, id)).ok());
  }
  void Apply(uint32_t producer, const FrameOps& ops) {
    for (uint64_t id : ops.erases) Erase(producer, id);
    for (const auto& b : ops.inserts) Insert(producer, b);
    for (const auto& b : ops.updates) Update(producer, b);
  }
  void Query(PairList* uncollide, PairList* collide) {
    struct Sink final : EventSink<uint64_t> {
      PairList* u;
      PairList* c;
      void Collide(const uint64_t& a, const uint64_t& b) override { c->emplace_back(a, b); }
      void Uncollide(const uint64_t& a, const uint64_t& b) override { u->emplace_back(a, b); }
    } sink;
    uncollide->clear();
    collide->clear();
    sink.u = uncollide;
    sink.c = collide;
    engine_.Query(sink);
  }
  size_t Size() const { return engine_.Size(); }
  /// The overlapping pairs as of the last Query, sorted.
  PairList Pairs() const {
    PairList out;
    engine_.ForEachOverlap([&](const uint64_t& a, const uint64_t& b) { out.emplace_back(a, b); });
    std::sort(out.begin(), out.end());
    return out;
  }

 private:
  BruteForce<K, float, uint64_t> engine_;
};

/// Drives an OverlapView from a subscriber until done(view) holds while it is synced (asking for
/// a snapshot when it wants one, and again every 500 ms while none arrives).
inline bool SyncUntil(client::EventSubscriber& sub, client::SnapshotRequester& requests,
                      client::OverlapView& view,
                      const std::function<bool(const client::OverlapView&)>& done,
                      std::chrono::milliseconds timeout = 15s, uint64_t interest = 0) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  auto asked = std::chrono::steady_clock::time_point{};
  while (!(view.synced() && done(view))) {
    const auto now = std::chrono::steady_clock::now();
    if (now > deadline) return false;
    if (view.wants_snapshot() && now - asked > 500ms) {
      EXPECT_TRUE(requests.Request("test", interest).ok());
      asked = now;
    }
    std::vector<wire::EventBatch> parts;
    if (!sub.Poll(50ms, &parts).ok()) return false;
    for (const auto& p : parts) {
      if (view.Apply(p)) asked = {};  // lost: ask at once
    }
  }
  return true;
}

/// SyncUntil the view is synced at daemon frame `frame` (of the epoch it follows).
inline bool SyncTo(client::EventSubscriber& sub, client::SnapshotRequester& requests,
                   client::OverlapView& view, uint64_t frame,
                   std::chrono::milliseconds timeout = 15s, uint64_t interest = 0) {
  return SyncUntil(
      sub, requests, view, [frame](const client::OverlapView& v) { return v.frame() == frame; },
      timeout, interest);
}

}  // namespace bp::test
