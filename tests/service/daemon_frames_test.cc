// The daemon's frames: the frame log, event parts, tick frames, summaries and stop under load,
// doubles rounded outward into a float engine.
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

// Splits a CSV line (no quoting: the frame log has numbers only).
std::vector<std::string> CsvFields(const std::string& line) {
  std::vector<std::string> out;
  std::stringstream in(line);
  for (std::string field; std::getline(in, field, ',');) out.push_back(field);
  return out;
}

TEST(Daemon, FrameLogHasALinePerFrameWithItsStagesAndCounts) {
  const std::filesystem::path path = std::filesystem::temp_directory_path() /
                                     ("bp_frame_log_test_" + std::to_string(getpid()) + ".csv");
  service::Config config = TestConfig(kDomain);
  config.engine.algorithm = "grid_dense";
  config.logging.frame_log = path.string();
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(1);
  Scene scene(SmallScene(11));
  Oracle<3> oracle;
  PairList unc, col;
  FrameOps ops = InitialOps(scene);
  struct Expected {
    size_t inserts, updates, erases, collides, uncollides, objects;
  };
  std::vector<Expected> expected;
  for (uint64_t frame = 1; frame <= 6; ++frame) {
    if (frame > 1) scene.NextFrame(&ops);
    oracle.Apply(1, ops);
    oracle.Query(&unc, &col);
    expected.push_back({ops.inserts.size(), ops.updates.size(), ops.erases.size(), col.size(),
                        unc.size(), oracle.Size()});
    PublishFrame(*pub, ops, 3, frame, 2);
    ExpectFrame(*client.events, frame, unc, col);
  }
  BP_ASSERT_OK(daemon.Stop());  // flushes the log

  std::ifstream in(path);
  ASSERT_TRUE(in) << "no frame log at " << path;
  std::string header;
  ASSERT_TRUE(std::getline(in, header));
  const std::vector<std::string> names = CsvFields(header);
  auto column = [&](const char* name) {
    const auto it = std::find(names.begin(), names.end(), name);
    EXPECT_NE(it, names.end()) << "no column " << name;
    return static_cast<size_t>(it - names.begin());
  };
  std::vector<std::vector<std::string>> rows;
  for (std::string line; std::getline(in, line);) rows.push_back(CsvFields(line));
  ASSERT_EQ(rows.size(), expected.size());
  for (size_t i = 0; i < rows.size(); ++i) {
    const std::vector<std::string>& row = rows[i];
    ASSERT_EQ(row.size(), names.size()) << "line " << i + 2;
    auto number = [&](const char* name) { return std::stod(row.at(column(name))); };
    const Expected& e = expected[i];
    SCOPED_TRACE("frame " + std::to_string(i + 1));
    EXPECT_EQ(number("frame"), static_cast<double>(i + 1));
    EXPECT_EQ(number("source_producer"), 1.0);
    EXPECT_EQ(number("source_frame"), static_cast<double>(i + 1));
    EXPECT_GT(number("source_sent_ns"), 0.0);
    EXPECT_GT(number("wall_ns"), number("source_sent_ns"));
    EXPECT_EQ(number("batches"), 2.0);
    EXPECT_EQ(number("inserts"), static_cast<double>(e.inserts));
    EXPECT_EQ(number("updates"), static_cast<double>(e.updates));
    EXPECT_EQ(number("erases"), static_cast<double>(e.erases));
    EXPECT_EQ(number("collides"), static_cast<double>(e.collides));
    EXPECT_EQ(number("uncollides"), static_cast<double>(e.uncollides));
    EXPECT_EQ(number("objects"), static_cast<double>(e.objects));
    for (const char* ms : {"ingest_ms", "query_ms", "publish_ms", "core_ms", "cells_ms"}) {
      EXPECT_GE(number(ms), 0.0) << ms;
    }
    EXPECT_GT(number("query_ms"), 0.0);
    EXPECT_GT(number("cells_queried"), 0.0);
  }
  std::filesystem::remove(path);
}

TEST(Daemon, AFrameLogThatCannotBeOpenedFailsTheStartNamingIt) {
  service::Config config = TestConfig(kDomain);
  config.logging.frame_log = "/nonexistent-dir-bp/frames.csv";
  std::unique_ptr<service::Daemon> daemon;
  Status s = service::Daemon::Create(config, &daemon);
  EXPECT_EQ(s.code(), StatusCode::kUnavailable);
  EXPECT_NE(s.message().find("logging.frame_log: cannot open '/nonexistent-dir-bp/frames.csv'"),
            std::string::npos)
      << s.message();
  EXPECT_EQ(daemon, nullptr);
}

