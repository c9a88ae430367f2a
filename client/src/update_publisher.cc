#include "bp/client/update_publisher.h"

#include <time.h>

namespace bp::client {

uint64_t WallClockNs() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<uint64_t>(ts.tv_sec) * 1'000'000'000u + static_cast<uint64_t>(ts.tv_nsec);
}

Status UpdatePublisher::Create(Connection& connection, uint32_t producer,
                               std::chrono::milliseconds write_timeout,
                               std::unique_ptr<UpdatePublisher>* out) {
  if (producer == 0 || producer > 0xFFFF) {
    return Status(StatusCode::kInvalidArgument,
                  "producer id " + std::to_string(producer) + " is outside 1..65535");
  }
  std::unique_ptr<UpdatePublisher> p(new UpdatePublisher());
  p->producer_ = producer;
  dds::Qos qos;
  qos::UpdatesWriter(qos.get(), write_timeout);
  if (Status s = dds::Writer::Create(connection.participant(), connection.updates_topic(), qos,
                                     &p->writer_);
      !s.ok()) {
    return s;
  }
  *out = std::move(p);
  return Status::Ok();
}

Status UpdatePublisher::WaitForDaemon(std::chrono::milliseconds timeout) const {
  return writer_.WaitForReaders(1, timeout);
}

Status UpdatePublisher::Publish(wire::UpdateBatch* batch) {
  batch->set_version(wire::SCHEMA_VERSION_1);
  batch->set_producer(producer_);
  batch->set_batch_seq(seq_ + 1);
  batch->set_sent_time_ns(WallClockNs());
  buffer_.clear();
  if (!batch->SerializeToString(&buffer_)) {
    return Status(StatusCode::kInvalidArgument, "UpdateBatch does not serialise");
  }
  return PublishRaw(buffer_);
}

Status UpdatePublisher::PublishRaw(std::string_view payload) {
  Status s = writer_.Write(seq_ + 1, payload);
  if (s.ok()) ++seq_;
  return s;
}

}  // namespace bp::client
