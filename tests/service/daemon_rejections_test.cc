// Bad input at the daemon: each bad item rejected with its reason and the rest applied,
// batch-level faults, the capped rejection list, producers' id spaces, category and mask.
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

}  // namespace
}  // namespace bp::test
