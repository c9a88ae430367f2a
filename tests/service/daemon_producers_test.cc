// The daemon's producers over time: leases that expire, restarts restated, hung producers,
// batch_seq gaps repaired, partial restates, raised requests with backoff.
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

// A producer that goes away (here its writer is deleted; a killed process loses its
// liveliness, see daemon_process_test.cc) has its objects erased after producers.lease_s, with
// one frame of uncollides for every pair they were in, its own pairs and the others'.
TEST(Daemon, AProducerThatGoesAwayHasItsObjectsErasedAfterTheLease) {
  service::Config config = TestConfig(kDomain);
  config.producers.lease_s = 0.5;
  InProcessDaemon daemon(config);
  Client client(config);
  auto stays = client.Publisher(2);
  std::chrono::steady_clock::time_point gone;
  {
    std::unique_ptr<transport::Connection> own;  // its own participant, as another process has
    BP_ASSERT_OK(transport::Connection::Open(ClientOptions(config), &own));
    std::unique_ptr<client::UpdatePublisher> leaver;
    BP_ASSERT_OK(client::UpdatePublisher::Create(*own, 1, 5000ms, &leaver));
    BP_ASSERT_OK(leaver->WaitForDaemon(10s));
    wire::UpdateBatch b1 = InsertBatch({{10, Cube(0)}, {11, Cube(0.5f)}});
    b1.set_end_of_frame(false);
    BP_ASSERT_OK(leaver->Publish(&b1));
    // The same writer speaks for producer 5 too (as bpctl replay does for a recording's
    // producers): both ids are its, and both expire with it.
    wire::UpdateBatch b5 = InsertBatch({{50, Cube(80)}, {51, Cube(80.5f)}});
    b5.set_version(wire::SCHEMA_VERSION_1);
    b5.set_producer(5);
    BP_ASSERT_OK(leaver->PublishRaw(b5.SerializeAsString()));
    ExpectFrame(*client.events, 1, {},
                {{service::GlobalKey(1, 10), service::GlobalKey(1, 11)},
                 {service::GlobalKey(5, 50), service::GlobalKey(5, 51)}});
    wire::UpdateBatch b2 = InsertBatch({{20, Cube(0.25f)}, {21, Cube(40)}});
    BP_ASSERT_OK(stays->Publish(&b2));
    ExpectFrame(*client.events, 2, {},
                {{service::GlobalKey(1, 10), service::GlobalKey(2, 20)},
                 {service::GlobalKey(1, 11), service::GlobalKey(2, 20)}});
    gone = std::chrono::steady_clock::now();
  }
  FrameEvents fe;
  ASSERT_TRUE(client.events->WaitFrame(3, &fe, 10s)) << "producer 1's objects were not erased";
  const double waited =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - gone).count();
  EXPECT_GE(waited, 0.45) << "erased before the lease ran out";
  // Both of the writer's producers expire (one frame each).
  PairList uncollide = fe.uncollide;
  if (fe.last.objects() != 2u) {
    ASSERT_TRUE(client.events->WaitFrame(4, &fe, 10s)) << "producer 5 did not expire";
    uncollide.insert(uncollide.end(), fe.uncollide.begin(), fe.uncollide.end());
    std::sort(uncollide.begin(), uncollide.end());
  }
  EXPECT_EQ(uncollide, (PairList{{service::GlobalKey(1, 10), service::GlobalKey(1, 11)},
                                 {service::GlobalKey(1, 10), service::GlobalKey(2, 20)},
                                 {service::GlobalKey(1, 11), service::GlobalKey(2, 20)},
                                 {service::GlobalKey(5, 50), service::GlobalKey(5, 51)}}));
  EXPECT_TRUE(fe.collide.empty());
  EXPECT_EQ(fe.last.objects(), 2u);
  EXPECT_EQ(fe.last.overlaps(), 0u);
  EXPECT_EQ(daemon.daemon().producers_expired(), 2u);
  const uint64_t next_frame = fe.last.frame() + 1;
  // Producer 2 is untouched and its objects still pair with newcomers.
  wire::UpdateBatch b3 = InsertBatch({{22, Cube(40.5f)}});
  BP_ASSERT_OK(stays->Publish(&b3));
  ExpectFrame(*client.events, next_frame, {},
              {{service::GlobalKey(2, 21), service::GlobalKey(2, 22)}});
  // The status reports count the expiries and name the producers as they expire.
  ASSERT_TRUE(client.status->WaitUntil(
      [](const wire::DaemonStatus& r) { return r.producers_expired() == 2 && r.epoch() != 0; }));
  std::set<uint32_t> named;
  for (const auto& r : client.status->reports()) {
    named.insert(r.expired_producers().begin(), r.expired_producers().end());
  }
  EXPECT_EQ(named, (std::set<uint32_t>{1, 5}));
}

