// bp::client::Subscriber's counters over real Cyclone DDS on loopback: envelopes written by
// hand on the events topic, as a daemon would, with numbers missing.
#include "bp/client/subscriber.h"

#include <chrono>
#include <memory>
#include <vector>

#include <gtest/gtest.h>

#include "../service/service_test_support.h"

namespace bp::test {
namespace {

using namespace std::chrono_literals;

// The sequence of a restarted daemon starts again at 1: the gaps within its run still count,
// though its numbers are below the ones of the daemon before it.
TEST(Subscriber, CountsGapsWithinEachRunOfTheSequence) {
  const service::Config config = TestConfig(BP_TEST_DOMAIN);
  std::unique_ptr<client::Connection> connection;
  BP_ASSERT_OK(client::Connection::Open(ClientOptions(config), &connection));
  std::unique_ptr<client::EventSubscriber> events;
  BP_ASSERT_OK(client::EventSubscriber::Create(*connection, 64, &events));
  dds::Qos qos;
  client::qos::EventsWriter(qos.get(), 64, 1000ms);
  dds::Writer writer;
  BP_ASSERT_OK(connection->CreateWriter(client::TopicId::kEvents, qos, &writer));
  BP_ASSERT_OK(events->WaitForDaemon(10s));  // the writer is matched
  std::vector<wire::EventBatch> received;
  auto send = [&](std::vector<uint64_t> seqs) {
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
  send({1, 2, 3, 4, 5, 6, 7, 8, 10});  // 9 missing
  EXPECT_EQ(events->gaps(), 1u);
  send({1, 2, 4});  // a new run: 3 missing
  EXPECT_EQ(events->gaps(), 2u);
  EXPECT_EQ(events->malformed(), 0u);
}

}  // namespace
}  // namespace bp::test
