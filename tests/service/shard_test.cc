// A world served by three daemons (shards): the shard map, the merging view on hand-made
// streams, and real processes on loopback: three broadphased, a producer process routing a
// scene of heavy border traffic through ShardedPublisher, and this process merging the shards'
// streams, compared with the brute-force oracle frame by frame. Then the same with a shard
// killed (SIGKILL) and started again mid-scene.
//
// The producer is this binary run with --produce (main below), so that the subscriber can
// generate the very same scene for the oracle.
#include <cinttypes>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>
#include <sstream>

#include "interest_oracle.h"
#include "process_test_support.h"
#include "service_test_support.h"
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include "bp/client/sharded.h"
#include "bp/transport/shard_map.h"

namespace bp::test {
namespace {

constexpr uint32_t kDomain = BP_TEST_DOMAIN;
constexpr uint32_t kProducer = 5;

// Three shards on a 3 x 2 grid of 20 m blocks: a owns the two lower-left blocks, b the right
// column, c the two upper-left ones, so borders run along x and along y.
constexpr const char* kMap = R"(dimension: 3
origin: [-30, -20, -10]
edge: [20, 20, 20]
count: [3, 2, 1]
shards:
  - name: a
    blocks: [{from: [0, 0, 0], to: [1, 0, 0]}]
  - name: b
    blocks: [{from: [2, 0, 0], to: [2, 1, 0]}]
  - name: c
    blocks: [{from: [0, 1, 0], to: [1, 1, 0]}]
)";

// A scene of heavy border traffic, the same for every seed in the producer and the oracle:
// boxes oscillating across the borders, boxes larger than a shard, every object crossing at
// once every 40th frame, teleports between shards and churn every frame.
class BorderScene {
 public:
  explicit BorderScene(uint64_t seed) : random_(seed) {
    for (int i = 0; i < 150; ++i) AddMover(false);
    for (int i = 0; i < 3; ++i) AddMover(true);
  }
  // The inserts of frame 1.
  void Initial(FrameOps* ops) {
    ops->Clear();
    for (auto& [id, m] : movers_) ops->inserts.push_back(Box(id, m, 1));
    frame_ = 1;
  }
  void Next(FrameOps* ops) {
    ops->Clear();
    ++frame_;
    if (frame_ % 40 == 0) {
      for (auto& [id, m] : movers_)
        m.center[0] = m.center[0] + 20 > 35 ? m.center[0] - 50 : m.center[0] + 20;
    }
    std::uniform_real_distribution<double> x(-35, 35), y(-25, 25);
    for (int t = 0; t < 2; ++t) {
      auto it = std::next(movers_.begin(), static_cast<long>(random_() % movers_.size()));
      if (!it->second.large) it->second.center = {x(random_), y(random_), 0};
    }
    // Churn: one erased, one inserted.
    auto gone = std::next(movers_.begin(), static_cast<long>(random_() % movers_.size()));
    if (!gone->second.large) {
      ops->erases.push_back(gone->first);
      movers_.erase(gone);
    }
    const uint64_t added = AddMover(false);
    for (auto& [id, m] : movers_) {
      if (id == added) {
        ops->inserts.push_back(Box(id, m, frame_));
      } else {
        ops->updates.push_back(Box(id, m, frame_));
      }
    }
  }
  uint64_t frame() const { return frame_; }

 private:
  struct Mover {
    std::array<double, 3> center, direction;
    double amplitude, phase, half;
    bool large;
  };
  uint64_t AddMover(bool large) {
    std::uniform_real_distribution<double> x(-35, 35), y(-25, 25), u(0, 1);
    Mover m;
    m.center = {x(random_), y(random_), 0};
    const double angle = u(random_) * 6.283185307179586;
    m.direction = {std::cos(angle), std::sin(angle), 0};
    m.amplitude = large ? 3 : 4 + 8 * u(random_);
    m.phase = u(random_) * 6.283185307179586;
    m.half = large ? 25 : 0.5 + 1.5 * u(random_);
    m.large = large;
    movers_[next_id_] = m;
    return next_id_++;
  }
  static SceneBox Box(uint64_t id, const Mover& m, uint64_t frame) {
    const double s = m.amplitude * std::sin(0.15 * static_cast<double>(frame) + m.phase);
    SceneBox b;
    b.id = id;
    for (size_t a = 0; a < 3; ++a) {
      const double c = m.center[a] + s * m.direction[a];
      const double half = a == 2 ? std::min(m.half, 2.0) : m.half;
      b.lo[a] = static_cast<float>(c - half);
      b.hi[a] = static_cast<float>(c + half);
    }
    b.moves = true;
    return b;
  }
  std::mt19937_64 random_;
  std::map<uint64_t, Mover> movers_;
  uint64_t next_id_ = 1;
  uint64_t frame_ = 0;
};

transport::ShardMap TestMap() {
  transport::ShardMap map;
  EXPECT_TRUE(transport::ShardMap::Parse(kMap, "test map", &map).ok());
  return map;
}

TEST(ShardMap, RoutesBoxesToEveryShardTheyTouch) {
  const transport::ShardMap map = TestMap();
  ASSERT_EQ(map.size(), 3u);
  auto route = [&](std::array<double, 3> lo, std::array<double, 3> hi) {
    return map.Route(lo.data(), hi.data());
  };
  EXPECT_EQ(route({-25, -15, 0}, {-24, -14, 1}), 0b001u);            // inside a
  EXPECT_EQ(route({15, 5, 0}, {16, 6, 1}), 0b010u);                  // inside b
  EXPECT_EQ(route({-25, 5, 0}, {-24, 6, 1}), 0b100u);                // inside c
  EXPECT_EQ(route({9, -1, 0}, {11, 1, 0}), 0b111u);                  // on the corner of all three
  EXPECT_EQ(route({-500, -500, -500}, {-400, -400, -400}), 0b001u);  // beyond the grid
  EXPECT_EQ(route({-1e30, -1e30, 0}, {1e30, 1e30, 0}), 0b111u);
  // A border belongs to the block above it; a box touching it from below is in both.
  EXPECT_EQ(route({5, -5, 0}, {10, -4, 0}), 0b011u);
  EXPECT_EQ(route({10, -5, 0}, {11, -4, 0}), 0b010u);
  EXPECT_EQ(route({std::nan(""), 0, 0}, {1, 1, 1}), 0u);
  EXPECT_EQ(route({2, 0, 0}, {1, 1, 1}), 0u);
  EXPECT_EQ(map.Find("c"), 2);
  EXPECT_EQ(map.BlocksOwned(1), 2u);
  EXPECT_EQ(transport::ShardPartition("p", "b"), "p.shard.b");
  EXPECT_EQ(transport::ShardPartition("", "b"), "shard.b");
}

TEST(ShardMap, ProblemsNameTheKeyAndTheLine) {
  transport::ShardMap map;
  Status s = transport::ShardMap::Parse(
      "dimension: 3\norigin: [0, 0, 0]\nedge: [1, -1, 1]\ncount: [2, 1, 1]\nshards:\n"
      "  - name: a\n    blocks: [{from: [0, 0, 0], to: [0, 0, 0]}]\n",
      "m.yaml", &map);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("m.yaml:3:"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("edge"), std::string::npos) << s.message();
  s = transport::ShardMap::Parse(
      "dimension: 3\norigin: [0, 0, 0]\nedge: [1, 1, 1]\ncount: [2, 1, 1]\nshards:\n"
      "  - name: a\n    blocks: [{from: [0, 0, 0], to: [0, 0, 0]}]\n",
      "m.yaml", &map);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("block [1, 0, 0] has no owner"), std::string::npos) << s.message();
  s = transport::ShardMap::Parse(
      "dimension: 3\norigin: [0, 0, 0]\nedge: [1, 1, 1]\ncount: [2, 1, 1]\nshards:\n"
      "  - name: a\n    blocks: [{from: [0, 0, 0], to: [1, 0, 0]}]\n"
      "  - name: b\n    blocks: [{from: [1, 0, 0], to: [1, 0, 0]}]\n",
      "m.yaml", &map);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("m.yaml:9:"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("already owned by 'a'"), std::string::npos) << s.message();
  // The same map written differently has the same digest.
  transport::ShardMap one, two;
  ASSERT_TRUE(transport::ShardMap::Parse(kMap, "one", &one).ok());
  std::string other = kMap;
  other.replace(other.find("[-30, -20, -10]"), 15, "[-30.0, -20, -1e1]");
  ASSERT_TRUE(transport::ShardMap::Parse(other, "two", &two).ok());
  EXPECT_EQ(one.digest(), two.digest());
}