// With producers.lease_s = 0 the objects of a producer that left stay.
TEST(Daemon, WithoutALeaseTheObjectsOfAProducerThatLeftStay) {
  service::Config config = TestConfig(kDomain);
  config.producers.lease_s = 0;
  InProcessDaemon daemon(config);
  Client client(config);
  {
    auto leaver = client.Publisher(1);
    wire::UpdateBatch b1 = InsertBatch({{10, Cube(0)}, {11, Cube(0.5f)}});
    BP_ASSERT_OK(leaver->Publish(&b1));
    ExpectFrame(*client.events, 1, {}, {{service::GlobalKey(1, 10), service::GlobalKey(1, 11)}});
  }
  FrameEvents fe;
  EXPECT_FALSE(client.events->WaitFrame(2, &fe, 1500ms)) << "a frame without any update";
  EXPECT_EQ(daemon.daemon().producers_expired(), 0u);
  // A new writer of producer 1 is a new incarnation: what the old one left is erased first.
  auto second = client.Publisher(1);
  wire::UpdateBatch b2 = InsertBatch({{11, Cube(0.6f)}, {12, Cube(0.7f)}});
  BP_ASSERT_OK(second->Publish(&b2));
  // Erase of 10 and 11, insert of 11 and 12 in one frame: (10, 11) ends, (11, 12) begins.
  ExpectFrame(*client.events, 2, {{service::GlobalKey(1, 10), service::GlobalKey(1, 11)}},
              {{service::GlobalKey(1, 11), service::GlobalKey(1, 12)}});
  EXPECT_EQ(daemon.daemon().producers_expired(), 0u) << "a take-over is not a lease expiry";
}

