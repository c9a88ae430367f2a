#include "bp/client/update_publisher.h"

#include <algorithm>
#include <cmath>
#include <thread>

#include "kept_objects.h"

namespace bp::client {
namespace {

template <class R>
void CopyCorner(const R& values, size_t at, uint32_t dim, std::array<double, 6>* out) {
  for (uint32_t a = 0; a < dim; ++a)
    (*out)[a] = static_cast<double>(values.Get(static_cast<int>(at + a)));
}

}  // namespace

UpdatePublisher::UpdatePublisher() : kept_(std::make_unique<KeptObjects>()) {}
UpdatePublisher::~UpdatePublisher() = default;

size_t UpdatePublisher::kept_objects() const { return kept_->size(); }

Status UpdatePublisher::Create(Connection& connection, uint32_t producer,
                               std::chrono::milliseconds write_timeout,
                               std::unique_ptr<UpdatePublisher>* out) {
  PublisherOptions options;
  options.write_timeout = write_timeout;
  return Create(connection, producer, options, out);
}

Status UpdatePublisher::Create(Connection& connection, uint32_t producer,
                               const PublisherOptions& options,
                               std::unique_ptr<UpdatePublisher>* out) {
  if (producer == 0 || producer > 0xFFFF) {
    return Status(StatusCode::kInvalidArgument,
                  "producer id " + std::to_string(producer) + " is outside 1..65535");
  }
  if (options.restate_batch_items == 0) {
    return Status(StatusCode::kInvalidArgument, "restate_batch_items must be at least 1");
  }
  std::unique_ptr<UpdatePublisher> p(new UpdatePublisher());
  p->producer_ = producer;
  p->options_ = options;
  dds::Qos qos;
  qos::UpdatesWriter(qos.get(), options.write_timeout, options.liveliness_lease);
  if (Status s = connection.CreateWriter(TopicId::kUpdates, qos, &p->writer_); !s.ok()) {
    return s;
  }
  if (options.restate_on_restart) {
    dds::Qos status_qos;
    qos::StatusReader(status_qos.get(), 16);
    if (Status s = connection.CreateReader(TopicId::kStatus, status_qos, &p->status_); !s.ok()) {
      return s;
    }
  }
  *out = std::move(p);
  return Status::Ok();
}

Status UpdatePublisher::WaitForDaemon(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  if (Status s = writer_.WaitForReaders(1, timeout); !s.ok()) return s;
  if (!options_.restate_on_restart) return Status::Ok();
  while (true) {
    if (Status s = Maintain(); !s.ok()) return s;
    if (epoch_ != 0) return Status::Ok();
    if (std::chrono::steady_clock::now() >= deadline) {
      return Status(StatusCode::kDeadlineExceeded,
                    "waiting for the daemon's status report (its epoch)");
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

Status UpdatePublisher::Stamp(wire::UpdateBatch* batch) {
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

Status UpdatePublisher::Publish(wire::UpdateBatch* batch) {
  if (options_.restate_on_restart) {
    if (Status s = Maintain(); !s.ok()) return s;
  }
  if (Status s = Stamp(batch); !s.ok()) return s;
  if (options_.restate_on_restart) {
    if (epoch_ == 0) published_before_epoch_ = true;
    Keep(*batch);
  }
  return Status::Ok();
}

Status UpdatePublisher::PublishRaw(std::string_view payload) {
  Status s = writer_.Write(seq_ + 1, payload);
  if (s.ok()) ++seq_;
  return s;
}

void UpdatePublisher::Keep(const wire::UpdateBatch& batch) {
  using Record = KeptObjects::Record;
  // The daemon's order: erases, inserts, updates.
  for (uint64_t id : batch.erases()) kept_->Erase(id);
  if (batch.dim() >= 1 && batch.dim() <= 6) dim_ = batch.dim();
  frame_ = batch.frame();
  const uint32_t k = dim_;
  auto corners = [&](const wire::BoxArray& boxes, size_t i, Record* kept) {
    const size_t at = i * k;
    if (boxes.lo32_size() > 0) {
      if (static_cast<size_t>(boxes.lo32_size()) < at + k ||
          static_cast<size_t>(boxes.hi32_size()) < at + k) {
        return false;
      }
      CopyCorner(boxes.lo32(), at, k, &kept->lo);
      CopyCorner(boxes.hi32(), at, k, &kept->hi);
    } else {
      if (static_cast<size_t>(boxes.lo64_size()) < at + k ||
          static_cast<size_t>(boxes.hi64_size()) < at + k) {
        return false;
      }
      CopyCorner(boxes.lo64(), at, k, &kept->lo);
      CopyCorner(boxes.hi64(), at, k, &kept->hi);
    }
    // The daemon refuses a box that is not finite or inverted: keep the last one it took.
    for (uint32_t a = 0; a < k; ++a) {
      if (!std::isfinite(kept->lo[a]) || !std::isfinite(kept->hi[a]) || kept->lo[a] > kept->hi[a]) {
        return false;
      }
    }
    return true;
  };
  const wire::BoxArray& inserts = batch.inserts();
  for (int i = 0; i < inserts.ids_size(); ++i) {
    // An insert of an id still kept (this batch's erases are already applied) is refused as a
    // duplicate.
    if (kept_->Contains(inserts.ids(i))) continue;
    Record kept;
    kept.id = inserts.ids(i);
    if (!corners(inserts, static_cast<size_t>(i), &kept)) continue;  // refused by the daemon too
    if (inserts.static_flags_size() > i) kept.is_static = inserts.static_flags(i);
    if (inserts.category_size() > i) kept.category = inserts.category(i);
    if (inserts.mask_size() > i) kept.mask = inserts.mask(i);
    kept.has_attributes =
        inserts.static_flags_size() > 0 || inserts.category_size() > 0 || inserts.mask_size() > 0;
    kept_->Insert(kept);
  }
  const wire::BoxArray& updates = batch.updates();
  kept_->ForEachFound({updates.ids().data(), static_cast<size_t>(updates.ids_size())},
                      [&](size_t i, Record* kept) {
                        if (kept == nullptr) return;  // unknown to us: the daemon refuses it too
                        Record moved = *kept;
                        if (corners(updates, i, &moved)) *kept = moved;
                      });
}

Status UpdatePublisher::Maintain() {
  if (!options_.restate_on_restart) return Status::Ok();
  size_t taken = 0;
  Status s = status_.Take(
      64,
      [&](const dds::Received& r) {
        if (!status_msg_.ParseFromArray(r.payload.data(), static_cast<int>(r.payload.size()))) {
          return;
        }
        const uint64_t epoch = status_msg_.epoch();
        if (epoch == 0) return;
        if (epoch == epoch_) {
          // A report read before comes again when the status reader matches again.
          if (r.seq <= status_seq_) return;
          status_seq_ = r.seq;
          ReadLimits();
          // This daemon erased our objects (we hung or were cut off longer than its lease).
          for (uint32_t p : status_msg_.expired_producers()) {
            if (p == producer_) restate_due_ = true;
          }
          // It may have missed some of our batches: restate, unless our last restate began
          // after we had read the report that raised the request (that restate answers it).
          for (const auto& request : status_msg_.resync()) {
            if (request.producer() == producer_ && request.raised() > answered_upto_) {
              restate_due_ = true;
            }
          }
          return;
        }
        if (std::find(retired_epochs_.begin(), retired_epochs_.end(), epoch) !=
            retired_epochs_.end()) {
          return;  // a late report of a daemon already replaced
        }
        if (status_msg_.health() == wire::STOPPING) {
          retired_epochs_.push_back(epoch);
          return;
        }
        // A daemon not seen before. The first one needs a restate only if objects were
        // published before its epoch was known (they may have gone to an earlier daemon).
        if (epoch_ != 0) retired_epochs_.push_back(epoch_);
        if (epoch_ != 0 || published_before_epoch_) restate_due_ = true;
        epoch_ = epoch;
        status_seq_ = r.seq;
        answered_upto_ = 0;
        ReadLimits();
      },
      &taken);
  if (!s.ok()) return s;
  if (retired_epochs_.size() > 64) retired_epochs_.erase(retired_epochs_.begin());
  // Not into the void: a restate written before the writer matched the (new) daemon's reader
  // would be lost. It waits for a match (and the daemon asks again if it still misses it).
  if (restate_due_ && writer_.MatchedReaders() > 0) return Restate();
  return Status::Ok();
}

void UpdatePublisher::ReadLimits() {
  daemon_max_items_ = status_msg_.max_batch_items();
  daemon_max_bytes_ = status_msg_.max_batch_bytes();
}

Status UpdatePublisher::Restate() {
  const uint32_t k = dim_;
  if (k == 0) {  // nothing was ever published: the daemon holds nothing of ours
    restate_due_ = false;
    return Status::Ok();
  }
  // Batches the daemon accepts: at most its max_batch_items, and within its max_batch_bytes (an
  // object costs at most 8 + 2 * 6 * 8 bytes of id and corners plus 21 of attributes).
  uint64_t items = options_.restate_batch_items;
  if (daemon_max_items_ > 0) items = std::min(items, daemon_max_items_);
  if (daemon_max_bytes_ > 0) {
    constexpr uint64_t kItemBytes = 128, kBatchBytes = 256;
    items = std::min(items, daemon_max_bytes_ > kBatchBytes + kItemBytes
                                ? (daemon_max_bytes_ - kBatchBytes) / kItemBytes
                                : uint64_t{1});
  }
  const uint64_t run = seq_ + 1;  // the batch_seq of the run's first batch
  answered_upto_ = status_seq_;
  size_t next = 0;  // the next kept record to restate
  do {  // at least one batch: an empty restate erases what the daemon still holds of ours
    restate_batch_.Clear();
    restate_batch_.set_restate(true);
    restate_batch_.set_restate_run(run);
    restate_batch_.set_dim(k);
    restate_batch_.set_frame(frame_);
    wire::BoxArray* inserts = restate_batch_.mutable_inserts();
    bool attributes = false;
    const size_t from = next;
    for (uint64_t n = 0; n < items && next < kept_->size(); ++n, ++next) {
      const KeptObjects::Record& kept = kept_->at(next);
      inserts->add_ids(kept.id);
      for (uint32_t a = 0; a < k; ++a) inserts->add_lo64(kept.lo[a]);
      for (uint32_t a = 0; a < k; ++a) inserts->add_hi64(kept.hi[a]);
      attributes = attributes || kept.has_attributes;
    }
    if (attributes) {  // every attribute array is empty or complete
      for (size_t j = from; j != next; ++j) {
        const KeptObjects::Record& kept = kept_->at(j);
        inserts->add_static_flags(kept.is_static);
        inserts->add_category(kept.category);
        inserts->add_mask(kept.mask);
      }
    }
    // The last one closes a frame, so the restored objects' pairs are published even when
    // the producer rests (Maintain) and no other batch follows.
    restate_batch_.set_end_of_frame(next == kept_->size());
    if (Status s = Stamp(&restate_batch_); !s.ok()) return s;  // due again next time
  } while (next < kept_->size());
  restate_due_ = false;
  ++restates_;
  return Status::Ok();
}

}  // namespace bp::client