// Hand-made shard streams: the parts a daemon would publish.
struct Stream {
  uint64_t epoch = 1, seq = 0;
  wire::EventBatch Part(uint64_t frame, std::vector<uint64_t> uncollide,
                        std::vector<uint64_t> collide) {
    wire::EventBatch b;
    b.set_epoch(epoch);
    b.set_sequence(++seq);
    b.set_frame(frame);
    b.set_last_part(true);
    b.set_source_producer(kProducer);
    b.set_source_frame(frame);
    for (uint64_t k : uncollide) b.add_uncollide(k);
    for (uint64_t k : collide) b.add_collide(k);
    return b;
  }
  wire::EventBatch Snapshot(uint64_t frame, std::vector<uint64_t> pairs) {
    wire::EventBatch b = Part(frame, {}, {});
    b.set_snapshot(true);
    if (frame == 0) b.set_source_producer(0);
    for (uint64_t k : pairs) b.add_snapshot_pairs(k);
    return b;
  }
};

TEST(MergedView, APairHandedOverWithinAFrameProducesNoEvent) {
  client::MergedView view(2);
  Stream a, b;
  EXPECT_TRUE(view.Apply(0, a.Snapshot(0, {})) || true);
  view.Apply(1, b.Snapshot(0, {}));
  client::MergedFrame f;
  EXPECT_FALSE(view.Next(&f));
  view.Apply(0, a.Part(1, {}, {1, 2}));
  EXPECT_FALSE(view.Next(&f));  // b has not delivered frame 1
  EXPECT_EQ(view.waiting_for(), std::vector<size_t>{1});
  view.Apply(1, b.Part(1, {}, {}));
  ASSERT_TRUE(view.Next(&f));
  EXPECT_TRUE(f.snapshot);
  EXPECT_EQ(f.collide, (std::vector<uint64_t>{1, 2}));
  // Frame 2: (1, 2) moves from a to b; frame 3: both hold it (it straddles the border).
  view.Apply(1, b.Part(2, {}, {1, 2}));
  view.Apply(0, a.Part(2, {1, 2}, {3, 4}));
  ASSERT_TRUE(view.Next(&f));
  EXPECT_EQ(f.frame, 2u);
  EXPECT_TRUE(f.uncollide.empty());
  EXPECT_EQ(f.collide, (std::vector<uint64_t>{3, 4}));
  view.Apply(0, a.Part(3, {}, {1, 2}));
  view.Apply(1, b.Part(3, {}, {}));
  ASSERT_TRUE(view.Next(&f));
  EXPECT_TRUE(f.uncollide.empty() && f.collide.empty());
  // Frame 4: a lets go of it, b still holds it: no event; frame 5: b too: an uncollide.
  view.Apply(0, a.Part(4, {1, 2}, {}));
  view.Apply(1, b.Part(4, {}, {}));
  ASSERT_TRUE(view.Next(&f));
  EXPECT_TRUE(f.uncollide.empty() && f.collide.empty());
  view.Apply(0, a.Part(5, {}, {}));
  view.Apply(1, b.Part(5, {1, 2}, {}));
  ASSERT_TRUE(view.Next(&f));
  EXPECT_EQ(f.uncollide, (std::vector<uint64_t>{1, 2}));
  EXPECT_EQ(view.SortedPairs(), (PairList{{3, 4}}));
  EXPECT_EQ(view.contradictions(), 0u);
}