// The daemon restarts empty; a producer that keeps its objects (restate_on_restart)
// sends them again when it sees the new epoch, and a subscriber's view, resynced from a snapshot,
// equals the oracle's set. (daemon_process_test.cc kills the daemon with SIGKILL instead.)
TEST(Daemon, ARestartedDaemonGetsTheObjectsBackFromARestatingProducer) {
  service::Config config = TestConfig(kDomain);
  auto daemon = std::make_unique<InProcessDaemon>(config);
  Client client(config);
  client::PublisherOptions options;
  options.restate_on_restart = true;
  options.restate_batch_items = 150;  // several restate batches
  std::unique_ptr<client::UpdatePublisher> pub;
  BP_ASSERT_OK(client::UpdatePublisher::Create(*client.connection, 1, options, &pub));
  BP_ASSERT_OK(pub->WaitForDaemon(10s));
  const uint64_t first_epoch = pub->daemon_epoch();
  ASSERT_NE(first_epoch, 0u);
  std::unique_ptr<client::EventSubscriber> sub;
  BP_ASSERT_OK(client::EventSubscriber::Create(*client.connection, 1000, &sub));
  std::unique_ptr<client::SnapshotRequester> requests;
  BP_ASSERT_OK(client::SnapshotRequester::Create(*client.connection, &requests));
  BP_ASSERT_OK(sub->WaitForDaemon(10s));
  BP_ASSERT_OK(requests->WaitForDaemon(10s));
  client::OverlapView view;

  Scene scene(SmallScene(21));
  Oracle<3> oracle;
  PairList unc, col;
  FrameOps ops = InitialOps(scene);
  for (uint64_t frame = 1; frame <= 5; ++frame) {
    if (frame > 1) scene.NextFrame(&ops);
    oracle.Apply(1, ops);
    oracle.Query(&unc, &col);
    PublishFrame(*pub, ops, 3, frame, 1);
    ASSERT_TRUE(SyncTo(*sub, *requests, view, frame)) << view.last_loss();
  }
  EXPECT_EQ(view.SortedPairs(), oracle.Pairs());
  EXPECT_EQ(pub->kept_objects(), oracle.Size());

  BP_ASSERT_OK(daemon->Stop());
  daemon.reset();
  daemon = std::make_unique<InProcessDaemon>(config);
  BP_ASSERT_OK(requests->WaitForDaemon(10s));
  BP_ASSERT_OK(pub->WaitForDaemon(10s));
  for (uint64_t frame = 1; frame <= 5; ++frame) {
    scene.NextFrame(&ops);
    oracle.Apply(1, ops);
    oracle.Query(&unc, &col);
    PublishFrame(*pub, ops, 3, frame, 1);
    std::this_thread::sleep_for(20ms);
  }
  // The restate closes the new daemon's frame 1; the five published ones are frames 2..6.
  ASSERT_TRUE(SyncUntil(*sub, *requests, view, [&](const client::OverlapView& v) {
    return v.epoch() != first_epoch && v.frame() == 6;
  })) << view.last_loss();
  EXPECT_EQ(view.SortedPairs(), oracle.Pairs());
  EXPECT_NE(view.epoch(), first_epoch);
  EXPECT_EQ(view.restarts(), 1u);
  EXPECT_EQ(view.contradictions(), 0u);
  EXPECT_EQ(pub->restates(), 1u);
  EXPECT_NE(pub->daemon_epoch(), first_epoch);
  EXPECT_EQ(pub->kept_objects(), oracle.Size());
  // No insert was refused as a duplicate: restated objects replace what the daemon holds.
  client.status->Collect(300ms);
  for (const auto& r : client.status->rejections()) {
    EXPECT_NE(r.reason(), wire::DUPLICATE_INSERT) << r.message();
  }
}

// A restating producer that finds its own id among a report's expired_producers (it
// hung longer than the daemon's lease) restates its objects to the same daemon; the restate
// closes a frame, and replaces objects the daemon still holds without a rejection.
TEST(Daemon, AProducerTheDaemonExpiredWhileItHungRestates) {
  service::Config config = TestConfig(kDomain);
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.RestatingPublisher(1);
  wire::UpdateBatch b1 = InsertBatch({{10, Cube(0)}, {11, Cube(0.5f)}});
  BP_ASSERT_OK(pub->Publish(&b1));
  ExpectFrame(*client.events, 1, {}, {{service::GlobalKey(1, 10), service::GlobalKey(1, 11)}});
  BP_ASSERT_OK(pub->Maintain());
  EXPECT_EQ(pub->restates(), 0u);
  // The report the daemon publishes when producer 1's lease runs out (written here: making the
  // process hang longer than the lease is daemon_process_test's business).
  dds::Qos qos;
  transport::qos::StatusWriter(qos.get(), 1000ms);
  dds::Writer fake;
  BP_ASSERT_OK(client.connection->CreateWriter(transport::TopicId::kStatus, qos, &fake));
  wire::DaemonStatus report;
  report.set_version(wire::SCHEMA_VERSION_1);
  report.set_health(wire::SERVING);
  report.set_epoch(pub->daemon_epoch());
  report.add_expired_producers(7);  // another producer: not this one's business
  BP_ASSERT_OK(fake.Write(1001, report.SerializeAsString()));  // after the daemon's own
  std::this_thread::sleep_for(200ms);
  BP_ASSERT_OK(pub->Maintain());
  EXPECT_EQ(pub->restates(), 0u);
  report.add_expired_producers(1);
  BP_ASSERT_OK(fake.Write(1002, report.SerializeAsString()));
  for (int i = 0; i < 100 && pub->restates() == 0; ++i) {
    std::this_thread::sleep_for(10ms);
    BP_ASSERT_OK(pub->Maintain());
  }
  EXPECT_EQ(pub->restates(), 1u);
  // The restate closed frame 2: the daemon still held both objects, so nothing changed.
  ExpectFrame(*client.events, 2, {}, {});
  client.status->Collect(200ms);
  for (const auto& r : client.status->rejections()) ADD_FAILURE() << r.message();
}

