// broadphased as a real subprocess (the binary users run): configuration refusals with line
// numbers and exit status 2; a scene over DDS whose events equal the oracle's; SIGINT and SIGTERM
// finish the open frame, publish its events and exit 0.
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "process_test_support.h"
#include "service_test_support.h"
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

namespace bp::test {
namespace {

constexpr uint32_t kDomain = BP_TEST_DOMAIN;

// What a test that follows the daemon's overlap set opens: a connection, a status collector,
// an event subscriber and a snapshot requester, both matched to the daemon.
struct Watcher {
  struct {
    std::unique_ptr<transport::Connection> connection;
    std::unique_ptr<client::EventSubscriber> sub;
    std::unique_ptr<client::SnapshotRequester> requests;
  } dds;
  std::unique_ptr<RejectionCollector> status;
};

void OpenWatcher(const service::Config& c, Watcher* w) {
  BP_ASSERT_OK(transport::Connection::Open(ClientOptions(c), &w->dds.connection));
  w->status = std::make_unique<RejectionCollector>(*w->dds.connection);
  BP_ASSERT_OK(client::EventSubscriber::Create(*w->dds.connection, 1000, &w->dds.sub));
  BP_ASSERT_OK(client::SnapshotRequester::Create(*w->dds.connection, &w->dds.requests));
  BP_ASSERT_OK(w->dds.sub->WaitForDaemon(20s));
  BP_ASSERT_OK(w->dds.requests->WaitForDaemon(20s));
}

std::string WriteConfig(const std::string& dir, const std::string& text) {
  const std::string path = dir + "/broadphased.yaml";
  std::ofstream(path) << text;
  return path;
}

std::string ConfigText(const service::Config& c, double lease_s = 10) {
  return "engine:\n  algorithm: segmented_sap\n  dimension: 3\n"
         "dds:\n  domain: " +
         std::to_string(c.dds.domain) + "\n  cyclone_config: " + c.dds.cyclone_config +
         "\n  partition: " + c.dds.partition +
         "\nlogging:\n  level: info\n  summary_interval_s: 0.1\n"
         "producers:\n  lease_s: " +
         std::to_string(lease_s) + "\n";
}

TEST(DaemonProcess, BadConfigIsRefusedWithLineNumbersAndExitStatus2) {
  ScratchDir scratch;
  const std::string& dir = scratch.path();
  const std::string config = WriteConfig(dir,
                                         "engine:\n"
                                         "  algorithm: segmented_sap\n"
                                         "  dimensions: 3\n"
                                         "frames:\n"
                                         "  boundary: sometimes\n");
  Process p({"--config", config}, dir + "/log");
  EXPECT_EQ(p.Wait(), 2);
  const std::string log = ReadFile(dir + "/log");
  EXPECT_NE(log.find(":3:"), std::string::npos) << log;
  EXPECT_NE(log.find("unknown key 'engine.dimensions'"), std::string::npos) << log;
  EXPECT_NE(log.find(":5:"), std::string::npos) << log;
  EXPECT_NE(log.find("sometimes"), std::string::npos) << log;
}

TEST(DaemonProcess, MissingCycloneConfigFailsWithExitStatus1) {
  ScratchDir scratch;
  const std::string& dir = scratch.path();
  service::Config c = TestConfig(kDomain);
  c.dds.cyclone_config = dir + "/no-such.xml";
  const std::string config = WriteConfig(dir, ConfigText(c));
  Process p({"--config", config}, dir + "/log");
  EXPECT_EQ(p.Wait(), 1);
  EXPECT_NE(ReadFile(dir + "/log").find("no-such.xml"), std::string::npos);
}

void SceneThenSignal(int sig) {
  ScratchDir scratch;
  const std::string& dir = scratch.path();
  service::Config c = TestConfig(kDomain);
  const std::string config = WriteConfig(dir, ConfigText(c));
  Process daemon({"--config", config}, dir + "/log");

  std::unique_ptr<transport::Connection> connection;
  BP_ASSERT_OK(transport::Connection::Open(ClientOptions(c), &connection));
  EventCollector events(*connection);
  RejectionCollector status(*connection);
  BP_ASSERT_OK(events.subscriber().WaitForDaemon(20s));
  std::unique_ptr<client::UpdatePublisher> pub;
  BP_ASSERT_OK(client::UpdatePublisher::Create(*connection, 9, 5000ms, &pub));
  BP_ASSERT_OK(pub->WaitForDaemon(20s));

  SceneParams params;
  params.n = 300;
  params.moving = 40;
  params.churn = 4;
  params.density = 0.2;
  Scene scene(params);
  Oracle<3> oracle;
  PairList unc, col;
  FrameOps ops;
  ops.inserts = scene.Initial();
  for (uint64_t frame = 1; frame <= 10; ++frame) {
    if (frame > 1) scene.NextFrame(&ops);
    oracle.Apply(9, ops);
    oracle.Query(&unc, &col);
    wire::UpdateBatch batch;
    tools::FillSceneFrame(ops, 3, &batch);
    batch.set_frame(frame);
    // The last frame is left open: the signal must finish it.
    batch.set_end_of_frame(frame < 10);
    if (frame == 3) {  // one bad item among the good ones: refused, the rest applies
      client::AddBox<3>(batch.mutable_inserts(), 1'000'000,
                        Box<3, float>{{0, 0, 0}, {std::numeric_limits<float>::quiet_NaN(), 1, 1}});
    }
    BP_ASSERT_OK(pub->Publish(&batch));
    if (frame == 9) std::this_thread::sleep_for(300ms);  // periodic summaries (every 0.1 s)
    if (frame == 10) {
      BP_ASSERT_OK(pub->Flush(5s));
      daemon.Signal(sig);
    }
    FrameEvents got;
    ASSERT_TRUE(events.WaitFrame(frame, &got, 20s)) << "frame " << frame;
    EXPECT_EQ(got.uncollide, unc) << "frame " << frame;
    EXPECT_EQ(got.collide, col) << "frame " << frame;
  }
  ASSERT_TRUE(status.WaitFor(1));
  EXPECT_EQ(status.rejections()[0].reason(), wire::NOT_FINITE);
  EXPECT_EQ(status.rejections()[0].id(), 1'000'000u);
  EXPECT_EQ(daemon.Wait(), 0);
  const std::string log = ReadFile(dir + "/log");
  EXPECT_NE(log.find("insert["), std::string::npos) << "the rejection is not in the log:\n" << log;
  const size_t signal_at = log.find("finishing the frame");
  ASSERT_NE(signal_at, std::string::npos) << log;
  EXPECT_NE(log.find("stopped after 10 frames"), std::string::npos) << log;
  // A periodic summary line before the signal (the stop path prints one too; that one does not
  // count).
  const size_t summary_at = log.find("frames/s");
  EXPECT_LT(summary_at, signal_at) << "no periodic summary line before the signal:\n" << log;
}

TEST(DaemonProcess, SceneThenSigintFinishesTheFrameAndExits0) { SceneThenSignal(SIGINT); }
TEST(DaemonProcess, SceneThenSigtermFinishesTheFrameAndExits0) { SceneThenSignal(SIGTERM); }

TEST(DaemonProcess, CheckAndPrintConfig) {
  ScratchDir scratch;
  const std::string& dir = scratch.path();
  Process check({"--check-config", "--config", SourcePath("config/broadphased.yaml")},
                dir + "/check");
  EXPECT_EQ(check.Wait(), 0);
  EXPECT_NE(ReadFile(dir + "/check").find(": ok"), std::string::npos);
  Process print({"--print-config"}, dir + "/print");
  EXPECT_EQ(print.Wait(), 0);
  const std::string printed = ReadFile(dir + "/print");
  service::Config parsed;
  Status s = service::ParseConfig(printed, "printed", &parsed);
  EXPECT_TRUE(s.ok()) << s.ToString() << "\n" << printed;
}

// kill -9 of the daemon, then another one starts. The producer keeps its objects
// (restate_on_restart) and restates them to the new daemon when it sees its epoch; a subscriber
// sees the epoch change, resyncs from a snapshot, and ends with exactly the oracle's set.
TEST(DaemonProcess, AKilledDaemonIsReplacedAndRestatingProducersRestoreTheExactSet) {
  ScratchDir scratch;
  const std::string& dir = scratch.path();
  service::Config c = TestConfig(kDomain);
  const std::string config = WriteConfig(dir, ConfigText(c));
  auto daemon =
      std::make_unique<Process>(std::vector<std::string>{"--config", config}, dir + "/log1");

  Watcher watcher;
  ASSERT_NO_FATAL_FAILURE(OpenWatcher(c, &watcher));
  auto& [connection, sub, requests] = watcher.dds;
  RejectionCollector& status = *watcher.status;
  client::PublisherOptions options;
  options.restate_on_restart = true;
  std::unique_ptr<client::UpdatePublisher> pub;
  BP_ASSERT_OK(client::UpdatePublisher::Create(*connection, 4, options, &pub));
  BP_ASSERT_OK(pub->WaitForDaemon(20s));
  const uint64_t first_epoch = pub->daemon_epoch();
  client::OverlapView view;

  SceneParams params;
  params.n = 500;
  params.moving = 50;
  params.churn = 5;
  params.density = 0.2;
  params.seed = 44;
  Scene scene(params);
  Oracle<3> oracle;
  PairList unc, col;
  FrameOps ops;
  ops.inserts = scene.Initial();
  auto publish = [&](uint64_t frame) {
    oracle.Apply(4, ops);
    oracle.Query(&unc, &col);
    wire::UpdateBatch batch;
    tools::FillSceneFrame(ops, 3, &batch);
    batch.set_frame(frame);
    batch.set_end_of_frame(true);
    // A reliable writer waits for the killed daemon's reader until Cyclone's participant
    // lease (2 s in the loopback configuration) declares it dead: retry, as bpctl scene does.
    Status s = pub->Publish(&batch);
    for (int retry = 0; retry < 3 && s.code() == StatusCode::kDeadlineExceeded; ++retry) {
      s = pub->Publish(&batch);
    }
    BP_ASSERT_OK(s);
    scene.NextFrame(&ops);
  };
  for (uint64_t frame = 1; frame <= 5; ++frame) {
    publish(frame);
    ASSERT_TRUE(SyncTo(*sub, *requests, view, frame)) << view.last_loss();
  }
  ASSERT_EQ(view.SortedPairs(), oracle.Pairs());
  ASSERT_GT(oracle.Pairs().size(), 50u);

  daemon->Signal(SIGKILL);
  EXPECT_EQ(daemon->Wait(), -1) << "death by signal";
  daemon = std::make_unique<Process>(std::vector<std::string>{"--config", config}, dir + "/log2");
  // The new daemon's first report (its epoch), then its reader matched to the producer (the
  // killed daemon's reader may still count until Cyclone's participant lease expires).
  ASSERT_TRUE(status.WaitUntil(
      [&](const wire::DaemonStatus& r) { return r.epoch() != 0 && r.epoch() != first_epoch; },
      20s));
  (void)pub->WaitForReaders(2, 3s);
  for (uint64_t frame = 1; frame <= 5; ++frame) {
    publish(frame);
    std::this_thread::sleep_for(20ms);
  }
  ASSERT_TRUE(SyncUntil(*sub, *requests, view, [&](const client::OverlapView& v) {
    return v.epoch() != first_epoch && v.frame() == 6;
  })) << view.last_loss();
  EXPECT_EQ(view.SortedPairs(), oracle.Pairs());
  EXPECT_NE(view.epoch(), first_epoch);
  EXPECT_EQ(view.restarts(), 1u);
  EXPECT_EQ(view.contradictions(), 0u);
  EXPECT_EQ(pub->restates(), 1u);
  daemon->Signal(SIGTERM);
  EXPECT_EQ(daemon->Wait(), 0);
  const std::string log = ReadFile(dir + "/log2");
  EXPECT_NE(log.find("snapshot of frame"), std::string::npos) << log;
}

// kill -9 of a producer (bpctl scene). Its writer's liveliness lease (1 s) runs out, then
// the daemon's producers.lease_s (2 s); its objects are erased and every pair they were in is
// uncollided, exactly once.
TEST(DaemonProcess, AKilledProducersObjectsAreErasedAfterTheLease) {
  ScratchDir scratch;
  const std::string& dir = scratch.path();
  service::Config c = TestConfig(kDomain);
  const std::string config = WriteConfig(dir, ConfigText(c, /*lease_s=*/2.0));
  Process daemon({"--config", config}, dir + "/log");

  Watcher watcher;
  ASSERT_NO_FATAL_FAILURE(OpenWatcher(c, &watcher));
  auto& [connection, sub, requests] = watcher.dds;
  RejectionCollector& status = *watcher.status;
  // Producer 3 rests in this process; producer 8 is bpctl scene, killed below.
  std::unique_ptr<client::UpdatePublisher> resting;
  BP_ASSERT_OK(client::UpdatePublisher::Create(*connection, 3, 5000ms, &resting));
  BP_ASSERT_OK(resting->WaitForDaemon(20s));
  wire::UpdateBatch big;
  big.set_dim(3);
  big.set_end_of_frame(true);
  client::AddBox<3>(big.mutable_inserts(), 1,
                    Box<3, float>{{-1e6f, -1e6f, -1e6f}, {1e6f, 1e6f, 1e6f}});
  BP_ASSERT_OK(resting->Publish(&big));

  Process scene({"--config", config, "scene", "-n", "300", "--rate", "50", "--producer", "8",
                 "--seed", "5", "--quiet"},
                dir + "/scene.log", BPCTL);
  client::OverlapView view;
  // Running: the scene's 300 objects and the big box, all synced.
  const auto deadline = std::chrono::steady_clock::now() + 30s;
  auto asked = std::chrono::steady_clock::time_point{};
  uint64_t objects = 0;
  while (!(view.synced() && objects == 301 && view.size() > 300)) {
    ASSERT_LT(std::chrono::steady_clock::now(), deadline) << ReadFile(dir + "/scene.log");
    if (view.wants_snapshot() && std::chrono::steady_clock::now() - asked > 500ms) {
      BP_ASSERT_OK(requests->Request("test"));
      asked = std::chrono::steady_clock::now();
    }
    std::vector<wire::EventBatch> parts;
    BP_ASSERT_OK(sub->Poll(50ms, &parts));
    for (const auto& p : parts) {
      view.Apply(p);
      objects = p.objects();
    }
  }
  scene.Signal(SIGKILL);
  const auto killed = std::chrono::steady_clock::now();
  EXPECT_EQ(scene.Wait(), -1);
  // Every pair of producer 8 ends: the set keeps only producer 3's, which is none.
  while (!(view.synced() && objects == 1)) {
    ASSERT_LT(std::chrono::steady_clock::now(), killed + 20s) << "the objects were not erased";
    std::vector<wire::EventBatch> parts;
    BP_ASSERT_OK(sub->Poll(50ms, &parts));
    for (const auto& p : parts) {
      view.Apply(p);
      objects = p.objects();
    }
  }
  const double after =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - killed).count();
  // The writer's liveliness lease (1 s), then producers.lease_s (2 s).
  EXPECT_GE(after, 2.5) << "erased before producers.lease_s ran out";
  EXPECT_EQ(view.size(), 0u);
  EXPECT_EQ(view.contradictions(), 0u) << "an uncollide of a pair the view did not hold";
  EXPECT_EQ(view.resyncs(), 0u);
  ASSERT_TRUE(status.WaitUntil(
      [](const wire::DaemonStatus& r) { return r.producers_expired() == 1 && r.objects() == 1; }));
  daemon.Signal(SIGTERM);
  EXPECT_EQ(daemon.Wait(), 0);
  const std::string log = ReadFile(dir + "/log");
  EXPECT_NE(log.find("producer 8: its writer has not been alive"), std::string::npos) << log;
}

// A subscriber's interest (bpctl watch --region) lives as long as its process: killed with
// SIGKILL, its interest is dropped once its writer has not been alive for producers.lease_s.
// bpctl query answers a spot query from the command line.
TEST(DaemonProcess, ASubscriberKilledWithSigkillFreesItsInterest) {
  ScratchDir scratch;
  const std::string& dir = scratch.path();
  service::Config c = TestConfig(kDomain);
  const std::string config = WriteConfig(dir, ConfigText(c, /*lease_s=*/1.0));
  Process daemon({"--config", config}, dir + "/log");
  Watcher watcher;
  ASSERT_NO_FATAL_FAILURE(OpenWatcher(c, &watcher));
  RejectionCollector& status = *watcher.status;
  Process scene({"--config", config, "scene", "-n", "300", "--rate", "50", "--producer", "8",
                 "--seed", "5", "--quiet"},
                dir + "/scene.log", BPCTL);
  Process watch({"--config", config, "watch", "--region", "-1e6,-1e6,-1e6,1e6,1e6,1e6",
                 "--leave-margin", "1", "--pairs-inside", "--exact"},
                dir + "/watch.log", BPCTL);
  ASSERT_TRUE(status.WaitUntil([](const wire::DaemonStatus& r) { return r.interests() == 1; }, 20s))
      << ReadFile(dir + "/watch.log");
  // Its events flow: every object enters the region.
  const auto deadline = std::chrono::steady_clock::now() + 20s;
  while (ReadFile(dir + "/watch.log").find("collide region:0 8:") == std::string::npos) {
    ASSERT_LT(std::chrono::steady_clock::now(), deadline) << ReadFile(dir + "/watch.log");
    std::this_thread::sleep_for(50ms);
  }
  watch.Signal(SIGKILL);
  const auto killed = std::chrono::steady_clock::now();
  EXPECT_EQ(watch.Wait(), -1);
  const size_t before = status.reports().size();
  size_t index = 0;
  ASSERT_TRUE(status.WaitUntil(
      [&](const wire::DaemonStatus& r) {
        return index++ >= before && r.interests() == 0 && r.dropped_interests_size() == 1;
      },
      20s))
      << "the killed subscriber's interest was not dropped";
  const double after =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - killed).count();
  EXPECT_GE(after, 1.0) << "dropped before producers.lease_s ran out";

