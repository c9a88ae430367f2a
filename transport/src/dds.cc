#include "bp/transport/dds.h"

#include <condition_variable>
#include <cstring>
#include <map>
#include <mutex>
#include <thread>

#include "envelope.h"
#include <spdlog/spdlog.h>

namespace bp::dds {
namespace {

StatusCode CodeOf(dds_return_t rc) {
  switch (rc) {
    case DDS_RETCODE_TIMEOUT:
      return StatusCode::kDeadlineExceeded;
    case DDS_RETCODE_BAD_PARAMETER:
    case DDS_RETCODE_INCONSISTENT_POLICY:
    case DDS_RETCODE_IMMUTABLE_POLICY:
    case DDS_RETCODE_PRECONDITION_NOT_MET:
      return StatusCode::kInvalidArgument;
    case DDS_RETCODE_OUT_OF_RESOURCES:
      return StatusCode::kResourceExhausted;
    default:
      return StatusCode::kUnavailable;
  }
}

void CycloneLogSink(void* /*userdata*/, const dds_log_data_t* data) {
  std::string_view message(data->message, data->size);
  while (!message.empty() && (message.back() == '\n' || message.back() == '\r')) {
    message.remove_suffix(1);
  }
  spdlog::level::level_enum level = spdlog::level::debug;
  if (data->priority & (DDS_LC_FATAL | DDS_LC_ERROR)) {
    level = spdlog::level::err;
  } else if (data->priority & DDS_LC_WARNING) {
    level = spdlog::level::warn;
  } else if (data->priority & DDS_LC_INFO) {
    level = spdlog::level::info;
  }
  spdlog::log(level, "cyclonedds: {}", message);
}

// Polls a matched-count getter until it reaches n or timeout passes. Discovery is event-driven
// inside Cyclone; a 5 ms poll adds at most 5 ms to a wait that happens once per connection.
Status PollUntil(const std::function<uint32_t()>& count, uint32_t n,
                 std::chrono::milliseconds timeout, std::string_view what) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (count() < n) {
    if (std::chrono::steady_clock::now() >= deadline) {
      return Status(StatusCode::kDeadlineExceeded, std::string(what) + ": " +
                                                       std::to_string(count()) + " of " +
                                                       std::to_string(n) + " matched after " +
                                                       std::to_string(timeout.count()) + " ms");
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return Status::Ok();
}

dds_duration_t ToDds(std::chrono::nanoseconds d) {
  return d.count() < 0 ? 0 : static_cast<dds_duration_t>(d.count());
}

}  // namespace

Status FromRetcode(dds_return_t rc, std::string_view what) {
  if (rc >= 0) return Status::Ok();
  return Status(CodeOf(rc), std::string(what) + ": " + dds_strretcode(rc));
}

void RouteCycloneLogToSpdlog() {
  static std::once_flag once;
  std::call_once(once, [] { dds_set_log_sink(&CycloneLogSink, nullptr); });
}

Entity& Entity::operator=(Entity&& other) noexcept {
  if (this != &other) {
    Reset();
    handle_ = other.handle_;
    other.handle_ = 0;
  }
  return *this;
}

void Entity::Reset() {
  // A parent's deletion deletes its children: a child deleted afterwards is already gone, and
  // Cyclone then returns an error that means nothing here.
  if (handle_ > 0) (void)dds_delete(handle_);
  handle_ = 0;
}

namespace {
// The live domains of this process. An entry whose weak_ptr has expired belongs to a Domain
// being destroyed: its Cyclone domain still exists until ~Domain erases the entry, so Acquire
// waits for that instead of creating a second domain with the same id (which Cyclone refuses).
std::mutex domains_mutex;
std::condition_variable domains_changed;
std::map<uint32_t, std::weak_ptr<Domain>>& Domains() {
  static std::map<uint32_t, std::weak_ptr<Domain>> domains;
  return domains;
}
}  // namespace

Status Domain::Acquire(uint32_t id, const std::string& xml, std::shared_ptr<Domain>* out) {
  std::unique_lock lock(domains_mutex);
  auto& domains = Domains();
  for (;;) {
    auto it = domains.find(id);
    if (it == domains.end()) break;
    if (auto live = it->second.lock()) {
      if (live->xml_ != xml) {
        return Status(StatusCode::kInvalidArgument,
                      "DDS domain " + std::to_string(id) +
                          " already exists in this process with another configuration");
      }
      *out = std::move(live);
      return Status::Ok();
    }
    domains_changed.wait(lock);  // being destroyed: wait for ~Domain to erase it
  }
  RouteCycloneLogToSpdlog();
  const dds_entity_t handle = dds_create_domain(id, xml.empty() ? nullptr : xml.c_str());
  if (handle < 0) {
    return FromRetcode(handle, "creating DDS domain " + std::to_string(id) +
                                   " (check the Cyclone XML configuration)");
  }
  std::shared_ptr<Domain> domain(new Domain(id, handle, xml));
  domains[id] = domain;
  *out = std::move(domain);
  return Status::Ok();
}

Domain::~Domain() {
  std::lock_guard lock(domains_mutex);
  (void)dds_delete(handle_);
  Domains().erase(id_);
  domains_changed.notify_all();
}

Status Participant::Create(uint32_t domain, const std::string& xml, const std::string& partition,
                           std::unique_ptr<Participant>* out) {
  std::unique_ptr<Participant> p(new Participant());
  if (Status s = Domain::Acquire(domain, xml, &p->domain_); !s.ok()) return s;
  const dds_entity_t participant = dds_create_participant(domain, nullptr, nullptr);
  if (participant < 0) return FromRetcode(participant, "creating DDS participant");
  p->participant_ = Entity(participant);
  Qos qos;
  if (!partition.empty()) dds_qset_partition1(qos.get(), partition.c_str());
  const dds_entity_t publisher = dds_create_publisher(participant, qos.get(), nullptr);
  if (publisher < 0) return FromRetcode(publisher, "creating DDS publisher");
  p->publisher_ = Entity(publisher);
  const dds_entity_t subscriber = dds_create_subscriber(participant, qos.get(), nullptr);
  if (subscriber < 0) return FromRetcode(subscriber, "creating DDS subscriber");
  p->subscriber_ = Entity(subscriber);
  *out = std::move(p);
  return Status::Ok();
}

Status Participant::CreateTopic(const std::string& name, dds_entity_t* out_topic) {
  const dds_entity_t topic =
      dds_create_topic(participant_.get(), &bp_wire_Envelope_desc, name.c_str(), nullptr, nullptr);
  if (topic < 0) return FromRetcode(topic, "creating DDS topic '" + name + "'");
  *out_topic = topic;  // owned by the participant
  return Status::Ok();
}

namespace {
// The parent of a writer (publisher) or reader (subscriber): the participant's own, or, with a
// partition, a new one of that partition, owned by *own.
Status PartitionParent(const Participant& participant, const std::string* partition, bool publisher,
                       Entity* own, dds_entity_t* parent) {
  *parent = publisher ? participant.publisher() : participant.subscriber();
  if (partition == nullptr) return Status::Ok();
  Qos qos;
  dds_qset_partition1(qos.get(), partition->c_str());
  const dds_entity_t p = publisher ? dds_create_publisher(participant.get(), qos.get(), nullptr)
                                   : dds_create_subscriber(participant.get(), qos.get(), nullptr);
  if (p < 0) {
    return FromRetcode(p, std::string("creating DDS ") + (publisher ? "publisher" : "subscriber") +
                              " for partition '" + *partition + "'");
  }
  *own = Entity(p);
  *parent = p;
  return Status::Ok();
}
}  // namespace

Status Writer::Create(const Participant& participant, dds_entity_t topic, const Qos& qos,
                      Writer* out, const std::string* partition) {
  Entity publisher;
  dds_entity_t parent = 0;
  if (Status s = PartitionParent(participant, partition, true, &publisher, &parent); !s.ok()) {
    return s;
  }
  const dds_entity_t writer = dds_create_writer(parent, topic, qos.get(), nullptr);
  if (writer < 0) return FromRetcode(writer, "creating DDS writer");
  out->writer_ = Entity(writer);
  out->publisher_ = std::move(publisher);
  return Status::Ok();
}

Status Writer::Write(uint64_t seq, std::string_view payload) {
  bp_wire_Envelope sample{};
  sample.seq = seq;
  // Cyclone serialises during dds_write and never frees a buffer with _release unset.
  sample.payload._buffer = reinterpret_cast<uint8_t*>(const_cast<char*>(payload.data()));
  sample.payload._length = static_cast<uint32_t>(payload.size());
  sample.payload._maximum = static_cast<uint32_t>(payload.size());
  sample.payload._release = false;
  if (payload.size() > UINT32_MAX) {
    return Status(StatusCode::kInvalidArgument, "payload of " + std::to_string(payload.size()) +
                                                    " bytes exceeds the envelope's 4 GiB limit");
  }
  return FromRetcode(dds_write(writer_.get(), &sample), "dds_write");
}

Reaper::Reaper() {
  thread_ = std::thread([this] {
    std::unique_lock lock(mutex_);
    for (;;) {
      wake_.wait(lock, [this] { return stop_ || !pending_.empty(); });
      std::vector<Writer> batch;
      batch.swap(pending_);
      lock.unlock();
      batch.clear();  // the deletions, outside the lock
      lock.lock();
      if (stop_ && pending_.empty()) return;
    }
  });
}

Reaper::~Reaper() {
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
  }
  wake_.notify_one();
  thread_.join();
}

void Reaper::Delete(Writer&& writer) {
  {
    std::lock_guard lock(mutex_);
    pending_.push_back(std::move(writer));
  }
  wake_.notify_one();
}

uint32_t Writer::MatchedReaders() const {
  dds_publication_matched_status_t status{};
  if (dds_get_publication_matched_status(writer_.get(), &status) < 0) return 0;
  return status.current_count;
}

Status Writer::WaitForReaders(uint32_t n, std::chrono::milliseconds timeout) const {
  return PollUntil([this] { return MatchedReaders(); }, n, timeout, "waiting for DDS readers");
}

Status Writer::WaitForAcks(std::chrono::milliseconds timeout) const {
  return FromRetcode(dds_wait_for_acks(writer_.get(), ToDds(timeout)), "waiting for DDS acks");
}

void WriterLiveliness::TakeChanges(std::vector<Change>* out) {
  out->clear();
  std::lock_guard<std::mutex> lock(mutex_);
  out->swap(changes_);
}

void WriterLiveliness::OnLivelinessChanged(dds_entity_t /*reader*/,
                                           dds_liveliness_changed_status_t status, void* arg) {
  auto* self = static_cast<WriterLiveliness*>(arg);
  // One call per change: +1 alive when a writer matches or regains liveliness; -1 alive when it
  // loses it (+1 not alive) or is deleted; -1 not alive when a writer that was not alive goes.
  if (status.alive_count_change == 0 && status.not_alive_count_change == 0) return;
  std::lock_guard<std::mutex> lock(self->mutex_);
  self->changes_.push_back({status.last_publication_handle, status.alive_count_change > 0});
  if (self->on_change_) self->on_change_();
}

void WriterLiveliness::SetOnChange(std::function<void()> on_change) {
  std::lock_guard<std::mutex> lock(mutex_);
  on_change_ = std::move(on_change);
}

Status Reader::Create(const Participant& participant, dds_entity_t topic, const Qos& qos,
                      Reader* out, WriterLiveliness* liveliness, const std::string* partition) {
  Entity subscriber;
  dds_entity_t parent = 0;
  if (Status s = PartitionParent(participant, partition, false, &subscriber, &parent); !s.ok()) {
    return s;
  }
  dds_listener_t* listener = nullptr;
  if (liveliness != nullptr) {
    listener = dds_create_listener(liveliness);
    dds_lset_liveliness_changed(listener, &WriterLiveliness::OnLivelinessChanged);
  }
  const dds_entity_t reader = dds_create_reader(parent, topic, qos.get(), listener);
  if (listener != nullptr) dds_delete_listener(listener);
  if (reader < 0) return FromRetcode(reader, "creating DDS reader");
  out->reader_ = Entity(reader);
  out->subscriber_ = std::move(subscriber);
  return Status::Ok();
}

Status Reader::Take(size_t max, const std::function<void(const Received&)>& f, size_t* out_taken) {
  *out_taken = 0;
  samples_.assign(max, nullptr);  // null pointers: Cyclone loans its own buffers
  infos_.resize(max);
  const dds_return_t n =
      dds_take(reader_.get(), samples_.data(), infos_.data(), max, static_cast<uint32_t>(max));
  if (n < 0) return FromRetcode(n, "dds_take");
  for (int i = 0; i < n; ++i) {
    const size_t k = static_cast<size_t>(i);
    if (!infos_[k].valid_data) continue;
    const auto* envelope = static_cast<const bp_wire_Envelope*>(samples_[k]);
    Received received;
    received.seq = envelope->seq;
    received.payload =
        std::span<const uint8_t>(envelope->payload._buffer, envelope->payload._length);
    received.info = &infos_[k];
    f(received);
    ++*out_taken;
  }
  if (n > 0)
    return FromRetcode(dds_return_loan(reader_.get(), samples_.data(), n), "dds_return_loan");
  return Status::Ok();
}

uint32_t Reader::MatchedWriters() const {
  dds_subscription_matched_status_t status{};
  if (dds_get_subscription_matched_status(reader_.get(), &status) < 0) return 0;
  return status.current_count;
}

std::vector<dds_instance_handle_t> Reader::MatchedWriterHandles() const {
  std::vector<dds_instance_handle_t> handles(64);
  for (;;) {
    const dds_return_t n =
        dds_get_matched_publications(reader_.get(), handles.data(), handles.size());
    if (n < 0) return {};
    if (static_cast<size_t>(n) <= handles.size()) {
      handles.resize(static_cast<size_t>(n));
      return handles;
    }
    handles.resize(static_cast<size_t>(n));
  }
}

Guid Reader::MatchedWriterGuid(dds_instance_handle_t writer) const {
  Guid guid{};
  dds_builtintopic_endpoint_t* endpoint = dds_get_matched_publication_data(reader_.get(), writer);
  if (endpoint == nullptr) return guid;
  static_assert(sizeof(endpoint->key.v) == sizeof(guid));
  std::memcpy(guid.data(), endpoint->key.v, guid.size());
  dds_builtintopic_free_endpoint(endpoint);
  return guid;
}

Status Reader::WaitForWriters(uint32_t n, std::chrono::milliseconds timeout) const {
  return PollUntil([this] { return MatchedWriters(); }, n, timeout, "waiting for DDS writers");
}

Status WaitSet::Create(const Participant& participant, WaitSet* out) {
  const dds_entity_t waitset = dds_create_waitset(participant.get());
  if (waitset < 0) return FromRetcode(waitset, "creating DDS waitset");
  out->waitset_ = Entity(waitset);
  // A waitset attached to itself wakes when its trigger is set: that is how Wake() works.
  return FromRetcode(dds_waitset_attach(waitset, waitset, waitset), "attaching DDS waitset");
}

Status WaitSet::Attach(const Reader& reader) {
  const dds_entity_t condition = dds_create_readcondition(reader.get(), DDS_ANY_STATE);
  if (condition < 0) return FromRetcode(condition, "creating DDS read condition");
  conditions_.emplace_back(condition);
  return FromRetcode(dds_waitset_attach(waitset_.get(), condition, condition),
                     "attaching to DDS waitset");
}

Status WaitSet::Wait(std::chrono::nanoseconds timeout, int* out_triggered) {
  *out_triggered = 0;
  dds_attach_t triggered[8];
  const dds_return_t n = dds_waitset_wait(waitset_.get(), triggered, 8, ToDds(timeout));
  (void)dds_waitset_set_trigger(waitset_.get(), false);
  if (n < 0) return FromRetcode(n, "dds_waitset_wait");
  *out_triggered = n;
  return Status::Ok();
}

void WaitSet::Wake() { (void)dds_waitset_set_trigger(waitset_.get(), true); }

}  // namespace bp::dds