// Batches lost in DDS (a producer stalled longer than Cyclone's participant lease was
// dropped and discovered again) show as a batch_seq gap. The daemon asks the producer to restate
// (DaemonStatus.resync), and a restate states the producer's whole set: an object it no longer
// has is erased, a box that diverged is replaced.
TEST(Daemon, ABatchSeqGapIsRepairedByARestateTheDaemonAsksFor) {
  service::Config config = TestConfig(kDomain);
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.RestatingPublisher(2);
  const uint64_t k10 = service::GlobalKey(2, 10), k11 = service::GlobalKey(2, 11);
  const uint64_t k12 = service::GlobalKey(2, 12), k13 = service::GlobalKey(2, 13);
  wire::UpdateBatch b1 = InsertBatch({{10, Cube(0)}, {11, Cube(0.5f)}, {12, Cube(5)}});
  BP_ASSERT_OK(pub->Publish(&b1));  // batch_seq 1
  ExpectFrame(*client.events, 1, {}, {{k10, k11}});
  // What the daemon holds but the producer does not (as if the producer's next batch, which
  // undid it, had been lost): 13 next to 12, and 10 away from 11.
  wire::UpdateBatch stray = InsertBatch({{13, Cube(5.5f)}});
  client::AddBox<3>(stray.mutable_updates(), 10, Cube(20));
  stray.set_version(wire::SCHEMA_VERSION_1);
  stray.set_producer(2);
  stray.set_batch_seq(2);
  BP_ASSERT_OK(pub->PublishRaw(stray.SerializeAsString()));  // not kept by the publisher
  ExpectFrame(*client.events, 2, {{k10, k11}}, {{k12, k13}});
  // A lost batch: batch_seq 3 reaches the daemon as bytes it cannot read (refused, and not
  // attributed to producer 2), so batch_seq 4 shows the gap.
  BP_ASSERT_OK(pub->PublishRaw("not an UpdateBatch"));
  wire::UpdateBatch b2;
  b2.set_dim(3);
  b2.set_end_of_frame(true);
  client::AddBox<3>(b2.mutable_updates(), 12, Cube(5));
  BP_ASSERT_OK(pub->Publish(&b2));  // batch_seq 4
  ExpectFrame(*client.events, 3, {}, {});
  ASSERT_TRUE(client.status->WaitUntil([](const wire::DaemonStatus& r) {
    return r.resync_size() == 1 && r.resync(0).producer() == 2 && r.resync(0).seen_batch_seq() == 4;
  }));
  for (int i = 0; i < 200 && pub->restates() == 0; ++i) {
    std::this_thread::sleep_for(10ms);
    BP_ASSERT_OK(pub->Maintain());
  }
  ASSERT_EQ(pub->restates(), 1u);
  // The restate (one batch, closing frame 4) names 10, 11 and 12 with their boxes: 10 is back
  // next to 11, and 13, which it does not name, is erased.
  FrameEvents frame4;
  ASSERT_TRUE(client.events->WaitFrame(4, &frame4));
  EXPECT_EQ(frame4.uncollide, (PairList{{k12, k13}}));
  EXPECT_EQ(frame4.collide, (PairList{{k10, k11}}));
  EXPECT_EQ(frame4.last.objects(), 3u);
  // Answered: the sequence goes on from the restate, and no report asks again.
  wire::UpdateBatch b3;
  b3.set_dim(3);
  b3.set_end_of_frame(true);
  b3.add_erases(11);
  b3.add_erases(77);  // unknown: a rejection, so that a report follows
  BP_ASSERT_OK(pub->Publish(&b3));
  ExpectFrame(*client.events, 5, {{k10, k11}}, {});
  wire::DaemonStatus report;
  ASSERT_TRUE(client.status->WaitUntil([&](const wire::DaemonStatus& r) {
    report = r;
    return r.rejections_size() == 1 && r.rejections(0).id() == 77;
  }));
  EXPECT_EQ(report.resync_size(), 0);
  BP_ASSERT_OK(pub->Maintain());
  EXPECT_EQ(pub->restates(), 1u);
  ASSERT_EQ(client.status->rejections().size(), 2u);
  EXPECT_EQ(client.status->rejections()[0].reason(), wire::MALFORMED);
}