TEST(MergedView, AShardThatLostItsSyncHoldsTheStreamBackThenFoldsTheFramesItMissed) {
  client::MergedView view(2);
  Stream a, b;
  view.Apply(0, a.Snapshot(0, {}));
  view.Apply(1, b.Snapshot(0, {}));
  client::MergedFrame f;
  view.Apply(0, a.Part(1, {}, {1, 2}));
  view.Apply(1, b.Part(1, {}, {5, 6}));
  ASSERT_TRUE(view.Next(&f));
  // b restarts: a goes on alone, and nothing is merged until b's snapshot.
  b.epoch = 2;
  b.seq = 0;
  view.Apply(0, a.Part(2, {1, 2}, {}));
  view.Apply(0, a.Part(3, {}, {7, 8}));
  EXPECT_TRUE(view.Apply(1, b.Part(1, {}, {})));  // the new daemon: wants a snapshot
  EXPECT_FALSE(view.Next(&f));
  EXPECT_EQ(view.waiting_for(), std::vector<size_t>{1});
  view.Apply(1, b.Snapshot(3, {5, 6, 9, 10}));
  ASSERT_TRUE(view.Next(&f));
  EXPECT_EQ(f.frame, 3u);
  EXPECT_EQ(f.skipped, 1u);
  EXPECT_EQ(f.uncollide, (std::vector<uint64_t>{1, 2}));
  EXPECT_EQ(f.collide, (std::vector<uint64_t>{7, 8, 9, 10}));
  EXPECT_EQ(view.restarts(1), 1u);
  EXPECT_EQ(view.SortedPairs(), (PairList{{5, 6}, {7, 8}, {9, 10}}));
}

TEST(MergedView, FramesOfTheDaemonsOwnCountIntoTheNextProducerFrameInOrder) {
  client::MergedView view(2);
  Stream a, b;
  view.Apply(0, a.Snapshot(0, {}));
  view.Apply(1, b.Snapshot(0, {}));
  view.Apply(0, a.Part(1, {}, {1, 2}));
  view.Apply(1, b.Part(1, {}, {}));
  client::MergedFrame f;
  ASSERT_TRUE(view.Next(&f));
  // Shard b: a restate's frame collides (3, 4), an expiry's frame (no producer) uncollides it
  // again and collides (5, 6); then producer frame 2. Shard b's frames before 2 are folded.
  wire::EventBatch restate = b.Part(1, {}, {3, 4});
  restate.set_restate(true);
  view.Apply(1, restate);
  wire::EventBatch expiry = b.Part(1, {3, 4}, {5, 6});
  expiry.set_source_producer(0);
  view.Apply(1, expiry);
  view.Apply(1, b.Part(2, {}, {7, 8}));
  view.Apply(0, a.Part(2, {1, 2}, {}));
  ASSERT_TRUE(view.Next(&f));
  EXPECT_EQ(f.frame, 2u);
  EXPECT_EQ(f.uncollide, (std::vector<uint64_t>{1, 2}));
  EXPECT_EQ(f.collide, (std::vector<uint64_t>{5, 6, 7, 8}));
  EXPECT_EQ(view.contradictions(), 0u);
  EXPECT_EQ(view.SortedPairs(), (PairList{{5, 6}, {7, 8}}));
}

// The router's parts, read on each shard's updates topic (no daemon: what a recorder sees).
class ShardRecorders {
 public:
  ShardRecorders(transport::Connection& connection, const transport::ShardMap& map) {
    for (size_t s = 0; s < map.size(); ++s) {
      scoped_.push_back(connection.Scoped(
          transport::ShardPartition(connection.options().partition, map.name(s))));
      dds::Qos qos;
      transport::qos::UpdatesReader(qos.get(), 1000);
      readers_.emplace_back();
      EXPECT_TRUE(
          scoped_.back()->CreateReader(transport::TopicId::kUpdates, qos, &readers_.back()).ok());
    }
  }
  // The next batch shard s received (waits up to 10 s).
  wire::UpdateBatch Next(size_t s) {
    const auto deadline = std::chrono::steady_clock::now() + 10s;
    while (queued_.size() <= s || queued_[s].empty()) {
      queued_.resize(readers_.size());
      for (size_t r = 0; r < readers_.size(); ++r) {
        size_t taken = 0;
        EXPECT_TRUE(readers_[r]
                        .Take(
                            64,
                            [&](const dds::Received& got) {
                              wire::UpdateBatch b;
                              EXPECT_TRUE(b.ParseFromArray(got.payload.data(),
                                                           static_cast<int>(got.payload.size())));
                              queued_[r].push_back(b);
                            },
                            &taken)
                        .ok());
      }
      if (std::chrono::steady_clock::now() > deadline) {
        ADD_FAILURE() << "shard " << s << " received no batch";
        return {};
      }
      std::this_thread::sleep_for(2ms);
    }
    wire::UpdateBatch b = queued_[s].front();
    queued_[s].erase(queued_[s].begin());
    return b;
  }
  std::vector<dds::Reader>& readers() { return readers_; }

 private:
  std::vector<std::unique_ptr<transport::Connection>> scoped_;
  std::vector<dds::Reader> readers_;
  std::vector<std::vector<wire::UpdateBatch>> queued_;
};

void AddBox(wire::BoxArray* a, uint64_t id, std::array<float, 3> lo, std::array<float, 3> hi) {
  a->add_ids(id);
  for (float v : lo) a->add_lo32(v);
  for (float v : hi) a->add_hi32(v);
}

std::vector<uint64_t> Ids(const wire::BoxArray& a) { return {a.ids().begin(), a.ids().end()}; }
std::vector<uint64_t> Erases(const wire::UpdateBatch& b) {
  return {b.erases().begin(), b.erases().end()};
}

