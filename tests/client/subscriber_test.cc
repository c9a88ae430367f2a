// bp::client::Subscriber's counters over real Cyclone DDS on loopback: envelopes written by
// hand on the events topic, as a daemon would, with numbers missing.
#include "bp/client/subscriber.h"

#include <chrono>
#include <memory>
#include <vector>

#include "../service/service_test_support.h"
#include <gtest/gtest.h>

namespace bp::test {
namespace {

using namespace std::chrono_literals;

// Each daemon run is a writer of its own whose sequence starts again at 1: gaps are counted per
// writer, whether the new run's first numbers delivered are below the old run's last or above.
TEST(Subscriber, CountsGapsPerWriter) {
  const service::Config config = TestConfig(BP_TEST_DOMAIN);
  std::unique_ptr<transport::Connection> connection;
  BP_ASSERT_OK(transport::Connection::Open(ClientOptions(config), &connection));
  std::unique_ptr<client::EventSubscriber> events;
  BP_ASSERT_OK(client::EventSubscriber::Create(*connection, 64, &events));
  dds::Qos qos;
  transport::qos::EventsWriter(qos.get(), 64, 1000ms);
  std::vector<wire::EventBatch> received;
  auto send = [&](dds::Writer& writer, std::vector<uint64_t> seqs) {
    for (uint64_t seq : seqs) {
      wire::EventBatch part;
      part.set_sequence(seq);
      part.set_last_part(true);
      BP_ASSERT_OK(writer.Write(seq, part.SerializeAsString()));
    }
    const size_t want = received.size() + seqs.size();
    for (int i = 0; i < 100 && received.size() < want; ++i) {
      BP_ASSERT_OK(events->Poll(100ms, &received));
    }
    ASSERT_EQ(received.size(), want);
  };
  auto writer = [&]() {
    dds::Writer w;
    EXPECT_TRUE(connection->CreateWriter(transport::TopicId::kEvents, qos, &w).ok());
    EXPECT_TRUE(w.WaitForReaders(1, 10s).ok());  // nothing written before the match is lost
    return w;
  };
  dds::Writer first = writer();
  send(first, {1, 2, 3, 4, 5, 6, 7, 8, 10});  // 9 missing
  EXPECT_EQ(events->gaps(), 1u);
  dds::Writer second = writer();
  send(second, {12, 13, 15});  // its first parts lost before it matched: only 14 counts
  EXPECT_EQ(events->gaps(), 2u);
  dds::Writer third = writer();
  send(third, {1, 2, 4});  // below the others' numbers: 3 missing
  EXPECT_EQ(events->gaps(), 3u);
  EXPECT_EQ(events->malformed(), 0u);
}

}  // namespace
}  // namespace bp::test