// A restate run that did not arrive whole names too little: the daemon erases nothing, keeps
// asking, and publishes a report at the run's end (so that the producer restates again).
TEST(Daemon, ARestateThatIsNotWholeErasesNothingAndIsAskedForAgain) {
  service::Config config = TestConfig(kDomain);
  config.limits.max_batch_items = 100;
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(3);  // raw batches with chosen batch_seq values
  auto send = [&](wire::UpdateBatch batch, uint64_t seq, uint64_t run) {
    batch.set_version(wire::SCHEMA_VERSION_1);
    batch.set_producer(3);
    batch.set_batch_seq(seq);
    batch.set_restate(run != 0);
    batch.set_restate_run(run);
    BP_ASSERT_OK(pub->PublishRaw(batch.SerializeAsString()));
  };
  auto asked = [&](uint64_t seen) {
    return client.status->WaitUntil([seen](const wire::DaemonStatus& r) {
      return r.resync_size() == 1 && r.resync(0).producer() == 3 &&
             r.resync(0).seen_batch_seq() == seen && r.max_batch_items() == 100;
    });
  };
  auto frame = [&](uint64_t number, const PairList& uncollide, uint64_t objects) {
    FrameEvents got;
    ASSERT_TRUE(client.events->WaitFrame(number, &got)) << "frame " << number;
    EXPECT_EQ(got.uncollide, uncollide) << "frame " << number;
    EXPECT_TRUE(got.collide.empty()) << "frame " << number;
    EXPECT_EQ(got.last.objects(), objects) << "frame " << number;
  };
  const PairList pair = {{service::GlobalKey(3, 1), service::GlobalKey(3, 2)}};
  send(InsertBatch({{1, Cube(0)}, {2, Cube(0.5f)}}), 1, 0);
  ExpectFrame(*client.events, 1, {}, pair);
  wire::UpdateBatch one = InsertBatch({{1, Cube(0)}});  // a run's batch naming 1, not the last
  one.set_end_of_frame(false);
  const wire::UpdateBatch last = InsertBatch({});
  // A batch_seq missing in the middle (3).
  send(one, 2, 2);
  send(last, 4, 2);
  frame(2, {}, 2);
  ASSERT_TRUE(asked(4));
  // The first batch missing (5).
  send(last, 6, 5);
  frame(3, {}, 2);
  ASSERT_TRUE(asked(6));
  // A batch refused as a whole (101 items > limits.max_batch_items).
  send(one, 7, 7);
  wire::UpdateBatch many = InsertBatch({});
  many.set_end_of_frame(false);
  for (uint64_t id = 1; id <= 101; ++id) client::AddBox<3>(many.mutable_inserts(), id, Cube(0));
  send(many, 8, 7);
  send(last, 9, 7);
  frame(4, {}, 2);
  ASSERT_TRUE(asked(9));
  // A run cut short by an ordinary batch.
  send(one, 10, 10);
  send(last, 11, 0);
  frame(5, {}, 2);
  ASSERT_TRUE(asked(11));
  // A whole run: 2, which it does not name, is erased, and the request is answered.
  send(one, 12, 12);
  send(last, 13, 12);
  frame(6, pair, 1);
  wire::UpdateBatch bad = InsertBatch({{9, Box<3, float>{{1, 0, 0}, {0, 1, 1}}}});  // inverted
  send(bad, 14, 0);
  wire::DaemonStatus report;
  ASSERT_TRUE(client.status->WaitUntil([&](const wire::DaemonStatus& r) {
    report = r;
    return r.rejections_size() == 1 && r.rejections(0).id() == 9;
  }));
  EXPECT_EQ(report.resync_size(), 0);
}