TEST(ShardedPublisher, RoutesEachItemSoThatEveryShardAppliesWhatOneDaemonWould) {
  service::Config config = TestConfig(kDomain);
  std::unique_ptr<transport::Connection> connection;
  BP_ASSERT_OK(transport::Connection::Open(ClientOptions(config), &connection));
  const transport::ShardMap map = TestMap();
  ShardRecorders recorders(*connection, map);
  std::unique_ptr<client::ShardedPublisher> pub;
  BP_ASSERT_OK(client::ShardedPublisher::Create(*connection, map, kProducer, {}, &pub));
  for (size_t s = 0; s < 3; ++s) BP_ASSERT_OK(pub->shard(s).WaitForReaders(1, 20s));
  const float nan = std::nanf("");
  // Frame 1: 1 inside a; 2 across a and b; 3 not a box (NaN): unchanged to a; 4 static, in c.
  wire::UpdateBatch batch;
  batch.set_dim(3);
  batch.set_frame(1);
  batch.set_end_of_frame(true);
  AddBox(batch.mutable_inserts(), 1, {-25, -15, 0}, {-24, -14, 1});
  AddBox(batch.mutable_inserts(), 2, {8, -15, 0}, {12, -14, 1});
  AddBox(batch.mutable_inserts(), 3, {nan, 0, 0}, {1, 1, 1});
  AddBox(batch.mutable_inserts(), 4, {-25, 5, 0}, {-24, 6, 1});
  for (bool st : {false, false, false, true}) batch.mutable_inserts()->add_static_flags(st);
  BP_ASSERT_OK(pub->Publish(&batch));
  wire::UpdateBatch a = recorders.Next(0), b = recorders.Next(1), c = recorders.Next(2);
  EXPECT_EQ(Ids(a.inserts()), (std::vector<uint64_t>{1, 2, 3}));
  EXPECT_EQ(a.inserts().static_flags_size(), 3);  // as given (false)
  EXPECT_FALSE(a.inserts().static_flags(0) || a.inserts().static_flags(1));
  EXPECT_EQ(Ids(b.inserts()), (std::vector<uint64_t>{2}));
  EXPECT_EQ(Ids(c.inserts()), (std::vector<uint64_t>{4}));
  ASSERT_EQ(c.inserts().static_flags_size(), 1);
  EXPECT_TRUE(c.inserts().static_flags(0));
  EXPECT_TRUE(a.end_of_frame() && b.end_of_frame() && c.end_of_frame());
  EXPECT_EQ(pub->objects(), 3u);  // 3 was not placed
  EXPECT_EQ(pub->border_objects(), 1u);
  // Frame 2: 4 moves from c to b (inserted there with its static flag, erased from c); 2 is
  // erased and inserted again in c (an insert with an update of its box later in the batch);
  // 9 is unknown (its update goes to a, which refuses it); 1 is inserted twice (a refuses it).
  batch.Clear();
  batch.set_dim(3);
  batch.set_frame(2);
  batch.set_end_of_frame(true);
  batch.add_erases(2);
  AddBox(batch.mutable_inserts(), 2, {-25, 5, 0}, {-24, 6, 1});
  AddBox(batch.mutable_inserts(), 1, {-25, -15, 0}, {-24, -14, 1});
  AddBox(batch.mutable_updates(), 4, {15, 5, 0}, {16, 6, 1});
  AddBox(batch.mutable_updates(), 9, {0, 0, 0}, {1, 1, 1});
  AddBox(batch.mutable_updates(), 2, {-26, 5, 0}, {-24, 6, 1});
  BP_ASSERT_OK(pub->Publish(&batch));
  a = recorders.Next(0);
  b = recorders.Next(1);
  c = recorders.Next(2);
  EXPECT_EQ(Erases(a), (std::vector<uint64_t>{2}));
  EXPECT_EQ(Ids(a.inserts()), (std::vector<uint64_t>{1}));  // the duplicate, refused there
  EXPECT_EQ(Ids(a.updates()), (std::vector<uint64_t>{9}));  // unknown, refused there
  EXPECT_EQ(Erases(b), (std::vector<uint64_t>{2}));
  EXPECT_EQ(Ids(b.inserts()), (std::vector<uint64_t>{4}));
  ASSERT_EQ(b.inserts().static_flags_size(), 1);
  EXPECT_TRUE(b.inserts().static_flags(0));
  EXPECT_EQ(b.inserts().lo32(0), 15.0f);  // the update's box
  std::vector<uint64_t> c_erases = Erases(c);
  std::sort(c_erases.begin(), c_erases.end());
  EXPECT_EQ(c_erases, (std::vector<uint64_t>{4}));
  EXPECT_EQ(Ids(c.inserts()), (std::vector<uint64_t>{2}));
  EXPECT_EQ(c.inserts().lo32(0), -26.0f);  // inserted with the box of its later update
  EXPECT_EQ(pub->handovers(), 2u);
  // Refused whole, nothing sent: a closing frame number that does not increase, a malformed
  // array.
  batch.Clear();
  batch.set_dim(3);
  batch.set_frame(2);
  batch.set_end_of_frame(true);
  Status s = pub->Publish(&batch);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("increase"), std::string::npos) << s.message();
  batch.set_frame(3);
  batch.mutable_inserts()->add_ids(7);
  batch.mutable_inserts()->add_lo32(0);
  s = pub->Publish(&batch);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("inserts has 1 ids but 1 lo"), std::string::npos) << s.message();
}

// --- Real processes ------------------------------------------------------------------------

// "local id" of a global key.
std::string KeyName(uint64_t key) { return std::to_string(key & ((uint64_t{1} << 48) - 1)); }

std::string SelfExe() { return std::filesystem::read_symlink("/proc/self/exe").string(); }

// Three shard daemons a, b, c and, on demand, the producer process. Each process may run in a
// network namespace of its own (hosts: "" = this one), with its own Cyclone configuration.
struct World {
  ScratchDir dir{"bp-shard-"};
  std::string map_path;
  service::Config base = TestConfig(kDomain);
  // Per host (a, b, c, producer): its network namespace and Cyclone configuration.
  std::array<std::string, 4> netns, cyclone;

