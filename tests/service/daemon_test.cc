// The daemon in-process with real Cyclone DDS on loopback (domain BP_TEST_DOMAIN, a partition
// per test): scripted scenes against the oracle frame by frame, every bad input, several
// producers, tick frames, event parts, clean shutdown.
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

#include "service_test_support.h"

namespace bp::test {
namespace {

constexpr uint32_t kDomain = BP_TEST_DOMAIN;

struct Client {
  std::unique_ptr<client::Connection> connection;
  std::unique_ptr<EventCollector> events;
  std::unique_ptr<RejectionCollector> status;

  explicit Client(const service::Config& config) {
    Status s = client::Connection::Open(ClientOptions(config), &connection);
    EXPECT_TRUE(s.ok()) << s.ToString();
    events = std::make_unique<EventCollector>(*connection);
    status = std::make_unique<RejectionCollector>(*connection);
    EXPECT_TRUE(events->subscriber().WaitForDaemon(10s).ok());
    EXPECT_TRUE(status->subscriber().WaitForDaemon(10s).ok());
  }
  std::unique_ptr<client::UpdatePublisher> Publisher(
      uint32_t producer, std::chrono::milliseconds write_timeout = 5000ms) {
    std::unique_ptr<client::UpdatePublisher> p;
    Status s = client::UpdatePublisher::Create(*connection, producer, write_timeout, &p);
    EXPECT_TRUE(s.ok()) << s.ToString();
    EXPECT_TRUE(p->WaitForDaemon(10s).ok());
    return p;
  }
  /// A publisher that keeps its objects and restates them (restate_on_restart).
  std::unique_ptr<client::UpdatePublisher> RestatingPublisher(uint32_t producer) {
    client::PublisherOptions options;
    options.restate_on_restart = true;
    std::unique_ptr<client::UpdatePublisher> p;
    Status s = client::UpdatePublisher::Create(*connection, producer, options, &p);
    EXPECT_TRUE(s.ok()) << s.ToString();
    EXPECT_TRUE(p->WaitForDaemon(10s).ok());
    return p;
  }
};

SceneParams SmallScene(uint64_t seed, int dim = 3) {
  SceneParams p;
  p.dim = dim;
  p.n = 400;
  p.moving = 60;
  p.churn = 6;
  p.density = 0.2;  // dense enough for plenty of events
  p.seed = seed;
  return p;
}

FrameOps InitialOps(const Scene& scene) {
  FrameOps ops;
  ops.inserts = scene.Initial();
  return ops;
}

void ExpectFrame(EventCollector& events, uint64_t frame, const PairList& uncollide,
                 const PairList& collide) {
  FrameEvents got;
  ASSERT_TRUE(events.WaitFrame(frame, &got)) << "no events for frame " << frame;
  EXPECT_EQ(got.uncollide, uncollide) << "uncollides of frame " << frame;
  EXPECT_EQ(got.collide, collide) << "collides of frame " << frame;
}

// Publishes ops as one frame, split into `batches` batches; the last closes the frame.
void PublishFrame(client::UpdatePublisher& pub, const FrameOps& ops, int dim, uint64_t frame,
                  int batches, bool end_of_frame = true) {
  const size_t nb = static_cast<size_t>(batches);
  for (size_t part = 0; part < nb; ++part) {
    FrameOps slice;
    auto take = [&](const auto& all, auto& out) {
      const size_t lo = all.size() * part / nb, hi = all.size() * (part + 1) / nb;
      out.assign(all.begin() + static_cast<std::ptrdiff_t>(lo),
                 all.begin() + static_cast<std::ptrdiff_t>(hi));
    };
    take(ops.erases, slice.erases);
    take(ops.inserts, slice.inserts);
    take(ops.updates, slice.updates);
    wire::UpdateBatch batch;
    client::FillSceneFrame(slice, dim, &batch);
    batch.set_frame(frame);
    batch.set_end_of_frame(end_of_frame && part + 1 == nb);
    Status s = pub.Publish(&batch);
    ASSERT_TRUE(s.ok()) << s.ToString();
  }
}

template <int K>
void RunScene(const char* algorithm, int keep_cpus_awake_ms = 0) {
  service::Config config = TestConfig(kDomain);
  config.engine.algorithm = algorithm;
  config.frames.keep_cpus_awake_ms = keep_cpus_awake_ms;
  config.engine.dimension = K;
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(1);
  Scene scene(SmallScene(7, K));
  Oracle<K> oracle;
  PairList unc, col;
  FrameOps ops = InitialOps(scene);
  size_t events = 0;
  for (uint64_t frame = 1; frame <= 25; ++frame) {
    if (frame > 1) scene.NextFrame(&ops);
    oracle.Apply(1, ops);
    oracle.Query(&unc, &col);
    events += unc.size() + col.size();
    PublishFrame(*pub, ops, K, frame, 1 + static_cast<int>(frame % 3));
    ExpectFrame(*client.events, frame, unc, col);
  }
  EXPECT_GT(events, 200u) << "the scene should produce plenty of events";
  FrameEvents last;
  ASSERT_TRUE(client.events->WaitFrame(25, &last));
  EXPECT_EQ(last.last.objects(), oracle.Size());
  EXPECT_EQ(last.last.source_producer(), 1u);
  EXPECT_EQ(last.last.source_frame(), 25u);
  EXPECT_GT(last.last.source_sent_time_ns(), 0u);
  if (keep_cpus_awake_ms > 0) {
    EXPECT_GE(daemon.daemon().cpus_kept_awake(), 1u) << "the CPUs were not kept awake";
  }
  BP_ASSERT_OK(daemon.Stop());
  EXPECT_EQ(daemon.daemon().rejected(), 0u);
  EXPECT_EQ(daemon.daemon().cpus_kept_awake(), 0u);
  EXPECT_EQ(client.events->subscriber().gaps(), 0u);
}

TEST(Daemon, SceneMatchesOracleFrameByFrame3D) { RunScene<3>("segmented_sap"); }
TEST(Daemon, SceneMatchesOracleFrameByFrame2D) { RunScene<2>("segmented_sap"); }
TEST(Daemon, BatchSapSceneMatchesOracleFrameByFrame3D) { RunScene<3>("batch_sap"); }
TEST(Daemon, DynamicOctreeSceneMatchesOracleFrameByFrame3D) { RunScene<3>("dynamic_octree"); }
TEST(Daemon, SceneMatchesOracleWithBruteForceEngine) { RunScene<3>("brute_force"); }
TEST(Daemon, GridSceneMatchesOracleFrameByFrame3D) { RunScene<3>("grid_segmented_sap"); }
TEST(Daemon, GridBatchSceneMatchesOracleFrameByFrame2D) { RunScene<2>("grid_batch_sap"); }
TEST(Daemon, GridDenseSceneMatchesOracleFrameByFrame3D) { RunScene<3>("grid_dense"); }
// The CPUs kept awake (frames.keep_cpus_awake_ms) by SCHED_IDLE spinners change no event.
TEST(Daemon, SceneMatchesOracleWithTheCpusKeptAwake) { RunScene<3>("grid_dense", 50); }

wire::UpdateBatch InsertBatch(std::initializer_list<std::pair<uint64_t, Box<3, float>>> boxes) {
  wire::UpdateBatch batch;
  batch.set_dim(3);
  batch.set_end_of_frame(true);
  for (auto& [id, box] : boxes) client::AddBox<3>(batch.mutable_inserts(), id, box);
  return batch;
}

Box<3, float> Cube(float x, float w = 1.0f) { return Box<3, float>{{x, 0, 0}, {x + w, w, w}}; }

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

TEST(Daemon, EachBadItemIsRejectedWithItsReasonAndTheRestApplies) {
  service::Config config = TestConfig(kDomain);
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(4);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  // Frame 1: ids 1 and 2 overlap and are valid; everything else in the batch is bad.
  wire::UpdateBatch batch = InsertBatch({{1, Cube(0)},
                                         {2, Cube(0.5f)},
                                         {3, Box<3, float>{{nan, 0, 0}, {1, 1, 1}}},
                                         {4, Box<3, float>{{0, 0, 0}, {1, inf, 1}}},
                                         {5, Box<3, float>{{0, 2, 0}, {1, 1, 1}}},
                                         {1, Cube(9)},
                                         {uint64_t{1} << 48, Cube(0)}});
  client::AddBox<3>(batch.mutable_updates(), 77, Cube(0));
  batch.add_erases(78);
  BP_ASSERT_OK(pub->Publish(&batch));
  ASSERT_TRUE(client.status->WaitFor(7));
  struct Expect {
    wire::Op op;
    uint32_t index;
    wire::RejectReason reason;
    const char* text;
  };
  const Expect expected[] = {
      {wire::OP_INSERT, 2, wire::NOT_FINITE, "insert[2] id 3: lo on axis 0 is NaN"},
      {wire::OP_INSERT, 3, wire::NOT_FINITE, "insert[3] id 4: hi on axis 1 is infinite"},
      {wire::OP_INSERT, 4, wire::INVERTED, "insert[4] id 5: lo > hi on axis 1"},
      {wire::OP_INSERT, 5, wire::DUPLICATE_INSERT, "already has an object with this id"},
      {wire::OP_INSERT, 6, wire::ID_OUT_OF_RANGE, "below 2^48"},
      {wire::OP_UPDATE, 0, wire::UNKNOWN_ID, "update[0] id 77: no such object of producer 4"},
      {wire::OP_ERASE, 0, wire::UNKNOWN_ID, "erase[0] id 78: no such object of producer 4"},
  };
  for (const auto& e : expected) {
    const wire::Rejection* r = client.status->Find(e.op, e.index);
    ASSERT_NE(r, nullptr) << "no rejection for op " << e.op << " index " << e.index;
    EXPECT_EQ(r->reason(), e.reason) << r->message();
    EXPECT_NE(r->message().find(e.text), std::string::npos) << r->message();
    EXPECT_EQ(r->producer(), 4u);
  }
  EXPECT_EQ(client.status->rejections().size(), 7u);
  // The valid rest applied: 1 and 2 collide.
  ExpectFrame(*client.events, 1, {}, {{service::GlobalKey(4, 1), service::GlobalKey(4, 2)}});
  EXPECT_EQ(daemon.daemon().rejected(), 7u);
}

TEST(Daemon, BatchLevelFaultsAreRejectedAndTheDaemonKeepsServing) {
  service::Config config = TestConfig(kDomain);
  config.limits.max_batch_bytes = 4096;
  config.limits.max_batch_items = 100;
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(5);
  size_t expected = 0;
  auto expect_rejection = [&](wire::RejectReason reason, const char* text) {
    ++expected;
    ASSERT_TRUE(client.status->WaitFor(expected)) << "no rejection " << text;
    const wire::Rejection& r = client.status->rejections().back();
    EXPECT_EQ(r.reason(), reason) << r.message();
    EXPECT_NE(r.message().find(text), std::string::npos) << r.message();
  };
  // Malformed protobuf.
  BP_ASSERT_OK(pub->PublishRaw(std::string("\xff\xff\xff\xff garbage", 12)));
  expect_rejection(wire::MALFORMED, "is not a valid UpdateBatch");
  // Oversize in bytes, then in items.
  BP_ASSERT_OK(pub->PublishRaw(std::string(5000, '\0')));
  expect_rejection(wire::OVERSIZE, "exceeds limits.max_batch_bytes = 4096");
  wire::UpdateBatch many;
  many.set_dim(3);
  for (uint64_t i = 0; i < 101; ++i) many.add_erases(i);
  BP_ASSERT_OK(pub->Publish(&many));
  expect_rejection(wire::OVERSIZE, "101 items exceeds limits.max_batch_items = 100");
  // Unknown schema version, bad producer id (raw, since Publish stamps both).
  wire::UpdateBatch raw = InsertBatch({{1, Cube(0)}});
  raw.set_version(static_cast<wire::SchemaVersion>(2));
  raw.set_producer(5);
  BP_ASSERT_OK(pub->PublishRaw(raw.SerializeAsString()));
  expect_rejection(wire::UNSUPPORTED_VERSION, "schema version 2 is not supported");
  raw.set_version(wire::SCHEMA_VERSION_1);
  raw.set_producer(0);
  BP_ASSERT_OK(pub->PublishRaw(raw.SerializeAsString()));
  expect_rejection(wire::BAD_PRODUCER, "producer id 0 is outside 1..65535");
  // Wrong dimension: the batch says 2; the daemon is 3-D.
  wire::UpdateBatch flat = InsertBatch({{1, Cube(0)}});
  flat.set_dim(2);
  BP_ASSERT_OK(pub->Publish(&flat));
  expect_rejection(wire::WRONG_DIMENSION, "the batch's dim is 2; the daemon's dimension is 3");
  // Coordinates that do not match the ids.
  wire::UpdateBatch short_coords = InsertBatch({{1, Cube(0)}});
  short_coords.mutable_inserts()->mutable_lo32()->RemoveLast();
  BP_ASSERT_OK(pub->Publish(&short_coords));
  expect_rejection(wire::WRONG_DIMENSION, "1 ids need 3 lo and hi values");
  // Attributes on an update, attribute array of the wrong length.
  wire::UpdateBatch attrs = InsertBatch({{1, Cube(0)}, {2, Cube(3)}});
  attrs.mutable_inserts()->add_category(2);
  BP_ASSERT_OK(pub->Publish(&attrs));
  expect_rejection(wire::BAD_ATTRIBUTE, "must be empty or have one value per id");
  ++expected;  // both items of that insert array are refused
  ASSERT_TRUE(client.status->WaitFor(expected));
  // The writer now holds producer 5: a payload that does not parse is reported as producer 5's
  // (the first one, sent before the writer held an id, as producer 0).
  EXPECT_EQ(client.status->rejections().front().producer(), 0u);
  BP_ASSERT_OK(pub->PublishRaw(std::string("\xff\xff\xff\xff garbage", 12)));
  expect_rejection(wire::MALFORMED, "is not a valid UpdateBatch");
  EXPECT_EQ(client.status->rejections().back().producer(), 5u);
  // After all that, a valid frame still works.
  wire::UpdateBatch good = InsertBatch({{1, Cube(0)}, {2, Cube(0.25f)}});
  good.set_frame(99);
  BP_ASSERT_OK(pub->Publish(&good));
  FrameEvents frame;
  bool found = false;
  for (uint64_t f = 1; f <= 10 && !found; ++f) {
    if (client.events->WaitFrame(f, &frame, 2s) && frame.last.source_frame() == 99) found = true;
  }
  ASSERT_TRUE(found);
  EXPECT_EQ(frame.collide, (PairList{{service::GlobalKey(5, 1), service::GlobalKey(5, 2)}}));
  BP_ASSERT_OK(daemon.Stop());
}

TEST(Daemon, RejectionListIsCappedAndTheRestCounted) {
  service::Config config = TestConfig(kDomain);
  config.limits.max_rejections_reported = 5;
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(6);
  wire::UpdateBatch batch;
  batch.set_dim(3);
  batch.set_end_of_frame(true);
  for (uint64_t i = 0; i < 50; ++i) batch.add_erases(i);
  BP_ASSERT_OK(pub->Publish(&batch));
  ASSERT_TRUE(client.status->WaitFor(5));
  FrameEvents frame;
  ASSERT_TRUE(client.events->WaitFrame(1, &frame));
  EXPECT_EQ(client.status->rejections().size(), 5u);
  EXPECT_EQ(client.status->not_listed(), 45u);
  EXPECT_EQ(daemon.daemon().rejected(), 50u);
}

TEST(Daemon, TwoProducersShareTheWorldButNotTheirIds) {
  service::Config config = TestConfig(kDomain);
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub1 = client.Publisher(1);
  auto pub2 = client.Publisher(2);
  Scene scene1(SmallScene(11)), scene2(SmallScene(12));
  Oracle<3> oracle;
  PairList unc, col;
  FrameOps ops1 = InitialOps(scene1), ops2 = InitialOps(scene2);
  size_t cross = 0;
  for (uint64_t frame = 1; frame <= 15; ++frame) {
    if (frame > 1) {
      scene1.NextFrame(&ops1);
      scene2.NextFrame(&ops2);
    }
    oracle.Apply(1, ops1);
    oracle.Apply(2, ops2);
    oracle.Query(&unc, &col);
    for (auto& [a, b] : col) cross += (a >> 48) != (b >> 48);
    // Producer 1 never closes a frame; producer 2 does, after producer 1's batch arrived.
    PublishFrame(*pub1, ops1, 3, frame, 1, /*end_of_frame=*/false);
    BP_ASSERT_OK(pub1->Flush(5s));
    PublishFrame(*pub2, ops2, 3, frame, 1, /*end_of_frame=*/true);
    ExpectFrame(*client.events, frame, unc, col);
  }
  EXPECT_GT(cross, 0u) << "the two producers' objects should meet";
  BP_ASSERT_OK(daemon.Stop());
}

TEST(Daemon, AProducerCannotTouchAnotherProducersObjects) {
  service::Config config = TestConfig(kDomain);
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub1 = client.Publisher(1);
  auto pub2 = client.Publisher(2);
  wire::UpdateBatch b1 = InsertBatch({{10, Cube(0)}, {11, Cube(0.5f)}});
  BP_ASSERT_OK(pub1->Publish(&b1));
  ExpectFrame(*client.events, 1, {}, {{service::GlobalKey(1, 10), service::GlobalKey(1, 11)}});
  // Producer 2 names id 10 and 11: these are its own ids, which do not exist.
  wire::UpdateBatch b2;
  b2.set_dim(3);
  b2.set_end_of_frame(true);
  b2.add_erases(10);
  client::AddBox<3>(b2.mutable_updates(), 11, Cube(50));
  BP_ASSERT_OK(pub2->Publish(&b2));
  ASSERT_TRUE(client.status->WaitFor(2));
  for (auto& r : client.status->rejections()) {
    EXPECT_EQ(r.reason(), wire::UNKNOWN_ID);
    EXPECT_EQ(r.producer(), 2u);
  }
  ExpectFrame(*client.events, 2, {}, {});  // producer 1's pair is untouched
  // A second writer claiming producer id 1 while the first is alive is refused.
  auto impostor = client.Publisher(1);
  wire::UpdateBatch b3;
  b3.set_dim(3);
  b3.add_erases(10);
  BP_ASSERT_OK(impostor->Publish(&b3));
  ASSERT_TRUE(client.status->WaitFor(3));
  EXPECT_EQ(client.status->rejections()[2].reason(), wire::PRODUCER_CONFLICT);
  // Once the first writer is gone, a new writer takes the id over and can erase. (A rejected
  // batch closes no frame, so frame 3 appears only once the take-over happened.)
  pub1.reset();
  FrameEvents fe;
  bool taken_over = false;
  for (int attempt = 0; attempt < 50 && !taken_over; ++attempt) {
    wire::UpdateBatch b4;
    b4.set_dim(3);
    b4.set_end_of_frame(true);
    b4.add_erases(10);
    BP_ASSERT_OK(impostor->Publish(&b4));
    taken_over = client.events->WaitFrame(3, &fe, 200ms);
  }
  ASSERT_TRUE(taken_over) << "the new writer of producer 1 never took the id over";
  EXPECT_EQ(fe.uncollide, (PairList{{service::GlobalKey(1, 10), service::GlobalKey(1, 11)}}));
}

TEST(Daemon, CategoryAndMaskFilterPairs) {
  service::Config config = TestConfig(kDomain);
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(3);
  // Four overlapping boxes: 1 and 2 in category 1 ignore each other (mask 2); 3 is category 2
  // and sees everyone; 4 has default filter (category 1, mask all).
  wire::UpdateBatch batch =
      InsertBatch({{1, Cube(0)}, {2, Cube(0.1f)}, {3, Cube(0.2f)}, {4, Cube(0.3f)}});
  for (uint64_t c : {1ull, 1ull, 2ull, 1ull}) batch.mutable_inserts()->add_category(c);
  for (uint64_t m : {2ull, 2ull, ~0ull, ~0ull}) batch.mutable_inserts()->add_mask(m);
  BP_ASSERT_OK(pub->Publish(&batch));
  auto k = [](uint64_t id) { return service::GlobalKey(3, id); };
  // 1-2: 1&2=0 no. 1-3: (1&~0)&&(2&2) yes. 1-4: (1&~0)&&(1&2)=0 no. 2-3 yes. 2-4 no. 3-4 yes.
  ExpectFrame(*client.events, 1, {}, {{k(1), k(3)}, {k(2), k(3)}, {k(3), k(4)}});
  wire::UpdateBatch erase;
  erase.set_dim(3);
  erase.set_end_of_frame(true);
  erase.add_erases(3);
  BP_ASSERT_OK(pub->Publish(&erase));
  ExpectFrame(*client.events, 2, {{k(1), k(3)}, {k(2), k(3)}, {k(3), k(4)}}, {});
  FrameEvents f2;
  ASSERT_TRUE(client.events->WaitFrame(2, &f2));
  EXPECT_EQ(f2.last.overlaps(), 0u);
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
  std::unique_ptr<client::Connection> connection;
  BP_ASSERT_OK(client::Connection::Open(ClientOptions(config), &connection));
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

}  // namespace
}  // namespace bp::test

namespace bp::test {
namespace {

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
}  // namespace
}  // namespace bp::test

namespace bp::test {
namespace {

// The client library's callback style: a listener thread hands every EventBatch to a callback.
TEST(Daemon, ClientLibraryRoundTripWithACallback) {
  service::Config config = TestConfig(kDomain);
  InProcessDaemon daemon(config);
  std::unique_ptr<client::Connection> connection;
  BP_ASSERT_OK(client::Connection::Open(ClientOptions(config), &connection));
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
    std::unique_ptr<client::Connection> own;  // its own participant, as another process has
    BP_ASSERT_OK(client::Connection::Open(ClientOptions(config), &own));
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
  client::qos::StatusWriter(qos.get(), 1000ms);
  dds::Writer fake;
  BP_ASSERT_OK(client.connection->CreateWriter(client::TopicId::kStatus, qos, &fake));
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
  client::qos::StatusWriter(qos.get(), 1000ms);
  dds::Writer fake;
  BP_ASSERT_OK(client.connection->CreateWriter(client::TopicId::kStatus, qos, &fake));
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
