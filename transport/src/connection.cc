#include "bp/transport/connection.h"

#include <cinttypes>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <mutex>
#include <random>
#include <sstream>

namespace bp::transport {
namespace {
dds_duration_t Ms(std::chrono::milliseconds d) { return DDS_MSECS(d.count()); }
}  // namespace

Status ReadTextFile(const std::string& path, std::string* out) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Status(StatusCode::kNotFound, "cannot open '" + path + "'");
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) return Status(StatusCode::kUnavailable, "cannot read '" + path + "'");
  *out = text.str();
  return Status::Ok();
}

namespace {
std::string Suffixed(const std::string& partition, const char* kind, uint64_t id) {
  char hex[17];
  std::snprintf(hex, sizeof(hex), "%016" PRIx64, id);
  return (partition.empty() ? std::string() : partition + ".") + kind + "." + hex;
}
}  // namespace

uint64_t RandomId() {
  static std::mutex mutex;
  static std::random_device random;
  std::lock_guard lock(mutex);
  uint64_t v = 0;
  while (v == 0) v = uint64_t{random()} << 32 | random();
  return v;
}

std::string InterestPartition(const std::string& partition, uint64_t interest) {
  return Suffixed(partition, "interest", interest);
}

std::string ClientPartition(const std::string& partition, uint64_t client) {
  return Suffixed(partition, "client", client);
}

namespace qos {
void UpdatesWriter(dds_qos_t* qos, std::chrono::milliseconds write_timeout,
                   std::chrono::milliseconds liveliness_lease) {
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, Ms(write_timeout));
  dds_qset_history(qos, DDS_HISTORY_KEEP_ALL, 0);
  dds_qset_liveliness(qos, DDS_LIVELINESS_AUTOMATIC, Ms(liveliness_lease));
}
void UpdatesReader(dds_qos_t* qos, int32_t queue) {
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  dds_qset_history(qos, DDS_HISTORY_KEEP_ALL, 0);
  dds_qset_resource_limits(qos, queue, DDS_LENGTH_UNLIMITED, DDS_LENGTH_UNLIMITED);
}
void EventsWriter(dds_qos_t* qos, int32_t history, std::chrono::milliseconds write_timeout) {
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, Ms(write_timeout));
  dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, history);
}
void EventsReader(dds_qos_t* qos, int32_t depth) {
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, depth);
}
void StatusWriter(dds_qos_t* qos, std::chrono::milliseconds write_timeout) {
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, Ms(write_timeout));
  dds_qset_durability(qos, DDS_DURABILITY_TRANSIENT_LOCAL);
  dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 16);
}
void StatusReader(dds_qos_t* qos, int32_t depth) {
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  dds_qset_durability(qos, DDS_DURABILITY_TRANSIENT_LOCAL);
  dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, depth);
}
void RequestsWriter(dds_qos_t* qos) {
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_MSECS(100));
  dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 4);
}
void RequestsReader(dds_qos_t* qos) {
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 64);
}
void InterestsWriter(dds_qos_t* qos, std::chrono::milliseconds write_timeout,
                     std::chrono::milliseconds liveliness_lease) {
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, Ms(write_timeout));
  dds_qset_history(qos, DDS_HISTORY_KEEP_ALL, 0);
  dds_qset_liveliness(qos, DDS_LIVELINESS_AUTOMATIC, Ms(liveliness_lease));
}
void InterestsReader(dds_qos_t* qos) {
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  dds_qset_history(qos, DDS_HISTORY_KEEP_ALL, 0);
}
void RepliesWriter(dds_qos_t* qos, std::chrono::milliseconds write_timeout) {
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, Ms(write_timeout));
  dds_qset_durability(qos, DDS_DURABILITY_TRANSIENT_LOCAL);  // the first answer precedes the match
  dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 64);
}
void RepliesReader(dds_qos_t* qos) {
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  dds_qset_durability(qos, DDS_DURABILITY_TRANSIENT_LOCAL);
  dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 64);
}
}  // namespace qos

Status Connection::Open(const ConnectionOptions& options, std::unique_ptr<Connection>* out) {
  std::unique_ptr<Connection> c(new Connection());
  c->options_ = options;
  std::unique_ptr<dds::Participant> participant;
  if (Status s = dds::Participant::Create(options.domain, options.cyclone_xml, options.partition,
                                          &participant);
      !s.ok()) {
    return s;
  }
  dds::Participant& p = *participant;
  c->shared_.reset(new Shared{std::move(participant), p, {}, {}});
  *out = std::move(c);
  return Status::Ok();
}

Status Connection::GetTopic(TopicId id, dds_entity_t* out) {
  const auto index = static_cast<size_t>(id);
  std::lock_guard<std::mutex> lock(shared_->mutex);
  dds_entity_t& topic = shared_->topics[index];
  if (topic == 0) {
    const TopicNames& names = options_.topics;
    const std::string* name[] = {&names.updates,  &names.events,    &names.status,
                                 &names.requests, &names.interests, &names.replies};
    static_assert(std::size(name) == kTopicCount);
    if (Status s = shared_->participant.CreateTopic(*name[index], &topic); !s.ok()) return s;
  }
  *out = topic;
  return Status::Ok();
}

Status Connection::CreateWriter(TopicId id, const dds::Qos& qos, dds::Writer* out,
                                const std::string* partition) {
  dds_entity_t topic = 0;
  if (Status s = GetTopic(id, &topic); !s.ok()) return s;
  if (partition == nullptr && scoped_) partition = &options_.partition;
  return dds::Writer::Create(shared_->participant, topic, qos, out, partition);
}

Status Connection::CreateReader(TopicId id, const dds::Qos& qos, dds::Reader* out,
                                dds::WriterLiveliness* liveliness, const std::string* partition) {
  dds_entity_t topic = 0;
  if (Status s = GetTopic(id, &topic); !s.ok()) return s;
  if (partition == nullptr && scoped_) partition = &options_.partition;
  return dds::Reader::Create(shared_->participant, topic, qos, out, liveliness, partition);
}

std::unique_ptr<Connection> Connection::Scoped(const std::string& partition) const {
  std::unique_ptr<Connection> c(new Connection());
  c->options_ = options_;
  c->options_.partition = partition;
  c->scoped_ = true;
  c->shared_ = shared_;
  return c;
}

}  // namespace bp::transport