TEST(Daemon, LargeFramesAreSplitIntoParts) {
  service::Config config = TestConfig(kDomain);
  config.limits.max_pairs_per_event_batch = 7;
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(1);
  Scene scene(SmallScene(3));
  Oracle<3> oracle;
  PairList unc, col;
  FrameOps ops = InitialOps(scene);
  for (uint64_t frame = 1; frame <= 5; ++frame) {
    if (frame > 1) scene.NextFrame(&ops);
    oracle.Apply(1, ops);
    oracle.Query(&unc, &col);
    PublishFrame(*pub, ops, 3, frame, 1);
    FrameEvents got;
    ASSERT_TRUE(client.events->WaitFrame(frame, &got));
    EXPECT_EQ(got.uncollide, unc);
    EXPECT_EQ(got.collide, col);
    EXPECT_EQ(got.parts, std::max<size_t>(1, (unc.size() + col.size() + 6) / 7));
  }
  // Sequence numbers run 1, 2, 3... over all parts.
  const auto& seqs = client.events->sequences();
  for (size_t i = 0; i < seqs.size(); ++i) EXPECT_EQ(seqs[i], i + 1);
}

TEST(Daemon, TickFramesCloseWithoutEndOfFrame) {
  service::Config config = TestConfig(kDomain);
  config.frames.boundary = service::FrameBoundary::kTick;
  config.frames.tick_ms = 20;
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(1);
  wire::UpdateBatch batch = InsertBatch({{1, Cube(0)}, {2, Cube(0.5f)}});
  batch.set_end_of_frame(false);
  BP_ASSERT_OK(pub->Publish(&batch));
  // Frames keep coming on the tick (the first ones may pass before this subscriber matched);
  // the pair shows up in one of them.
  bool seen = false;
  uint64_t previous = 0;
  for (int i = 0; i < 500 && !seen; ++i) {
    FrameEvents fe;
    ASSERT_TRUE(client.events->NextFrame(&fe, 5s)) << "tick frames stopped after " << previous;
    EXPECT_GT(fe.frame, previous);
    previous = fe.frame;
    seen = !fe.collide.empty();
    EXPECT_EQ(fe.last.source_producer(), 0u);
  }
  EXPECT_TRUE(seen);
}

// A producer that never pauses and a daemon slower than it (every batch closes a frame of a
// brute-force query over 1000 crowded boxes, O(n^2) and validated): the update queue never
// empties, and periodic status reports and a stop request must still be served (a drain that
// waited for an empty queue starved them until the producer stopped; this test caught it).
TEST(Daemon, SummariesAndStopAreServedUnderSustainedLoad) {
  service::Config config = TestConfig(kDomain);
  config.engine.algorithm = "brute_force";
  config.dds.update_queue = 4;
  config.logging.summary_interval_s = 0.05;
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(1, 300ms);
  constexpr uint64_t kBoxes = 1000;
  std::atomic<bool> run{true};
  std::atomic<uint64_t> sent{0};
  std::thread producer([&] {
    wire::UpdateBatch batch;
    batch.set_dim(3);
    batch.set_end_of_frame(true);
    for (uint64_t id = 0; id < kBoxes; ++id) {
      client::AddBox<3>(batch.mutable_inserts(), id, Cube(static_cast<float>(id % 100)));
    }
    while (!pub->Publish(&batch).ok() && run.load()) {
    }
    batch.mutable_inserts()->Clear();
    float shift = 0;
    while (run.load()) {
      batch.mutable_updates()->Clear();
      shift += 0.01f;
      for (uint64_t id = 0; id < kBoxes; ++id) {
        client::AddBox<3>(batch.mutable_updates(), id, Cube(static_cast<float>(id % 100) + shift));
      }
      if (pub->Publish(&batch).ok()) ++sent;  // DeadlineExceeded is back-pressure: try again
    }
  });
  // Whatever happens below, the producer stops after 20 s (a starved stop would hang forever).
  std::thread watchdog([&] {
    for (int i = 0; i < 2000 && run.load(); ++i) std::this_thread::sleep_for(10ms);
    run.store(false);
  });
  FrameEvents fe;
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(client.events->NextFrame(&fe, 10s));
  // Periodic reports (with interval statistics) keep coming while the producer floods.
  size_t periodic = 0;
  const auto until = std::chrono::steady_clock::now() + 8s;
  while (periodic < 3 && std::chrono::steady_clock::now() < until && run.load()) {
    std::vector<wire::DaemonStatus> reports;
    BP_ASSERT_OK(client.status->subscriber().Poll(100ms, &reports));
    for (auto& r : reports) {
      if (!r.has_interval() || r.interval().frames() == 0) continue;
      ++periodic;
      // Every frame decodes 1000 updates, queries 1000 boxes and publishes a part, so each
      // stage takes time; no stage of a frame exceeds the frame's work.
      const wire::IntervalStats& i = r.interval();
      for (auto [p50, p99, what] :
           {std::tuple{i.ingest_ms_p50(), i.ingest_ms_p99(), "ingest"},
            std::tuple{i.query_ms_p50(), i.query_ms_p99(), "query"},
            std::tuple{i.publish_ms_p50(), i.publish_ms_p99(), "publish"}}) {
        EXPECT_GT(p50, 0.0) << what;
        EXPECT_LE(p50, p99) << what;
        EXPECT_LE(p99, i.frame_ms_max()) << what;
      }
      EXPECT_LE(i.frame_ms_p50(), i.frame_ms_p99());
    }
  }
  EXPECT_GE(periodic, 3u) << "no periodic status while the producer floods";
  const bool flooding = run.load();
  const auto start = std::chrono::steady_clock::now();
  Status stopped = daemon.Stop();
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const bool still_flooding = run.load();
  run.store(false);
  producer.join();
  watchdog.join();
  BP_ASSERT_OK(stopped);
  EXPECT_TRUE(flooding && still_flooding) << "the stop came only after the producer stopped";
  EXPECT_LT(seconds, 5.0) << "stop took " << seconds << " s under load";
  EXPECT_GT(sent.load(), 5u);
  std::printf("stop took %.3f s; %llu batches sent\n", seconds,
              static_cast<unsigned long long>(sent.load()));
}