  World(uint32_t domain = kDomain, std::array<std::string, 4> hosts = {},
        std::array<std::string, 4> cyclone_xml = {})
      : netns(hosts), cyclone(cyclone_xml) {
    base.dds.domain = domain;
    map_path = dir.path() + "/shards.yaml";
    std::ofstream(map_path) << kMap;
    for (std::string& xml : cyclone) {
      if (xml.empty()) xml = base.dds.cyclone_config;
    }
    for (const char* name : {"a", "b", "c"}) daemons.push_back(Start(name));
  }
  std::vector<std::unique_ptr<Process>> daemons;
  std::unique_ptr<Process> Start(const std::string& name) {
    const size_t host = static_cast<size_t>(name[0] - 'a');
    const std::string config = dir.path() + "/broadphased-" + name + ".yaml";
    std::ofstream(config) << "engine:\n  algorithm: grid_dense\n  dimension: 3\n  threads: 1\n"
                          << "dds:\n  domain: " << base.dds.domain
                          << "\n  cyclone_config: " << cyclone[host]
                          << "\n  partition: " << base.dds.partition
                          << "\nlogging:\n  summary_interval_s: 0\nproducers:\n  lease_s: 10\n"
                          << "shards:\n  map: shards.yaml\n";
    return Run(host, BROADPHASED, {"--config", config, "--shard", name},
               dir.path() + "/daemon-" + name + ".log");
  }
  // binary args, in host's namespace if it has one.
  std::unique_ptr<Process> Run(size_t host, const std::string& binary,
                               std::vector<std::string> args, const std::string& log) {
    if (netns[host].empty()) return std::make_unique<Process>(args, log, binary);
    args.insert(args.begin(), {"netns", "exec", netns[host], binary});
    return std::make_unique<Process>(args, log, "/usr/sbin/ip");
  }
  std::string Logs() const {
    std::string out;
    for (const char* name : {"a", "b", "c"}) {
      out += "--- daemon " + std::string(name) + ":\n" +
             ReadFile(dir.path() + "/daemon-" + name + ".log");
    }
    return out + "--- producer:\n" + ReadFile(dir.path() + "/producer.log");
  }
  std::unique_ptr<Process> Produce(int frames, int rate) {
    return Run(3, SelfExe(),
               {"--produce", std::to_string(base.dds.domain), cyclone[3], base.dds.partition,
                map_path, std::to_string(frames), std::to_string(rate)},
               dir.path() + "/producer.log");
  }
};

// The merging subscriber of a world: a connection with options and a ShardedSubscriber of
// every shard's stream, matched to every shard.
void OpenMerged(World& w, const transport::ConnectionOptions& options,
                const transport::ShardMap& map, std::unique_ptr<transport::Connection>* connection,
                std::unique_ptr<client::ShardedSubscriber>* sub) {
  BP_ASSERT_OK(transport::Connection::Open(options, connection));
  BP_ASSERT_OK(client::ShardedSubscriber::Create(**connection, map, 1000, sub));
  const Status s = (*sub)->WaitForDaemons(30s);
  ASSERT_TRUE(s.ok()) << s.ToString() << "\n" << w.Logs();
}

// Follows the merged stream until frame `last`, comparing each merged frame with the oracle:
// the set at every frame, and the events too where no frame was folded. on_frame(frame) runs
// after each merged frame.
void FollowAndCompare(World& w, client::ShardedSubscriber& sub, uint64_t last,
                      const std::function<void(uint64_t)>& on_frame, uint64_t* folded) {
  BorderScene scene(7);
  Oracle<3> oracle;
  FrameOps ops;
  scene.Initial(&ops);
  oracle.Apply(kProducer, ops);
  PairList oracle_unc, oracle_col;
  oracle.Query(&oracle_unc, &oracle_col);
  std::set<std::pair<uint64_t, uint64_t>> set;
  std::vector<client::MergedFrame> frames;
  uint64_t frame = 0;
  const auto deadline = std::chrono::steady_clock::now() + 90s;
  while (frame < last) {
    ASSERT_LT(std::chrono::steady_clock::now(), deadline)
        << "merged frame " << frame << " of " << last << "; waiting for "
        << sub.view().waiting_for().size() << " shard(s)\n"
        << w.Logs();
    frames.clear();
    BP_ASSERT_OK(sub.Poll(100ms, &frames));
    for (const client::MergedFrame& f : frames) {
      ASSERT_GT(f.frame, frame);
      PairList unc = client::Pairs(
          google::protobuf::RepeatedField<uint64_t>(f.uncollide.begin(), f.uncollide.end()));
      PairList col = client::Pairs(
          google::protobuf::RepeatedField<uint64_t>(f.collide.begin(), f.collide.end()));
      if (f.snapshot) set.clear();
      for (const auto& p : unc)
        ASSERT_EQ(set.erase(p), 1u) << "frame " << f.frame << " uncollides an absent pair";
      for (const auto& p : col)
        ASSERT_TRUE(set.insert(p).second) << "frame " << f.frame << " collides a pair twice";
      // The oracle up to this frame.
      bool exact_events = !f.snapshot && f.skipped == 0 && scene.frame() + 1 == f.frame;
      while (scene.frame() < f.frame) {
        scene.Next(&ops);
        oracle.Apply(kProducer, ops);
        oracle.Query(&oracle_unc, &oracle_col);
      }
      if (exact_events) {
        std::sort(oracle_unc.begin(), oracle_unc.end());
        std::sort(oracle_col.begin(), oracle_col.end());
        ASSERT_EQ(unc, oracle_unc) << "uncollides of frame " << f.frame;
        ASSERT_EQ(col, oracle_col) << "collides of frame " << f.frame;
      } else {
        ++*folded;
      }
      const PairList expected = oracle.Pairs();
      const PairList got(set.begin(), set.end());
      if (got != expected) {
        PairList extra, missing;
        std::set_difference(got.begin(), got.end(), expected.begin(), expected.end(),
                            std::back_inserter(extra));
        std::set_difference(expected.begin(), expected.end(), got.begin(), got.end(),
                            std::back_inserter(missing));
        std::string text;
        for (const auto& [a, b] : extra) text += " +" + KeyName(a) + "-" + KeyName(b);
        for (const auto& [a, b] : missing) text += " -" + KeyName(a) + "-" + KeyName(b);
        FAIL() << "the set at frame " << f.frame << " differs from the oracle's:" << text
               << (f.skipped > 0 ? " (a folded frame)" : "") << "\n"
               << w.Logs();
      }
      frame = f.frame;
      on_frame(frame);
    }
  }
  EXPECT_EQ(sub.view().contradictions(), 0u);
}

