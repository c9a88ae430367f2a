// The daemon's interests over real DDS: each kind of interest on its own stream against the
// oracle filtered the same way, frame by frame, with a region moved and an interest dropped at
// run time; a late joiner of a stream synced from its snapshot; the whole-world stream
// unchanged; bad interests refused on the status topic; spot queries equal to the oracle's
// answer.
#include <algorithm>
#include <random>
#include <set>

#include "daemon_test_support.h"
#include "interest_oracle.h"

#include "bp/client/interests.h"

namespace bp::test {
namespace {

using B = Box<3, double>;

B ToDouble(const Box<3, float>& f) {
  B b;
  for (size_t a = 0; a < 3; ++a) {
    b.lo[a] = f.lo[a];
    b.hi[a] = f.hi[a];
  }
  return b;
}

// One interest followed through its own stream.
struct Follower {
  uint64_t id = 0;
  std::unique_ptr<client::EventSubscriber> sub;
  client::OverlapView view;
};

// Reads a follower's stream until it is synced and quiet for a while (the daemon wrote the parts
// of the frame the caller waited for before the caller saw that frame's world parts).
void Settle(Follower& f, client::SnapshotRequester& requests) {
  ASSERT_TRUE(SyncUntil(
      *f.sub, requests, f.view, [](const client::OverlapView&) { return true; }, 15s, f.id))
      << "interest " << f.id << ": " << f.view.last_loss();
  for (auto quiet_since = std::chrono::steady_clock::now();
       std::chrono::steady_clock::now() - quiet_since < 80ms;) {
    std::vector<wire::EventBatch> parts;
    BP_ASSERT_OK(f.sub->Poll(20ms, &parts));
    if (!parts.empty()) quiet_since = std::chrono::steady_clock::now();
    for (const auto& p : parts) {
      EXPECT_EQ(p.interest(), f.id);
      ASSERT_FALSE(f.view.Apply(p))
          << "interest " << f.id << " lost its sync: " << f.view.last_loss();
    }
  }
  ASSERT_TRUE(f.view.synced());
}

TEST(DaemonInterests, EachKindOnItsOwnStreamMatchesTheOracle) {
  service::Config config = TestConfig(kDomain);
  config.engine.algorithm = "grid_dense";
  InProcessDaemon daemon(config);
  Client client(config);
  auto pub = client.Publisher(1);
  auto pub2 = client.Publisher(2);
  Scene scene(SmallScene(21));
  InterestOracle<3> oracle;
  const double side = scene.side();

  // Producer 1's scene; producer 2's resting objects of categories 2 and 4 (one invisible to
  // regions: its mask lacks the regions' bit).
  FrameOps ops = InitialOps(scene);
  auto apply = [&](const FrameOps& o) {
    for (uint64_t id : o.erases) oracle.objects.erase(service::GlobalKey(1, id));
    for (const auto* list : {&o.inserts, &o.updates}) {
      for (const auto& b : *list) {
        oracle.objects[service::GlobalKey(1, b.id)].box = ToDouble(ToBox<3, float>(b, 1.0));
      }
    }
  };
  // The daemon frame that closed producer 1's frame `frame`, and the world's events there.
  auto world_frame = [&](uint64_t frame) {
    FrameEvents got;
    for (;;) {
      if (!client.events->NextFrame(&got)) {
        ADD_FAILURE() << "no daemon frame closed producer 1's frame " << frame;
        return uint64_t{0};
      }
      if (got.last.source_producer() == 1 && got.last.source_frame() == frame) break;
    }
    return got.frame;
  };
  apply(ops);
  PublishFrame(*pub, ops, 3, 1, 1);
  ASSERT_NE(world_frame(1), 0u);
  {
    wire::UpdateBatch batch;
    batch.set_dim(3);
    batch.set_end_of_frame(true);
    std::mt19937_64 rng(5);
    std::uniform_real_distribution<double> at(0, side);
    for (uint64_t id = 1; id <= 30; ++id) {
      Box<3, float> box;
      for (size_t a = 0; a < 3; ++a) {
        box.lo[a] = static_cast<float>(std::floor(at(rng)));
        box.hi[a] = box.lo[a] + 3;
      }
      ObjectOptions options;
      options.category = id % 2 == 0 ? 2 : 4;
      if (id == 7) options.mask = ~service::kRegionCategory;
      client::AddBox<3>(batch.mutable_inserts(), id, box);
      batch.mutable_inserts()->add_category(options.category);
      batch.mutable_inserts()->add_mask(options.mask);
      oracle.objects[service::GlobalKey(2, id)] = {ToDouble(box), options};
    }
    BP_ASSERT_OK(pub2->Publish(&batch));
    FrameEvents got;
    ASSERT_TRUE(client.events->NextFrame(&got));
  }

  std::unique_ptr<client::InterestClient> interests;
  BP_ASSERT_OK(client::InterestClient::Create(*client.connection, &interests));
  std::unique_ptr<client::SnapshotRequester> requests;
  BP_ASSERT_OK(client::SnapshotRequester::Create(*client.connection, &requests));
  BP_ASSERT_OK(interests->WaitForDaemon(10s));
  BP_ASSERT_OK(requests->WaitForDaemon(10s));
  auto region = [&](wire::Interest* in, double from, double to) {
    in->clear_region_lo();
    in->clear_region_hi();
    for (int a = 0; a < 3; ++a) in->add_region_lo(std::floor(side * from));
    for (int a = 0; a < 3; ++a) in->add_region_hi(std::floor(side * to));
  };
  std::vector<wire::Interest> declared(5);
  for (auto& in : declared) {
    in.set_id(client::InterestClient::NewInterestId());
    in.set_dim(3);
  }
  region(&declared[0], 0.3, 0.6);  // a region with hysteresis and the pairs inside it
  declared[0].set_leave_margin(2);
  declared[0].set_pairs_inside(true);
  region(&declared[1], 0.1, 0.3);  // two regions, no margin
  for (int a = 0; a < 3; ++a) declared[1].add_region_lo(std::floor(side * 0.7));
  for (int a = 0; a < 3; ++a) declared[1].add_region_hi(std::floor(side * 0.9));
  for (uint64_t id : {3u, 50u, 120u, 201u, 333u, 399u})
    declared[2].add_keys(service::GlobalKey(1, id));
  declared[3].add_producers(2);
  declared[4].set_category_mask(4);
  std::vector<Follower> followers(declared.size());
  for (size_t i = 0; i < declared.size(); ++i) {
    followers[i].id = declared[i].id();
    BP_ASSERT_OK(client::EventSubscriber::Create(*client.connection, 1000, &followers[i].sub,
                                                 followers[i].id));
  }
  for (const auto& in : declared) {
    BP_ASSERT_OK(interests->Declare(in));
    oracle.Declare(in);
  }
  const auto deadline = std::chrono::steady_clock::now() + 10s;
  while (daemon.daemon().interests() < declared.size() &&
         std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(5ms);
  }
  ASSERT_EQ(daemon.daemon().interests(), declared.size());

  // A whole-world view as well: it must never see a region.
  std::unique_ptr<transport::Connection> world_connection;
  BP_ASSERT_OK(transport::Connection::Open(ClientOptions(config), &world_connection));
  std::unique_ptr<client::EventSubscriber> world_sub;
  BP_ASSERT_OK(client::EventSubscriber::Create(*world_connection, 1000, &world_sub));
  std::unique_ptr<client::SnapshotRequester> world_requests;
  BP_ASSERT_OK(client::SnapshotRequester::Create(*world_connection, &world_requests));
  BP_ASSERT_OK(world_sub->WaitForDaemon(10s));
  BP_ASSERT_OK(world_requests->WaitForDaemon(10s));
  client::OverlapView world_view;

  oracle.Step();
  size_t region_pairs_seen = 0;
  for (uint64_t frame = 2; frame <= 11; ++frame) {
    if (frame == 6) {
      // Changed at run time: the first region moves; the keys interest is dropped.
      region(&declared[0], 0.4, 0.7);
      BP_ASSERT_OK(interests->Declare(declared[0]));
      oracle.Declare(declared[0]);
      BP_ASSERT_OK(interests->Drop(declared[2].id()));
      oracle.interests.erase(declared[2].id());
      const auto until = std::chrono::steady_clock::now() + 10s;
      while (daemon.daemon().interests() != declared.size() - 1 &&
             std::chrono::steady_clock::now() < until) {
        std::this_thread::sleep_for(5ms);
      }
      ASSERT_EQ(daemon.daemon().interests(), declared.size() - 1);
    }
    scene.NextFrame(&ops);
    apply(ops);
    oracle.Step();
    PublishFrame(*pub, ops, 3, frame, 1);
    const uint64_t daemon_frame = world_frame(frame);
    ASSERT_NE(daemon_frame, 0u);
    ASSERT_TRUE(SyncTo(*world_sub, *world_requests, world_view, daemon_frame))
        << world_view.last_loss();
    const auto world = world_view.SortedPairs();
    ASSERT_EQ(std::set<InterestOracle<3>::Pair>(world.begin(), world.end()), oracle.world)
        << "frame " << frame;
    for (auto& f : followers) {
      if (!oracle.interests.count(f.id)) continue;
      Settle(f, *requests);
      if (HasFatalFailure()) return;
      const auto got = f.view.SortedPairs();
      ASSERT_EQ(std::set<InterestOracle<3>::Pair>(got.begin(), got.end()),
                oracle.interests.at(f.id).set)
          << "interest " << f.id << " at frame " << frame;
      for (const auto& p : got) region_pairs_seen += p.first < service::kLocalIdLimit ? 1 : 0;
    }
  }
  EXPECT_GT(region_pairs_seen, 20u);
  // A late joiner of an interest's stream syncs from that interest's snapshot.
  Follower late;
  late.id = declared[0].id();
  BP_ASSERT_OK(client::EventSubscriber::Create(*client.connection, 1000, &late.sub, late.id));
  Settle(late, *requests);
  if (HasFatalFailure()) return;
  const auto late_pairs = late.view.SortedPairs();
  EXPECT_EQ(std::set<InterestOracle<3>::Pair>(late_pairs.begin(), late_pairs.end()),
            oracle.interests.at(late.id).set);
  for (const auto& in : declared) {
    if (!oracle.interests.count(in.id())) continue;
    EXPECT_FALSE(oracle.interests.at(in.id()).set.empty()) << "interest " << in.id() << " is empty";
  }

  // Spot queries: equal to the oracle's answer (as of the last frame).
  for (double from : {0.0, 0.25, 0.5}) {
    const std::vector<double> lo(3, std::floor(side * from)),
        hi(3, std::floor(side * (from + 0.3)));
    std::vector<uint64_t> keys;
    uint64_t at_frame = 0;
    BP_ASSERT_OK(interests->Query(lo, hi, 10s, &keys, &at_frame));
    B box;
    for (size_t a = 0; a < 3; ++a) {
      box.lo[a] = lo[a];
      box.hi[a] = hi[a];
    }
    EXPECT_EQ(keys, oracle.Spot(box));
    EXPECT_FALSE(keys.empty());
    EXPECT_EQ(at_frame, daemon.daemon().frames());
  }
  std::vector<uint64_t> keys;
  const std::vector<double> inverted{1, 1, 1}, zero{0, 0, 0};
  Status refused = interests->Query(inverted, zero, 10s, &keys);
  EXPECT_EQ(refused.code(), StatusCode::kInvalidArgument) << refused.ToString();
  EXPECT_NE(refused.message().find("lo > hi on axis 0"), std::string::npos) << refused.message();

  // Bad interests are refused on the status topic with their reason; nothing else changes.
  wire::Interest bad;
  bad.set_id(client::InterestClient::NewInterestId());
  bad.set_dim(3);
  for (double v : {0.0, std::nan(""), 0.0}) bad.add_region_lo(v);
  for (double v : {1.0, 1.0, 1.0}) bad.add_region_hi(v);
  BP_ASSERT_OK(interests->Declare(bad));
  wire::Interest unknown;
  unknown.set_id(client::InterestClient::NewInterestId());
  unknown.add_producers(9);
  BP_ASSERT_OK(interests->Declare(unknown));
  std::vector<wire::InterestRefusal> refusals;
  ASSERT_TRUE(client.status->WaitUntil([&](const wire::DaemonStatus& s) {
    EXPECT_TRUE(interests->OnStatus(s, &refusals).ok());
    return refusals.size() >= 2;
  })) << "no refusal reported";
  EXPECT_EQ(refusals[0].interest(), bad.id());
  EXPECT_NE(refusals[0].message().find("NaN"), std::string::npos) << refusals[0].message();
  EXPECT_EQ(refusals[1].interest(), unknown.id());
  EXPECT_NE(refusals[1].message().find("producers[0] = 9 is unknown"), std::string::npos)
      << refusals[1].message();
  EXPECT_EQ(daemon.daemon().interests(), declared.size() - 1);
  EXPECT_EQ(daemon.daemon().interest_refusals(), 2u);
}

}  // namespace
}  // namespace bp::test
