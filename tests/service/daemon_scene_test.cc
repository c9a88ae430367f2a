// The daemon in-process with real Cyclone DDS on loopback (domain BP_TEST_DOMAIN, a partition
// per test): a scripted scene against the oracle, frame by frame, for every engine.
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

}  // namespace
}  // namespace bp::test