TEST(ShardProcess, ThreeShardsOnLoopbackMatchTheOracleFrameByFrame) {
  World w;
  const transport::ShardMap map = TestMap();
  std::unique_ptr<transport::Connection> connection;
  std::unique_ptr<client::ShardedSubscriber> sub;
  OpenMerged(w, ClientOptions(w.base), map, &connection, &sub);
  if (HasFatalFailure()) return;
  constexpr int kFrames = 150;
  auto producer = w.Produce(kFrames, 100);
  uint64_t folded = 0;
  FollowAndCompare(
      w, *sub, kFrames, [](uint64_t) {}, &folded);
  EXPECT_EQ(folded, 1u) << "only the first merged frame (the join) should be a snapshot";
  EXPECT_EQ(producer->Wait(30s), 0) << w.Logs();
  for (size_t s = 0; s < 3; ++s) EXPECT_EQ(sub->view().resyncs(s), 0u) << map.name(s);
  std::printf("%s", ReadFile(w.dir.path() + "/producer.log").c_str());  // handovers, borders
}

// An interest across the shards: two regions on borders, the pairs inside them and the pairs of
// one key, declared on every shard and merged from their interest streams, equal to the interest
// oracle at every frame.
TEST(ShardProcess, AnInterestAcrossShardsMatchesTheOracleFrameByFrame) {
  World w;
  const transport::ShardMap map = TestMap();
  std::unique_ptr<transport::Connection> connection;
  BP_ASSERT_OK(transport::Connection::Open(ClientOptions(w.base), &connection));
  std::unique_ptr<client::ShardedInterestClient> interests;
  BP_ASSERT_OK(client::ShardedInterestClient::Create(*connection, map, &interests));
  {
    const Status s = interests->WaitForDaemons(30s);
    ASSERT_TRUE(s.ok()) << s.ToString() << "\n" << w.Logs();
  }
  wire::Interest interest;
  interest.set_id(client::InterestClient::NewInterestId());
  interest.set_dim(3);
  for (double v : {-15.0, -5.0, -3.0, 5.0, -10.0, -3.0}) interest.add_region_lo(v);
  for (double v : {-5.0, 5.0, 3.0, 15.0, 10.0, 3.0}) interest.add_region_hi(v);
  interest.set_pairs_inside(true);
  interest.add_keys(service::GlobalKey(kProducer, 7));
  wire::Interest with_margin = interest;
  with_margin.set_leave_margin(1);
  EXPECT_EQ(interests->Declare(with_margin).code(), StatusCode::kInvalidArgument);
  BP_ASSERT_OK(interests->Declare(interest));
  std::unique_ptr<client::ShardedSubscriber> sub;
  BP_ASSERT_OK(client::ShardedSubscriber::Create(*connection, map, 1000, &sub, interest.id()));
  BP_ASSERT_OK(sub->WaitForDaemons(30s));
  constexpr int kFrames = 120;
  auto producer = w.Produce(kFrames, 100);
  BorderScene scene(7);
  InterestOracle<3> oracle;
  oracle.Declare(interest);
  FrameOps ops;
  auto apply = [&] {
    for (uint64_t id : ops.erases) oracle.objects.erase(service::GlobalKey(kProducer, id));
    for (const auto* boxes : {&ops.inserts, &ops.updates}) {
      for (const SceneBox& b : *boxes) {
        auto& o = oracle.objects[service::GlobalKey(kProducer, b.id)];
        for (size_t a = 0; a < 3; ++a) {
          o.box.lo[a] = b.lo[a];
          o.box.hi[a] = b.hi[a];
        }
      }
    }
    oracle.Step();
  };
  scene.Initial(&ops);
  apply();
  std::set<std::pair<uint64_t, uint64_t>> set, before = oracle.interests[interest.id()].set;
  std::vector<client::MergedFrame> frames;
  uint64_t frame = 0, exact_frames = 0;
  const auto deadline = std::chrono::steady_clock::now() + 90s;
  while (frame < kFrames) {
    ASSERT_LT(std::chrono::steady_clock::now(), deadline) << "merged frame " << frame << "\n"
                                                          << w.Logs();
    BP_ASSERT_OK(interests->Maintain());
    frames.clear();
    BP_ASSERT_OK(sub->Poll(100ms, &frames));
    for (const client::MergedFrame& f : frames) {
      if (f.snapshot) set.clear();
      for (size_t i = 0; i + 1 < f.uncollide.size(); i += 2) {
        ASSERT_EQ(set.erase({f.uncollide[i], f.uncollide[i + 1]}), 1u) << "frame " << f.frame;
      }
      for (size_t i = 0; i + 1 < f.collide.size(); i += 2) {
        ASSERT_TRUE(set.insert({f.collide[i], f.collide[i + 1]}).second) << "frame " << f.frame;
      }
      const bool events_comparable = !f.snapshot && f.skipped == 0;
      while (scene.frame() < f.frame) {
        before = oracle.interests[interest.id()].set;
        scene.Next(&ops);
        apply();
      }
      const auto& expected = oracle.interests[interest.id()].set;
      ASSERT_EQ(set, expected) << "the interest's set at frame " << f.frame;
      if (events_comparable) {
        // The merged events are the difference between the oracle's sets.
        std::vector<uint64_t> unc, col;
        for (const auto& p : before) {
          if (!expected.count(p)) unc.insert(unc.end(), {p.first, p.second});
        }
        for (const auto& p : expected) {
          if (!before.count(p)) col.insert(col.end(), {p.first, p.second});
        }
        EXPECT_EQ(f.uncollide, unc) << "frame " << f.frame;
        EXPECT_EQ(f.collide, col) << "frame " << f.frame;
        ++exact_frames;
      }
      frame = f.frame;
    }
  }
  EXPECT_GE(exact_frames, static_cast<uint64_t>(kFrames) - 5) << "frames were folded";
  EXPECT_FALSE(oracle.interests[interest.id()].set.empty());
  EXPECT_EQ(producer->Wait(30s), 0) << w.Logs();
}

