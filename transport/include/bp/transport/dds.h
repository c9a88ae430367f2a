// bp::dds: a small RAII layer over the Cyclone DDS C API (there is no Debian package of the C++
// binding). Entities are owned and deleted on destruction; every Cyclone return code becomes a
// bp::Status naming the operation; Cyclone's own log goes to spdlog.
//
// Everything travels as the envelope of transport/envelope.idl: a sequence number and an opaque
// payload (a serialized protobuf message). The layer knows nothing of the payload.
//
// Thread safety: Cyclone's entities are thread-safe; these wrappers add no state of their own
// beyond the handle, except Reader::Take's scratch arrays, so one Reader is taken from by one
// thread at a time. WaitSet::Wake may be called from any thread.
// Invariants: a wrapper holds a valid handle (> 0) or none (0, after a move); a Domain outlives
// every participant created in it (participants keep it alive through a shared_ptr).
#pragma once

#include <array>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include <dds/dds.h>

#include "bp/status.h"

namespace bp::dds {

/// Converts a Cyclone return code to a Status; `what` names the failed operation.
Status FromRetcode(dds_return_t rc, std::string_view what);

/// Routes Cyclone's log (fatal, error, warning, info) into spdlog's default logger. Process-wide
/// and idempotent.
void RouteCycloneLogToSpdlog();

/// An owned Cyclone entity handle, deleted on destruction. Move-only.
class Entity {
 public:
  Entity() = default;
  explicit Entity(dds_entity_t handle) : handle_(handle) {}
  ~Entity() { Reset(); }
  Entity(Entity&& other) noexcept : handle_(other.handle_) { other.handle_ = 0; }
  Entity& operator=(Entity&& other) noexcept;
  Entity(const Entity&) = delete;
  Entity& operator=(const Entity&) = delete;
  /// The handle (0 if none).
  dds_entity_t get() const { return handle_; }
  /// Deletes the entity (and Cyclone deletes its children).
  void Reset();

 private:
  dds_entity_t handle_ = 0;
};

/// An owned QoS object.
class Qos {
 public:
  Qos() : qos_(dds_create_qos()) {}
  ~Qos() { dds_delete_qos(qos_); }
  Qos(const Qos&) = delete;
  Qos& operator=(const Qos&) = delete;
  /// The raw QoS, to set policies with dds_qset_*.
  dds_qos_t* get() const { return qos_; }

 private:
  dds_qos_t* qos_;
};

/// A DDS domain created with an explicit Cyclone XML configuration and shared by every
/// participant of this process on that domain id.
class Domain {
 public:
  /// Creates the domain, or returns the one this process already has for id. xml: Cyclone
  /// configuration text ("" = Cyclone's default, which honours CYCLONEDDS_URI). A second caller
  /// with a different xml for a live domain gets FailedPrecondition-like InvalidArgument.
  static Status Acquire(uint32_t id, const std::string& xml, std::shared_ptr<Domain>* out);
  ~Domain();
  Domain(const Domain&) = delete;
  Domain& operator=(const Domain&) = delete;
  /// The domain id.
  uint32_t id() const { return id_; }

 private:
  Domain(uint32_t id, dds_entity_t handle, std::string xml)
      : id_(id), handle_(handle), xml_(std::move(xml)) {}
  uint32_t id_;
  dds_entity_t handle_;
  std::string xml_;
};

/// A participant with a publisher and a subscriber in one partition.
class Participant {
 public:
  /// Joins domain id (created with xml if this process has not yet) in partition ("" = the
  /// default partition).
  static Status Create(uint32_t domain, const std::string& xml, const std::string& partition,
                       std::unique_ptr<Participant>* out);
  /// Participant handle.
  dds_entity_t get() const { return participant_.get(); }
  /// Publisher handle (carries the partition).
  dds_entity_t publisher() const { return publisher_.get(); }
  /// Subscriber handle (carries the partition).
  dds_entity_t subscriber() const { return subscriber_.get(); }
  /// Creates (or finds) the envelope topic called name.
  Status CreateTopic(const std::string& name, dds_entity_t* out_topic);

 private:
  Participant() = default;
  std::shared_ptr<Domain> domain_;
  Entity participant_;
  Entity publisher_;
  Entity subscriber_;
};

/// A DDS entity's GUID (network-wide identity; an instance handle is only local).
using Guid = std::array<uint8_t, 16>;

/// One envelope as received: sequence number, payload bytes, and its DDS sample info.
struct Received {
  uint64_t seq = 0;
  std::span<const uint8_t> payload;
  const dds_sample_info_t* info = nullptr;
};

/// A writer of envelopes on one topic.
class Writer {
 public:
  Writer() = default;
  /// Creates a writer for topic with qos (the qos's max_blocking_time bounds Write), in the
  /// participant's partition or, if partition is given, in a publisher of that partition.
  static Status Create(const Participant& participant, dds_entity_t topic, const Qos& qos,
                       Writer* out, const std::string* partition = nullptr);
  /// Publishes one envelope. DeadlineExceeded if the readers' resource limits kept it blocked
  /// beyond the writer's max_blocking_time (the envelope was not sent).
  Status Write(uint64_t seq, std::string_view payload);
  /// Readers currently matched.
  uint32_t MatchedReaders() const;
  /// Waits until at least n readers are matched. DeadlineExceeded on timeout.
  Status WaitForReaders(uint32_t n, std::chrono::milliseconds timeout) const;
  /// Waits until every matched reliable reader has acknowledged everything written.
  Status WaitForAcks(std::chrono::milliseconds timeout) const;
  dds_entity_t get() const { return writer_.get(); }