TEST(Daemon, StopFinishesTheFrameAndPublishesItsEvents) {
  service::Config config = TestConfig(kDomain);
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(1);
  wire::UpdateBatch batch = InsertBatch({{1, Cube(0)}, {2, Cube(0.5f)}});
  batch.set_end_of_frame(false);  // the frame is still open when the stop comes
  BP_ASSERT_OK(pub->Publish(&batch));
  BP_ASSERT_OK(pub->Flush(5s));
  // The batch is acknowledged by the daemon's reader; it may not be processed yet.
  BP_ASSERT_OK(daemon.Stop());
  ExpectFrame(*client.events, 1, {}, {{service::GlobalKey(1, 1), service::GlobalKey(1, 2)}});
  EXPECT_EQ(daemon.daemon().frames(), 1u);
  // STOPPING was reported.
  bool stopping = false;
  const auto deadline = std::chrono::steady_clock::now() + 5s;
  while (!stopping && std::chrono::steady_clock::now() < deadline) {
    std::vector<wire::DaemonStatus> reports;
    BP_ASSERT_OK(client.status->subscriber().Poll(100ms, &reports));
    for (auto& r : reports) stopping |= r.health() == wire::STOPPING;
    for (auto& r : client.status->reports()) stopping |= r.health() == wire::STOPPING;
  }
  EXPECT_TRUE(stopping);
}

TEST(Daemon, DoublesToAFloatEngineRoundOutward) {
  service::Config config = TestConfig(kDomain);
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(1);
  // 0.1 is not a float: box 1's hi rounds up and box 2's lo rounds down, so boxes that touch in
  // double arithmetic still touch as floats.
  wire::UpdateBatch batch;
  batch.set_dim(3);
  batch.set_end_of_frame(true);
  client::AddBox<3>(batch.mutable_inserts(), 1, Box<3, double>{{0, 0, 0}, {0.1, 1, 1}});
  wire::UpdateBatch second = batch;
  second.mutable_inserts()->Clear();
  BP_ASSERT_OK(pub->Publish(&batch));
  ExpectFrame(*client.events, 1, {}, {});
  client::AddBox<3>(second.mutable_inserts(), 2, Box<3, double>{{0.1, 0, 0}, {1, 1, 1}});
  client::AddBox<3>(second.mutable_inserts(), 3, Box<3, double>{{0, 0, 0}, {1e300, 1, 1}});
  BP_ASSERT_OK(pub->Publish(&second));
  ExpectFrame(*client.events, 2, {}, {{service::GlobalKey(1, 1), service::GlobalKey(1, 2)}});
  ASSERT_TRUE(client.status->WaitFor(1));
  EXPECT_EQ(client.status->rejections()[0].reason(), wire::NOT_FINITE);
  // The value in its short form, not the 300 digits of printf's %f.
  EXPECT_NE(client.status->rejections()[0].message().find(
                "hi on axis 0 is 1e+300, out of the engine's float range"),
            std::string::npos)
      << client.status->rejections()[0].message();
}

}  // namespace
}  // namespace bp::test