TEST(ShardProcess, AShardKilledAndStartedAgainIsRestatedAndTheMergedSetStaysExact) {
  World w;
  const transport::ShardMap map = TestMap();
  std::unique_ptr<transport::Connection> connection;
  std::unique_ptr<client::ShardedSubscriber> sub;
  OpenMerged(w, ClientOptions(w.base), map, &connection, &sub);
  if (HasFatalFailure()) return;
  constexpr int kFrames = 200;
  auto producer = w.Produce(kFrames, 50);
  uint64_t folded = 0;
  bool killed = false;
  FollowAndCompare(
      w, *sub, kFrames,
      [&](uint64_t frame) {
        if (frame < 40 || killed) return;
        killed = true;
        w.daemons[1]->Kill();  // SIGKILL
        std::this_thread::sleep_for(300ms);
        w.daemons[1] = w.Start("b");
      },
      &folded);
  EXPECT_TRUE(killed);
  EXPECT_EQ(sub->view().restarts(1), 1u);
  EXPECT_EQ(producer->Wait(60s), 0) << w.Logs();
}

// Hosts joined by a switch: a network namespace per host, each with a veth pair to a bridge in
// a switch namespace, and one pair from this (the root) namespace, so that this process is a
// host too. Removed on destruction. Needs root (CAP_NET_ADMIN).
class TestNetwork {
 public:
  static constexpr const char* kSubnet = "10.231.7.";
  // Creates hosts.size() namespaces; host i has address kSubnet (11 + i), this one kSubnet 1.
  explicit TestNetwork(size_t hosts) {
    // What a killed run of this test left behind would take the subnet's route: remove it.
    (void)std::system(
        "for n in $(/usr/sbin/ip netns list | grep -o '^bpnet[0-9a-z]*'); do /usr/sbin/ip netns "
        "del "
        "$n; done; for l in $(/usr/sbin/ip -br link | grep -o '^bpnet[0-9]*r'); do /usr/sbin/ip "
        "link del $l; done");
    std::string tag = "bpnet";
    tag += std::to_string(getpid() % 100000);
    sw_ = tag + "sw";
    netns_ = Ip("netns add " + sw_);
    bridge_ = netns_ && Ip("-n " + sw_ + " link add br0 type bridge");
    ok_ = bridge_ && Ip("-n " + sw_ + " link set br0 up");
    for (size_t i = 0; ok_ && i < hosts; ++i) {
      const std::string ns = tag + "h" + std::to_string(i);
      std::string port = "p";
      port += std::to_string(i);
      hosts_.push_back(ns);
      ok_ = Ip("netns add " + ns) && Ip("-n " + ns + " link set lo up") &&
            Ip("-n " + ns + " link add eth0 type veth peer name " + port + " netns " + sw_) &&
            Ip("-n " + ns + " addr add " + Address(i) + "/24 dev eth0") &&
            Ip("-n " + ns + " link set eth0 up") &&
            Ip("-n " + sw_ + " link set " + port + " master br0") &&
            Ip("-n " + sw_ + " link set " + port + " up");
    }
    root_ = tag + "r";
    ok_ = ok_ && Ip("link add " + root_ + " type veth peer name root netns " + sw_) &&
          Ip("addr add " + std::string(kSubnet) + "1/24 dev " + root_) &&
          Ip("link set " + root_ + " up") && Ip("-n " + sw_ + " link set root master br0") &&
          Ip("-n " + sw_ + " link set root up");
  }
  ~TestNetwork() {
    (void)Ip("link del " + root_);
    for (const std::string& ns : hosts_) (void)Ip("netns del " + ns);
    (void)Ip("netns del " + sw_);
  }
  bool ok() const { return ok_; }
  /// False when the kernel would not make a bridge (no bridge support): nothing to test on.
  bool bridge() const { return !netns_ || bridge_; }
  const std::string& host(size_t i) const { return hosts_[i]; }
  static std::string Address(size_t i) {
    std::string address = kSubnet;
    return address += std::to_string(11 + i);
  }
  // Cuts (or restores) host i's link at the switch.
  bool SetLink(size_t i, bool up) {
    return Ip("-n " + sw_ + " link set p" + std::to_string(i) + (up ? " up" : " down"));
  }
  // The shipped LAN configuration for the host at address: its interface, no multicast, and
  // every host of the network as a unicast peer.
  std::string CycloneXml(const std::string& address) const {
    std::string xml;
    EXPECT_TRUE(transport::ReadTextFile(SourcePath("config/cyclonedds-lan.xml"), &xml).ok());
    auto replace = [&](const std::string& from, const std::string& to) {
      const size_t at = xml.find(from);
      EXPECT_NE(at, std::string::npos) << "cyclonedds-lan.xml has no " << from;
      if (at != std::string::npos) xml.replace(at, from.size(), to);
    };
    std::string peers = "<Peers><Peer address=\"" + std::string(kSubnet) + "1\"/>";
    for (size_t i = 0; i < hosts_.size(); ++i) peers += "<Peer address=\"" + Address(i) + "\"/>";
    peers += "</Peers>";
    replace("<NetworkInterface autodetermine=\"true\"/>",
            "<NetworkInterface address=\"" + address + "\"/>");
    replace("<AllowMulticast>spdp</AllowMulticast>", "<AllowMulticast>false</AllowMulticast>");
    replace("<ParticipantIndex>auto</ParticipantIndex>",
            "<ParticipantIndex>auto</ParticipantIndex>" + peers);
    return xml;
  }

