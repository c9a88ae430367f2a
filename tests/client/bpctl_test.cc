// bpctl's commands in-process against the daemon on loopback DDS (domain BP_TEST_DOMAIN, a
// partition per test): scene + record, replay into a fresh daemon gives the same events, the
// recording through another engine gives the same events, and check agrees with both.
#include <cinttypes>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>

#include "../service/service_test_support.h"
#include "commands.h"

#include "bp/transport/recording.h"

namespace bp::test {
namespace {

constexpr uint32_t kDomain = BP_TEST_DOMAIN;
using FrameMap = std::map<uint64_t, std::pair<PairList, PairList>>;  // frame -> (unc, col)

std::string TempFile(const std::string& name) {
  return (std::filesystem::temp_directory_path() / (TestPartition() + "-" + name)).string();
}

// Collects frames 1..frames from a daemon's event topic.
FrameMap CollectFrames(EventCollector& events, uint64_t frames) {
  FrameMap out;
  for (uint64_t f = 1; f <= frames; ++f) {
    FrameEvents fe;
    EXPECT_TRUE(events.WaitFrame(f, &fe, 20s)) << "frame " << f;
    out[f] = {fe.uncollide, fe.collide};
  }
  return out;
}

// Runs a daemon with config, starts `publish` on a thread (scene or replay), and returns the
// events of frames 1..frames.
template <class Publish>
FrameMap RunDaemon(const service::Config& config, uint64_t frames, Publish publish) {
  InProcessDaemon daemon(config);
  std::unique_ptr<transport::Connection> connection;
  EXPECT_TRUE(transport::Connection::Open(ClientOptions(config), &connection).ok());
  EventCollector events(*connection);
  EXPECT_TRUE(events.subscriber().WaitForDaemon(10s).ok());
  std::thread publisher(publish);
  FrameMap got = CollectFrames(events, frames);
  publisher.join();
  EXPECT_TRUE(daemon.Stop().ok());
  return got;
}

// A scene of n objects (a tenth moving, a hundredth churned) at 40 Hz for 120 frames, quiet: a
// few seconds of traffic for a watcher.
bpctl::SceneOptions WatchedScene(uint32_t n) {
  bpctl::SceneOptions scene;
  scene.params.n = n;
  scene.params.moving = n / 10;
  scene.params.churn = n / 100;
  scene.params.density = 0.1;
  scene.rate_hz = 40;
  scene.frames = 120;
  scene.quiet = true;
  return scene;
}

TEST(Bpctl, RecordReplayAndCheckGiveIdenticalEvents) {
  service::Config config = TestConfig(kDomain);
  bpctl::Common common;
  common.config = config;
  const std::string file = TempFile("scene.bprec");
  constexpr uint64_t kFrames = 30;  // the initial frame and 29 more

  bpctl::SceneOptions scene;
  scene.params.n = 1500;
  scene.params.moving = 150;
  scene.params.churn = 20;
  scene.params.density = 0.1;
  scene.rate_hz = 0;
  scene.frames = kFrames - 1;
  scene.readers = 2;  // the daemon and the recorder
  scene.quiet = true;
  bpctl::RecordOptions record;
  record.file = file;
  record.batches = kFrames;

  // 1. Live: scene -> daemon (segmented_sap), recorded on the side.
  int record_rc = -1;
  std::thread recorder([&] { record_rc = bpctl::Record(common, record); });
  FrameMap live = RunDaemon(config, kFrames, [&] { EXPECT_EQ(bpctl::Scene(common, scene), 0); });
  recorder.join();
  ASSERT_EQ(record_rc, 0);
  size_t events = 0;
  for (auto& [f, e] : live) events += e.first.size() + e.second.size();
  EXPECT_GT(events, 1000u);

  // 2. Replay into a fresh daemon: the same events, frame by frame.
  bpctl::ReplayOptions replay;
  replay.file = file;
  replay.fast = true;
  replay.progress = false;
  FrameMap replayed =
      RunDaemon(config, kFrames, [&] { EXPECT_EQ(bpctl::Replay(common, replay), 0); });
  EXPECT_EQ(replayed, live);

  // 3. The recording at its recorded pace (x4) through a brute-force daemon: the same events.
  service::Config brute = config;
  brute.engine.algorithm = "brute_force";
  replay.fast = false;
  replay.speed = 4;
  FrameMap oracle = RunDaemon(brute, kFrames, [&] { EXPECT_EQ(bpctl::Replay(common, replay), 0); });
  EXPECT_EQ(oracle, live);

  // 4. check: the embedded engine agrees with brute force, and with what the daemon published.
  bpctl::CheckOptions check;
  check.file = file;
  check.quiet = true;
  bpctl::CheckResult result;
  ASSERT_EQ(bpctl::Check(common, check, &result), 0);
  EXPECT_TRUE(result.identical);
  EXPECT_EQ(result.frames, kFrames);
  EXPECT_EQ(result.batches, kFrames);
  FrameMap checked;
  for (auto& [f, p] : result.uncollides) checked[f].first.push_back(p);
  for (auto& [f, p] : result.collides) checked[f].second.push_back(p);
  for (uint64_t f = 1; f <= kFrames; ++f) checked[f];  // frames without events
  EXPECT_EQ(checked, live);
  // ... and so does the batch engine.
  bpctl::CheckOptions batch_check = check;
  batch_check.engine = "batch_sap";
  bpctl::CheckResult batch_result;
  ASSERT_EQ(bpctl::Check(common, batch_check, &batch_result), 0);
  EXPECT_TRUE(batch_result.identical);
  EXPECT_EQ(batch_result.collides, result.collides);
  EXPECT_EQ(batch_result.uncollides, result.uncollides);

  // 5. A recorder killed mid-write leaves a partial last batch: check keeps the complete ones.
  std::filesystem::resize_file(file, std::filesystem::file_size(file) - 10);
  bpctl::CheckResult truncated;
  ASSERT_EQ(bpctl::Check(common, check, &truncated), 0);
  EXPECT_EQ(truncated.batches, kFrames - 1);
  EXPECT_EQ(truncated.frames, kFrames - 1);
  std::filesystem::remove(file);
}

TEST(Bpctl, CheckCountsRejectionsAndRefusesBadInput) {
  bpctl::Common common;
  common.config = TestConfig(kDomain);
  bpctl::CheckOptions check;
  check.file = TempFile("missing.bprec");
  check.quiet = true;
  EXPECT_EQ(bpctl::Check(common, check), 1);
  check.engine = "octree";
  // A valid recording with a rejected item: check reports it but passes.
  const std::string file = TempFile("bad.bprec");
  {
    wire::RecordingWriter writer;
    ASSERT_TRUE(writer.Open(file, wire::RecordingHeader()).ok());
    wire::UpdateBatch b;
    b.set_version(wire::SCHEMA_VERSION_1);
    b.set_producer(1);
    b.set_dim(3);
    b.set_end_of_frame(true);
    client::AddBox<3>(b.mutable_inserts(), 1, Box<3, float>{{0, 0, 0}, {1, 1, 1}});
    client::AddBox<3>(b.mutable_inserts(), 2, Box<3, float>{{0, 0, 0}, {1, 1, 1}});
    client::AddBox<3>(b.mutable_inserts(), 3, Box<3, float>{{2, 0, 0}, {1, 1, 1}});
    ASSERT_TRUE(writer.Append(1, b.SerializeAsString()).ok());
    ASSERT_TRUE(writer.Append(2, "garbage").ok());
  }
  check.file = file;
  EXPECT_EQ(bpctl::Check(common, check), 2) << "unknown engine";
  check.engine = "";
  bpctl::CheckResult result;
  EXPECT_EQ(bpctl::Check(common, check, &result), 0);
  EXPECT_EQ(result.rejected, 2u);  // the inverted box and the garbage batch
  EXPECT_EQ(result.events, 1u);
  std::filesystem::remove(file);
}

// bpctl watch --exact joins a running scene late, syncs from a snapshot and checks its set
// against the daemon's count after every frame.
TEST(Bpctl, WatchExactJoinsLateAndAgreesWithTheDaemon) {
  service::Config config = TestConfig(kDomain);
  bpctl::Common common;
  common.config = config;
  common.wait_s = 10;
  const bpctl::SceneOptions scene = WatchedScene(1000);
  InProcessDaemon daemon(config);
  std::thread publisher([&] { EXPECT_EQ(bpctl::Scene(common, scene), 0); });
  std::this_thread::sleep_for(500ms);  // the scene is running: this watcher joins late
  bpctl::WatchOptions watch;
  watch.stats = true;
  watch.exact = true;
  watch.seconds = 2;
  EXPECT_EQ(bpctl::Watch(common, watch), 0);
  publisher.join();
  EXPECT_GE(daemon.daemon().snapshots(), 1u);
  EXPECT_TRUE(daemon.Stop().ok());
}

// watch --latency-log writes one CSV line per frame: the scene's stamp, the daemon's
// publication and the arrival, in that order of time; an unwritable path is refused at start.
TEST(Bpctl, WatchLatencyLogHasOneOrderedLinePerFrame) {
  service::Config config = TestConfig(kDomain);
  bpctl::Common common;
  common.config = config;
  common.wait_s = 10;
  bpctl::WatchOptions watch;
  watch.stats = true;
  watch.latency_log = "/nonexistent-dir/latency.csv";
  const auto refused_at = std::chrono::steady_clock::now();
  EXPECT_EQ(bpctl::Watch(common, watch), 1) << "an unwritable --latency-log";
  // Refused before it waits for a daemon (there is none yet; that wait is common.wait_s).
  EXPECT_LT(std::chrono::steady_clock::now() - refused_at, 5s);

  const bpctl::SceneOptions scene = WatchedScene(500);
  InProcessDaemon daemon(config);
  std::thread publisher([&] { EXPECT_EQ(bpctl::Scene(common, scene), 0); });
  const std::string file = TempFile("latency.csv");
  struct RemoveFile {
    std::string path;
    ~RemoveFile() { std::filesystem::remove(path); }
  } remove_file{file};
  watch.latency_log = file;
  watch.seconds = 2;
  testing::internal::CaptureStdout();
  EXPECT_EQ(bpctl::Watch(common, watch), 0);
  const std::string out = testing::internal::GetCapturedStdout();
  publisher.join();
  EXPECT_TRUE(daemon.Stop().ok());
  // The totals split the latency at the daemon's publication, with numbers (every frame here
  // carries both stamps).
  const size_t totals = out.find("total after");
  ASSERT_NE(totals, std::string::npos) << out;
  double up50 = -1, up99 = -1, down50 = -1, down99 = -1;
  const size_t legs = out.find("(to the daemon's publication", totals);
  ASSERT_NE(legs, std::string::npos) << out;
  ASSERT_EQ(std::sscanf(out.c_str() + legs,
                        "(to the daemon's publication p50 %lf p99 %lf, delivery p50 %lf p99 %lf)",
                        &up50, &up99, &down50, &down99),
            4)
      << out.substr(totals);
  EXPECT_GE(up50, 0);
  EXPECT_GE(up99, up50);
  EXPECT_GE(down50, 0);
  EXPECT_GE(down99, down50);

  std::ifstream in(file);
  std::string line;
  ASSERT_TRUE(std::getline(in, line));
  EXPECT_EQ(line, "frame,sent_ns,published_ns,arrived_ns");
  size_t lines = 0;
  uint64_t last_frame = 0;
  while (std::getline(in, line)) {
    uint64_t frame = 0, sent = 0, published = 0, arrived = 0;
    ASSERT_EQ(std::sscanf(line.c_str(), "%" SCNu64 ",%" SCNu64 ",%" SCNu64 ",%" SCNu64, &frame,
                          &sent, &published, &arrived),
              4)
        << line;
    EXPECT_GT(frame, last_frame) << line;
    EXPECT_GT(sent, 0u) << line;
    EXPECT_LE(sent, published) << line;
    EXPECT_LE(published, arrived) << line;
    last_frame = frame;
    ++lines;
  }
  EXPECT_GE(lines, 20u) << "two seconds of a 40 Hz scene";
}

}  // namespace
}  // namespace bp::test
