// What the daemon's in-process tests share: a client of the test's deployment (events, status,
// publishers), a small scene, a frame published in batches, and batch helpers.
#pragma once

#include <chrono>
#include <cstdint>
#include <initializer_list>
#include <memory>
#include <utility>

#include "service_test_support.h"

namespace bp::test {

using namespace std::chrono_literals;

inline constexpr uint32_t kDomain = BP_TEST_DOMAIN;

struct Client {
  std::unique_ptr<transport::Connection> connection;
  std::unique_ptr<EventCollector> events;
  std::unique_ptr<RejectionCollector> status;

  explicit Client(const service::Config& config) {
    Status s = transport::Connection::Open(ClientOptions(config), &connection);
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

inline SceneParams SmallScene(uint64_t seed, int dim = 3) {
  SceneParams p;
  p.dim = dim;
  p.n = 400;
  p.moving = 60;
  p.churn = 6;
  p.density = 0.2;  // dense enough for plenty of events
  p.seed = seed;
  return p;
}

inline FrameOps InitialOps(const Scene& scene) {
  FrameOps ops;
  ops.inserts = scene.Initial();
  return ops;
}

inline void ExpectFrame(EventCollector& events, uint64_t frame, const PairList& uncollide,
                        const PairList& collide) {
  FrameEvents got;
  ASSERT_TRUE(events.WaitFrame(frame, &got)) << "no events for frame " << frame;
  EXPECT_EQ(got.uncollide, uncollide) << "uncollides of frame " << frame;
  EXPECT_EQ(got.collide, collide) << "collides of frame " << frame;
}

// Publishes ops as one frame, split into `batches` batches; the last closes the frame.
inline void PublishFrame(client::UpdatePublisher& pub, const FrameOps& ops, int dim, uint64_t frame,
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
    tools::FillSceneFrame(slice, dim, &batch);
    batch.set_frame(frame);
    batch.set_end_of_frame(end_of_frame && part + 1 == nb);
    Status s = pub.Publish(&batch);
    ASSERT_TRUE(s.ok()) << s.ToString();
  }
}

inline wire::UpdateBatch InsertBatch(
    std::initializer_list<std::pair<uint64_t, Box<3, float>>> boxes) {
  wire::UpdateBatch batch;
  batch.set_dim(3);
  batch.set_end_of_frame(true);
  for (auto& [id, box] : boxes) client::AddBox<3>(batch.mutable_inserts(), id, box);
  return batch;
}

inline Box<3, float> Cube(float x, float w = 1.0f) {
  return Box<3, float>{{x, 0, 0}, {x + w, w, w}};
}

}  // namespace bp::test