 private:
  static bool Ip(const std::string& args) {
    return std::system(("/usr/sbin/ip " + args + " 2>&1").c_str()) == 0;
  }
  bool ok_ = false, netns_ = false, bridge_ = false;
  std::string sw_, root_;
  std::vector<std::string> hosts_;
};

// Three daemons and the producer each in a namespace of their own (four hosts), this process
// subscribing from a fifth, all with the LAN configuration and unicast discovery. Shard b's link
// is cut at the switch for longer than the participant lease, then restored: the producer
// restates shard b, and every merged frame still equals the oracle.
TEST(ShardNetwork, FourHostsOverVethPairsAndACutLinkResyncToTheExactSet) {
  if (geteuid() != 0) GTEST_SKIP() << "needs root to create network namespaces";
  TestNetwork net(4);
  if (!net.bridge()) GTEST_SKIP() << "the kernel makes no bridge (ip link add type bridge)";
  ASSERT_TRUE(net.ok()) << "could not create the namespaces and veth pairs";
  ScratchDir xml_dir("bp-shard-xml-");
  std::array<std::string, 4> hosts, xml_paths;
  for (size_t i = 0; i < 4; ++i) {
    hosts[i] = net.host(i);
    xml_paths[i] = xml_dir.path() + "/cyclone-" + std::to_string(i) + ".xml";
    std::ofstream(xml_paths[i]) << net.CycloneXml(TestNetwork::Address(i));
  }
  World w(kDomain + 1, hosts, xml_paths);
  const transport::ShardMap map = TestMap();
  transport::ConnectionOptions options = ClientOptions(w.base);
  options.cyclone_xml = net.CycloneXml(std::string(TestNetwork::kSubnet) + "1");
  std::unique_ptr<transport::Connection> connection;
  std::unique_ptr<client::ShardedSubscriber> sub;
  OpenMerged(w, options, map, &connection, &sub);
  if (HasFatalFailure()) return;
  constexpr int kFrames = 300;
  auto producer = w.Produce(kFrames, 50);
  uint64_t folded = 0;
  bool cut = false;
  FollowAndCompare(
      w, *sub, kFrames,
      [&](uint64_t frame) {
        if (frame < 40 || cut) return;
        cut = true;
        ASSERT_TRUE(net.SetLink(1, false));
        std::this_thread::sleep_for(4s);  // the LAN lease is 3 s
        ASSERT_TRUE(net.SetLink(1, true));
      },
      &folded);
  EXPECT_TRUE(cut);
  // Shard b missed the frames of the cut: they are folded into the frame of its restate.
  EXPECT_GE(folded, 1u) << "no merged frame folded the frames shard b missed";
  EXPECT_EQ(producer->Wait(60s), 0) << w.Logs();
  std::printf("%s", ReadFile(w.dir.path() + "/producer.log").c_str());
}

// The producer process: the scene through a ShardedPublisher that restates restarted shards.
int Produce(char** argv) {
  const std::string xml_path = argv[3], partition = argv[4], map_path = argv[5];
  const int frames = std::atoi(argv[6]), rate = std::atoi(argv[7]);
  transport::ConnectionOptions options;
  options.domain = static_cast<uint32_t>(std::atoi(argv[2]));
  options.partition = partition;
  if (!transport::ReadTextFile(xml_path, &options.cyclone_xml).ok()) return 3;
  transport::ShardMap map;
  if (Status s = transport::ShardMap::Load(map_path, &map); !s.ok()) {
    std::fprintf(stderr, "producer: %s\n", s.ToString().c_str());
    return 3;
  }
  std::unique_ptr<transport::Connection> connection;
  std::unique_ptr<client::ShardedPublisher> pub;
  client::PublisherOptions po;
  po.restate_on_restart = true;
  Status s = transport::Connection::Open(options, &connection);
  if (s.ok()) s = client::ShardedPublisher::Create(*connection, map, kProducer, po, &pub);
  if (s.ok()) s = pub->WaitForDaemon(30s);
  if (!s.ok()) {
    std::fprintf(stderr, "producer: %s\n", s.ToString().c_str());
    return 3;
  }
  BorderScene scene(7);
  FrameOps ops;
  wire::UpdateBatch batch;
  const auto period = std::chrono::microseconds(1000000 / rate);
  auto next = std::chrono::steady_clock::now();
  for (int f = 1; f <= frames; ++f) {
    if (f == 1) {
      scene.Initial(&ops);
    } else {
      scene.Next(&ops);
    }
    tools::FillSceneFrame(ops, 3, &batch);
    batch.set_frame(static_cast<uint64_t>(f));
    batch.set_end_of_frame(true);
    for (;;) {
      s = pub->Publish(&batch);
      if (s.ok()) break;
      if (s.code() != StatusCode::kDeadlineExceeded) {
        std::fprintf(stderr, "producer: frame %d: %s\n", f, s.ToString().c_str());
        return 1;
      }
      std::fprintf(stderr, "producer: frame %d: %s; retrying\n", f, s.ToString().c_str());
    }
    next += period;
    std::this_thread::sleep_until(next);
  }
  // Stay a little while: a shard restarted late still gets its restate.
  for (int i = 0; i < 100; ++i) {
    if (Status m = pub->Maintain(); !m.ok())
      std::fprintf(stderr, "producer: %s\n", m.ToString().c_str());
    std::this_thread::sleep_for(20ms);
  }
  s = pub->Flush(10s);
  std::fprintf(stderr, "producer: %d frames, %" PRIu64 " handovers, %zu border objects: %s\n",
               frames, pub->handovers(), pub->border_objects(), s.ToString().c_str());
  return s.ok() ? 0 : 1;
}

}  // namespace
}  // namespace bp::test

int main(int argc, char** argv) {
  if (argc >= 2 && std::string(argv[1]) == "--produce") {
    if (argc != 8) {
      std::fprintf(stderr, "usage: %s --produce DOMAIN CYCLONE_XML PARTITION MAP FRAMES RATE\n",
                   argv[0]);
      return 2;
    }
    return bp::test::Produce(argv);
  }
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