  Process query({"--config", config, "query", "--box", "-1e6,-1e6,-1e6,1e6,1e6,1e6"},
                dir + "/query.log", BPCTL);
  EXPECT_EQ(query.Wait(), 0) << ReadFile(dir + "/query.log");
  const std::string answer = ReadFile(dir + "/query.log");
  EXPECT_NE(answer.find("300 objects overlap the box at frame"), std::string::npos) << answer;
  daemon.Signal(SIGTERM);
  EXPECT_EQ(daemon.Wait(), 0);
  const std::string log = ReadFile(dir + "/log");
  EXPECT_NE(log.find("dropped: its writer has not been alive"), std::string::npos) << log;
}

// A producer (bpctl scene) stopped with SIGSTOP for 4 s: longer than Cyclone's
// participant lease (2 s), shorter than producers.lease_s (10 s). DDS drops it and discovers it
// again, and batches around the stall may be lost; the daemon asks it to restate. It keeps its
// id, nothing expires, and when the scene ends the daemon holds exactly the scene's last frame.
TEST(DaemonProcess, AProducerStoppedLongerThanTheParticipantLeaseEndsWithTheExactSet) {
  ScratchDir scratch;
  const std::string& dir = scratch.path();
  service::Config c = TestConfig(kDomain);
  const std::string config = WriteConfig(dir, ConfigText(c));
  Process daemon({"--config", config}, dir + "/log");

  Watcher watcher;
  ASSERT_NO_FATAL_FAILURE(OpenWatcher(c, &watcher));
  auto& [connection, sub, requests] = watcher.dds;
  RejectionCollector& status = *watcher.status;

  SceneParams params;
  params.n = 300;
  params.moving = 40;
  params.churn = 4;
  params.seed = 6;
  constexpr uint64_t kFrames = 240;  // 8 s at 30 Hz, plus the stall
  Process scene(
      {"--config", config, "scene", "-n", "300", "--moving", "40", "--churn", "4", "--seed", "6",
       "--rate", "30", "--frames", std::to_string(kFrames), "--producer", "8", "--quiet"},
      dir + "/scene.log", BPCTL);
  client::OverlapView view;
  ASSERT_TRUE(SyncUntil(
      *sub, *requests, view, [](const client::OverlapView& v) { return v.frame() >= 30; }, 30s))
      << ReadFile(dir + "/scene.log");
  scene.Signal(SIGSTOP);
  std::this_thread::sleep_for(4s);
  scene.Signal(SIGCONT);
  ASSERT_EQ(scene.Wait(60s), 0) << ReadFile(dir + "/scene.log");

  Scene expected(params);
  FrameOps ops;
  ops.inserts = expected.Initial();
  Oracle<3> oracle;
  PairList unc, col;
  for (uint64_t frame = 0; frame <= kFrames; ++frame) {
    if (frame > 0) expected.NextFrame(&ops);
    oracle.Apply(8, ops);
    oracle.Query(&unc, &col);
  }
  ASSERT_GT(oracle.Pairs().size(), 10u);
  const bool exact = SyncUntil(
      *sub, *requests, view,
      [&](const client::OverlapView& v) { return v.SortedPairs() == oracle.Pairs(); }, 20s);
  EXPECT_TRUE(exact) << "the daemon's set differs from the scene's last frame: "
                     << view.SortedPairs().size() << " pairs, the oracle " << oracle.Pairs().size()
                     << "\n"
                     << ReadFile(dir + "/log");
  EXPECT_EQ(view.contradictions(), 0u);
  status.Collect(300ms);
  ASSERT_FALSE(status.reports().empty());
  EXPECT_EQ(status.reports().back().objects(), 300u);
  EXPECT_EQ(status.reports().back().producers_expired(), 0u);
  daemon.Signal(SIGTERM);
  EXPECT_EQ(daemon.Wait(), 0);
  const std::string log = ReadFile(dir + "/log");
  // The stall was seen (DDS dropped the producer, or batches were lost), a restate was asked
  // for, and a whole one arrived.
  EXPECT_NE(log.find("asking it to restate"), std::string::npos) << log;
  EXPECT_NE(log.find("producer 8: restated 300 objects"), std::string::npos) << log;
  EXPECT_EQ(log.find("erased its"), std::string::npos) << log;
}

}  // namespace
}  // namespace bp::test