 private:
  Entity publisher_;  // its own publisher, when created in another partition (deleted last)
  Entity writer_;
};

/// Deletes writers on a thread of its own. Why: under load, Cyclone's dds_delete of a writer was
/// seen to wait until the deleting thread itself made progress elsewhere (the daemon's loop hung
/// in it; done on another thread, the same delete completes while the loop goes on). The reaper
/// must be destroyed before the participant of the writers it holds; its destructor deletes what
/// is left and joins.
class Reaper {
 public:
  Reaper();
  ~Reaper();
  Reaper(const Reaper&) = delete;
  Reaper& operator=(const Reaper&) = delete;
  /// Takes the writer; it is deleted soon, on the reaper's thread.
  void Delete(Writer&& writer);

 private:
  std::mutex mutex_;
  std::condition_variable wake_;
  std::vector<Writer> pending_;
  bool stop_ = false;
  std::thread thread_;
};

/// The liveliness of the writers a reader matched, as Cyclone reports it change by change
/// (its liveliness_changed listener). A writer becomes alive when it matches or asserts its
/// liveliness again, and stops being alive when its liveliness lease expires (its process died or
/// hung) or when it is deleted. Thread-safe: Cyclone's listener thread records, the owner takes.
/// It must outlive the reader it was given to.
class WriterLiveliness {
 public:
  struct Change {
    dds_instance_handle_t writer = 0;
    bool alive = false;
  };
  /// Called (on Cyclone's thread, under the tracker's lock: keep it short) after each recorded
  /// change, e.g. to wake a waitset. nullptr stops the calls.
  void SetOnChange(std::function<void()> on_change);
  /// Moves the changes recorded since the last call into *out, oldest first.
  void TakeChanges(std::vector<Change>* out);

 private:
  friend class Reader;
  static void OnLivelinessChanged(dds_entity_t reader, dds_liveliness_changed_status_t status,
                                  void* arg);
  std::mutex mutex_;
  std::vector<Change> changes_;
  std::function<void()> on_change_;
};

/// A reader of envelopes on one topic.
class Reader {
 public:
  Reader() = default;
  /// Creates a reader for topic with qos; with liveliness, it records its writers' liveliness.
  /// In the participant's partition or, if partition is given, in a subscriber of that one.
  static Status Create(const Participant& participant, dds_entity_t topic, const Qos& qos,
                       Reader* out, WriterLiveliness* liveliness = nullptr,
                       const std::string* partition = nullptr);
  /// Takes up to max envelopes and calls f on each valid one (loaned: the payload is valid only
  /// during the call). Returns the number of valid envelopes, or a negative Status via out.
  Status Take(size_t max, const std::function<void(const Received&)>& f, size_t* out_taken);
  /// Writers currently matched.
  uint32_t MatchedWriters() const;
  /// Instance handles of the matched writers.
  std::vector<dds_instance_handle_t> MatchedWriterHandles() const;
  /// The GUID of a matched writer; all zeros if it is not (or no longer) matched.
  Guid MatchedWriterGuid(dds_instance_handle_t writer) const;
  /// Waits until at least n writers are matched. DeadlineExceeded on timeout.
  Status WaitForWriters(uint32_t n, std::chrono::milliseconds timeout) const;
  dds_entity_t get() const { return reader_.get(); }

 private:
  Entity subscriber_;  // its own subscriber, when created in another partition (deleted last)
  Entity reader_;
  std::vector<void*> samples_;
  std::vector<dds_sample_info_t> infos_;
};

/// Waits for data on readers, or for Wake().
class WaitSet {
 public:
  WaitSet() = default;
  /// Creates a waitset in participant.
  static Status Create(const Participant& participant, WaitSet* out);
  /// Wakes when reader has data.
  Status Attach(const Reader& reader);
  /// Waits until data is available, Wake() is called, or timeout passes. *out_triggered is the
  /// number of triggered conditions (0 on timeout). The wake flag is cleared.
  Status Wait(std::chrono::nanoseconds timeout, int* out_triggered);
  /// Wakes a waiting thread (thread-safe).
  void Wake();

 private:
  Entity waitset_;
  std::vector<Entity> conditions_;
};

}  // namespace bp::dds