// A request no restate answers (the producer does not restate, or its restate was lost before
// its writer matched the daemon's reader) is raised again after 1 s, then 2 s, ...
TEST(Daemon, ARequestNoRestateAnswersIsRaisedAgainWithBackoff) {
  service::Config config = TestConfig(kDomain);
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(4);  // does not restate
  wire::UpdateBatch batch = InsertBatch({{1, Cube(0)}});
  batch.set_version(wire::SCHEMA_VERSION_1);
  batch.set_producer(4);
  batch.set_batch_seq(3);  // a first batch after 1 and 2, which this daemon did not see
  BP_ASSERT_OK(pub->PublishRaw(batch.SerializeAsString()));
  ExpectFrame(*client.events, 1, {}, {});
  std::vector<std::pair<uint64_t, std::chrono::steady_clock::time_point>> raises;
  ASSERT_TRUE(client.status->WaitUntil(
      [&](const wire::DaemonStatus& r) {
        if (r.resync_size() == 1 && r.resync(0).producer() == 4 &&
            (raises.empty() || r.resync(0).raised() > raises.back().first)) {
          raises.emplace_back(r.resync(0).raised(), std::chrono::steady_clock::now());
        }
        return raises.size() == 3;
      },
      10s));
  const auto first_gap = raises[1].second - raises[0].second;
  const auto second_gap = raises[2].second - raises[1].second;
  EXPECT_GE(first_gap, 800ms);
  EXPECT_GE(second_gap, 1800ms);
  EXPECT_GT(second_gap, first_gap);
}

// The publisher side: each raise of a request makes one restate, a report delivered again (its
// envelope sequence number already read) none, and restate batches fit the daemon's
// limits.max_batch_items (announced in its reports).
TEST(Daemon, ARestatingPublisherAnswersEachRaiseOnceWithinTheDaemonsLimits) {
  service::Config config = TestConfig(kDomain);
  config.limits.max_batch_items = 2;
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.RestatingPublisher(6);
  wire::UpdateBatch b1 = InsertBatch({{1, Cube(0)}, {2, Cube(3)}});
  wire::UpdateBatch b2 = InsertBatch({{3, Cube(6)}, {4, Cube(9)}});
  wire::UpdateBatch b3 = InsertBatch({{5, Cube(12)}});
  BP_ASSERT_OK(pub->Publish(&b1));
  BP_ASSERT_OK(pub->Publish(&b2));
  BP_ASSERT_OK(pub->Publish(&b3));
  FrameEvents got;
  ASSERT_TRUE(client.events->WaitFrame(3, &got));
  ASSERT_EQ(got.last.objects(), 5u);
  // Reports as the daemon would publish them (written here, with envelope numbers after the
  // daemon's own).
  dds::Qos qos;
  transport::qos::StatusWriter(qos.get(), 1000ms);
  dds::Writer fake;
  BP_ASSERT_OK(client.connection->CreateWriter(transport::TopicId::kStatus, qos, &fake));
  auto report = [&](uint64_t seq, uint64_t raised) {
    wire::DaemonStatus r;
    r.set_version(wire::SCHEMA_VERSION_1);
    r.set_health(wire::SERVING);
    r.set_epoch(pub->daemon_epoch());
    r.set_max_batch_items(2);
    wire::ResyncRequest* request = r.add_resync();
    request->set_producer(6);
    request->set_raised(raised);
    BP_ASSERT_OK(fake.Write(seq, r.SerializeAsString()));
  };
  auto settle = [&]() {
    for (int i = 0; i < 30; ++i) {
      std::this_thread::sleep_for(10ms);
      BP_ASSERT_OK(pub->Maintain());
    }
  };
  const uint64_t published = pub->published();
  report(1001, 1001);
  settle();
  EXPECT_EQ(pub->restates(), 1u);
  EXPECT_EQ(pub->published() - published, 3u) << "5 objects in batches of at most 2";
  report(1002, 1001);  // the same raise: answered
  report(1001, 1003);  // a report already read
  settle();
  EXPECT_EQ(pub->restates(), 1u);
  report(1003, 1003);  // raised again
  settle();
  EXPECT_EQ(pub->restates(), 2u);
  // Both restates arrived whole: nothing refused, nothing erased.
  ASSERT_TRUE(client.events->WaitFrame(5, &got));
  EXPECT_EQ(got.last.objects(), 5u);
  client.status->Collect(200ms);
  for (const auto& r : client.status->rejections()) ADD_FAILURE() << r.message();
}

}  // namespace
}  // namespace bp::test
