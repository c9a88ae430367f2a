// A producer in a few lines: join the deployment, build a batch of boxes, publish it once the
// daemon is there. Usage: client_standalone [domain] [wait_ms]. Exit 0 when it published, or
// when no daemon answered within wait_ms (it says so); 1 on an error.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>

#include "bp/client/batch_builder.h"
#include "bp/client/connection.h"
#include "bp/client/update_publisher.h"

int main(int argc, char** argv) {
  bp::client::ConnectionOptions options;
  options.domain = argc > 1 ? static_cast<uint32_t>(std::atoi(argv[1])) : 0;
  const int wait_ms = argc > 2 ? std::atoi(argv[2]) : 2000;
  // Loopback only, as config/cyclonedds-loopback.xml.
  options.cyclone_xml =
      "<CycloneDDS><Domain id=\"any\"><General><Interfaces><NetworkInterface "
      "address=\"127.0.0.1\"/></Interfaces><AllowMulticast>false</AllowMulticast></General>"
      "</Domain></CycloneDDS>";
  std::unique_ptr<bp::client::Connection> connection;
  bp::Status s = bp::client::Connection::Open(options, &connection);
  if (!s.ok()) {
    std::fprintf(stderr, "connect: %s\n", s.ToString().c_str());
    return 1;
  }
  std::unique_ptr<bp::client::UpdatePublisher> publisher;
  s = bp::client::UpdatePublisher::Create(*connection, 7, std::chrono::seconds(1), &publisher);
  if (!s.ok()) {
    std::fprintf(stderr, "publisher: %s\n", s.ToString().c_str());
    return 1;
  }
  bp::wire::UpdateBatch batch;
  batch.set_dim(3);
  batch.set_frame(1);
  batch.set_end_of_frame(true);
  bp::client::AddBox<3>(batch.mutable_inserts(), 1, bp::Box<3, float>{{0, 0, 0}, {1, 1, 1}});
  bp::client::AddBox<3>(batch.mutable_inserts(), 2, bp::Box<3, float>{{0.5f, 0, 0}, {2, 1, 1}});
  s = publisher->WaitForDaemon(std::chrono::milliseconds(wait_ms));
  if (!s.ok()) {
    std::printf("client_standalone: built a batch of %d boxes; no daemon answered (%s)\n",
                batch.inserts().ids_size(), s.message().c_str());
    return 0;
  }
  s = publisher->Publish(&batch);
  std::printf("client_standalone: published frame 1: %s\n", s.ToString().c_str());
  return s.ok() ? 0 : 1;
}
