// The daemon's subscribers: late, lagging and restarted ones resync from snapshots, one that
// never reads stalls nothing, the client library's callback style, snapshot rate limits.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <limits>
#include <mutex>
#include <set>
#include <sstream>
#include <string>
#include <tuple>

#include "daemon_test_support.h"

namespace bp::test {
namespace {

// A subscriber that joins late, one that falls behind (KEEP_LAST 12 overwrites what it
// does not read: a gap), and the first one across a daemon restart (a new epoch), each rebuild
// the exact overlap set from a snapshot and keep it exact frame by frame. Snapshots are split into
// parts.
TEST(Daemon, LateLaggingAndRestartedSubscribersResyncFromSnapshots) {
  service::Config config = TestConfig(kDomain);
  config.engine.algorithm = "grid_dense";
  // Snapshots of several parts. A subscriber's depth must exceed a snapshot's part count, or
  // its own history overwrites the snapshot while it arrives (docs/PROTOCOL.md).
  config.limits.max_pairs_per_event_batch = 100;
  auto daemon = std::make_unique<InProcessDaemon>(config);
  Client client(config);
  auto pub = client.Publisher(1);
  Scene scene(SmallScene(11));
  Oracle<3> oracle;
  PairList unc, col;
  FrameOps ops = InitialOps(scene);
  uint64_t frame = 0;
  auto step = [&] {
    if (frame > 0) scene.NextFrame(&ops);
    ++frame;
    oracle.Apply(1, ops);
    oracle.Query(&unc, &col);
    PublishFrame(*pub, ops, 3, frame, 1);
    FrameEvents got;
    ASSERT_TRUE(client.events->WaitFrame(frame, &got));
  };
  for (int i = 0; i < 8; ++i) step();
  ASSERT_GT(oracle.Pairs().size(), 100u) << "the snapshot should need several parts";
  ASSERT_LE(oracle.Pairs().size(), 1000u) << "the lagging subscriber's depth must hold a snapshot";

  // Two late joiners: one reads everything, one keeps only the newest 12 parts.
  std::unique_ptr<transport::Connection> connection;
  BP_ASSERT_OK(transport::Connection::Open(ClientOptions(config), &connection));
  std::unique_ptr<client::EventSubscriber> eager, lagging;
  BP_ASSERT_OK(client::EventSubscriber::Create(*connection, 1000, &eager));
  BP_ASSERT_OK(client::EventSubscriber::Create(*connection, 12, &lagging));
  std::unique_ptr<client::SnapshotRequester> requests;
  BP_ASSERT_OK(client::SnapshotRequester::Create(*connection, &requests));
  BP_ASSERT_OK(eager->WaitForDaemon(10s));
  BP_ASSERT_OK(lagging->WaitForDaemon(10s));
  BP_ASSERT_OK(requests->WaitForDaemon(10s));
  client::OverlapView eager_view, lagging_view;
  ASSERT_TRUE(SyncTo(*eager, *requests, eager_view, frame)) << eager_view.last_loss();
  EXPECT_EQ(eager_view.SortedPairs(), oracle.Pairs());
  ASSERT_TRUE(SyncTo(*lagging, *requests, lagging_view, frame)) << lagging_view.last_loss();
  EXPECT_EQ(lagging_view.SortedPairs(), oracle.Pairs());

  // Frame by frame: the eager view stays exact; the lagging one is not read meanwhile.
  for (int i = 0; i < 15; ++i) {  // at least 15 parts: more than the lagging depth
    step();
    ASSERT_TRUE(SyncTo(*eager, *requests, eager_view, frame)) << eager_view.last_loss();
    ASSERT_EQ(eager_view.SortedPairs(), oracle.Pairs()) << "frame " << frame;
  }
  EXPECT_EQ(eager_view.resyncs(), 0u);
  ASSERT_TRUE(SyncTo(*lagging, *requests, lagging_view, frame)) << lagging_view.last_loss();
  EXPECT_EQ(lagging_view.SortedPairs(), oracle.Pairs());
  EXPECT_GE(lagging_view.gaps(), 1u) << "KEEP_LAST 12 must have overwritten parts";
  EXPECT_GE(lagging_view.resyncs(), 1u);

  // The daemon restarts (a new epoch, frames from 1 again); the producer sends its objects
  // again as inserts of a fresh scene.
  BP_ASSERT_OK(daemon->Stop());
  const uint64_t old_epoch = eager_view.epoch();
  daemon.reset();
  daemon = std::make_unique<InProcessDaemon>(config);
  Client client2(config);
  auto pub2 = client2.Publisher(1);
  Scene scene2(SmallScene(12));
  Oracle<3> oracle2;
  FrameOps ops2 = InitialOps(scene2);
  for (uint64_t f = 1; f <= 3; ++f) {
    if (f > 1) scene2.NextFrame(&ops2);
    oracle2.Apply(1, ops2);
    oracle2.Query(&unc, &col);
    PublishFrame(*pub2, ops2, 3, f, 1);
    FrameEvents got;
    ASSERT_TRUE(client2.events->WaitFrame(f, &got));
  }
  ASSERT_TRUE(SyncTo(*eager, *requests, eager_view, 3)) << eager_view.last_loss();
  EXPECT_EQ(eager_view.SortedPairs(), oracle2.Pairs());
  EXPECT_NE(eager_view.epoch(), old_epoch);
  EXPECT_EQ(eager_view.restarts(), 1u);
  EXPECT_EQ(eager_view.contradictions(), 0u);
  EXPECT_GE(daemon->daemon().snapshots(), 1u);
}

TEST(Daemon, ASubscriberThatNeverReadsStallsNothing) {
  service::Config config = TestConfig(kDomain);
  config.dds.write_timeout_ms = 2000;  // a blocked write would show as a 2 s stall per frame
  InProcessDaemon daemon(config);
  Client client(config);
  std::unique_ptr<client::EventSubscriber> sleeper;
  BP_ASSERT_OK(client::EventSubscriber::Create(*client.connection, 2, &sleeper));
  BP_ASSERT_OK(sleeper->WaitForDaemon(10s));
  auto pub = client.Publisher(1);
  const auto start = std::chrono::steady_clock::now();
  constexpr uint64_t kFrames = 300;
  for (uint64_t frame = 1; frame <= kFrames; ++frame) {
    wire::UpdateBatch batch;
    batch.set_dim(3);
    batch.set_end_of_frame(true);
    client::AddBox<3>(batch.mutable_inserts(), frame, Cube(static_cast<float>(frame) * 0.5f));
    BP_ASSERT_OK(pub->Publish(&batch));
  }
  FrameEvents last;
  ASSERT_TRUE(client.events->WaitFrame(kFrames, &last, 30s));
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_LT(seconds, 20.0) << "the daemon was held up by the subscriber that never reads";
  EXPECT_EQ(client.events->subscriber().gaps(), 0u);
  EXPECT_EQ(last.last.objects(), kFrames);
  // The sleeper kept only its newest batches (depth 2; the last ones may still be in flight to
  // it) and can tell from the sequence numbers that it missed the others.
  std::vector<wire::EventBatch> kept;
  BP_ASSERT_OK(sleeper->Poll(1s, &kept));
  ASSERT_FALSE(kept.empty());
  EXPECT_LE(kept.size(), 2u);
  EXPECT_GT(kept.front().sequence(), kFrames - 10) << "the sleeper's history was not bounded";
  while (kept.back().frame() < kFrames) {
    const size_t before = kept.size();
    BP_ASSERT_OK(sleeper->Poll(5s, &kept));
    ASSERT_GT(kept.size(), before) << "the last frames never reached the sleeper";
  }
  BP_ASSERT_OK(daemon.Stop());
  EXPECT_EQ(daemon.daemon().frames(), kFrames);
}

// The client library's callback style: a listener thread hands every EventBatch to a callback.
TEST(Daemon, ClientLibraryRoundTripWithACallback) {
  service::Config config = TestConfig(kDomain);
  InProcessDaemon daemon(config);
  std::unique_ptr<transport::Connection> connection;
  BP_ASSERT_OK(transport::Connection::Open(ClientOptions(config), &connection));
  std::unique_ptr<client::EventSubscriber> sub;
  BP_ASSERT_OK(client::EventSubscriber::Create(*connection, 64, &sub));
  BP_ASSERT_OK(sub->WaitForDaemon(10s));
  std::mutex mutex;
  std::condition_variable arrived;
  std::vector<wire::EventBatch> received;
  BP_ASSERT_OK(sub->Listen([&](const wire::EventBatch& b) {
    std::lock_guard lock(mutex);
    received.push_back(b);
    arrived.notify_all();
  }));
  EXPECT_FALSE(sub->Listen([](const wire::EventBatch&) {}).ok()) << "a second listener";
  std::unique_ptr<client::UpdatePublisher> pub;
  BP_ASSERT_OK(client::UpdatePublisher::Create(*connection, 2, 1000ms, &pub));
  BP_ASSERT_OK(pub->WaitForDaemon(10s));
  wire::UpdateBatch batch = InsertBatch({{1, Cube(0)}, {2, Cube(0.5f)}});
  BP_ASSERT_OK(pub->Publish(&batch));
  {
    std::unique_lock lock(mutex);
    ASSERT_TRUE(arrived.wait_for(lock, 10s, [&] { return !received.empty(); }));
    EXPECT_EQ(client::Pairs(received[0].collide()),
              (PairList{{service::GlobalKey(2, 1), service::GlobalKey(2, 2)}}));
    EXPECT_EQ(received[0].source_producer(), 2u);
  }
  sub->StopListening();
  sub->StopListening();  // idempotent
}

// A subscriber that keeps asking gets at most one snapshot per
// limits.snapshot_interval_ms, and a request in between is served late, not dropped.
TEST(Daemon, SnapshotRequestsAreRateLimited) {
  service::Config config = TestConfig(kDomain);
  config.limits.snapshot_interval_ms = 400;
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(1);
  wire::UpdateBatch b1 = InsertBatch({{10, Cube(0)}, {11, Cube(0.5f)}});
  BP_ASSERT_OK(pub->Publish(&b1));
  ExpectFrame(*client.events, 1, {}, {{service::GlobalKey(1, 10), service::GlobalKey(1, 11)}});
  std::unique_ptr<client::SnapshotRequester> requests;
  BP_ASSERT_OK(client::SnapshotRequester::Create(*client.connection, &requests));
  BP_ASSERT_OK(requests->WaitForDaemon(10s));
  const auto start = std::chrono::steady_clock::now();
  while (std::chrono::steady_clock::now() - start < 1000ms) {
    BP_ASSERT_OK(requests->Request("flood"));
    std::this_thread::sleep_for(10ms);
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  // The last request is served within an interval.
  std::this_thread::sleep_for(600ms);
  const uint64_t snapshots = daemon.daemon().snapshots();
  EXPECT_GE(snapshots, 2u);
  EXPECT_LE(static_cast<double>(snapshots), seconds / 0.4 + 2.0) << "about 100 requests";
  // Quiet for longer than the interval: a request is served at once; a second one right after
  // waits for the interval, with nothing else waking the daemon, and is served then.
  BP_ASSERT_OK(requests->Request("one"));
  std::this_thread::sleep_for(150ms);
  EXPECT_EQ(daemon.daemon().snapshots(), snapshots + 1) << "served at once";
  BP_ASSERT_OK(requests->Request("deferred"));
  std::this_thread::sleep_for(100ms);
  EXPECT_EQ(daemon.daemon().snapshots(), snapshots + 1) << "not before the interval";
  std::this_thread::sleep_for(450ms);
  EXPECT_EQ(daemon.daemon().snapshots(), snapshots + 2) << "served when the interval ran out";
  // A fresh subscriber still syncs to the exact set.
  std::unique_ptr<client::EventSubscriber> sub;
  BP_ASSERT_OK(client::EventSubscriber::Create(*client.connection, 100, &sub));
  BP_ASSERT_OK(sub->WaitForDaemon(10s));
  client::OverlapView view;
  ASSERT_TRUE(SyncTo(*sub, *requests, view, 1)) << view.last_loss();
  EXPECT_EQ(view.SortedPairs(), (PairList{{service::GlobalKey(1, 10), service::GlobalKey(1, 11)}}));
}

}  // namespace
}  // namespace bp::test
