// broadphased's interests (daemon.h): declarations and drops, the streams of interest events and
// their snapshots, the owners' liveliness, and spot queries.
#include <algorithm>
#include <cinttypes>

#include "daemon.h"
#include <spdlog/spdlog.h>

#include "bp/transport/clock.h"

namespace bp::service {
namespace {

using Clock = std::chrono::steady_clock;

std::string Hex(uint64_t v) {
  char text[17];
  std::snprintf(text, sizeof(text), "%016" PRIx64, v);
  return text;
}

}  // namespace

uint64_t Daemon::WorldOverlaps() const {
  return host_->Overlaps() - (interests_ ? interests_->region_pairs() : 0);
}

void Daemon::ServeInterests() {
  if (interest_requests_.get() == 0) return;  // interests are off
  // One take per loop turn (bounded); later requests wait for the next turn.
  size_t taken = 0;
  Status s = interest_requests_.Take(
      kTakeBatch,
      [&](const dds::Received& r) { ServeInterestRequest(r.payload, r.info->publication_handle); },
      &taken);
  if (!s.ok()) spdlog::error("reading interest requests: {}", s.ToString());
  if (!pending_refusals_.empty()) {
    PublishStatus(wire::SERVING, false);
    pending_refusals_.clear();
  }
  interests_count_.store(interests_->size());
}

void Daemon::ServeInterestRequest(std::span<const uint8_t> payload, dds_instance_handle_t writer) {
  wire::InterestRequest& req = interest_request_;
  if (payload.size() > config_.limits.max_batch_bytes ||
      !req.ParseFromArray(payload.data(), static_cast<int>(payload.size()))) {
    RefuseInterest(0, 0,
                   "an interest request of " + std::to_string(payload.size()) +
                       " bytes is not a valid InterestRequest (or exceeds limits.max_batch_bytes)");
    return;
  }
  const uint64_t client = req.client();
  if (req.version() != wire::SCHEMA_VERSION_1) {
    RefuseInterest(client, 0,
                   "schema version " + std::to_string(req.version()) +
                       " is not supported (this daemon speaks version 1)");
    return;
  }
  if (client == 0) {
    RefuseInterest(0, 0, "client id 0 is not a client id (choose a random nonzero id)");
    return;
  }
  switch (req.request_case()) {
    case wire::InterestRequest::kDeclare: {
      const wire::Interest& in = req.declare();
      // A writer that is not alive (or gone) loses its interest to a new one that declares it
      // (validly: a refused declaration leaves it where it is).
      const uint64_t holder = interests_->Owner(in.id());
      bool take_over = false;
      if (holder != 0 && holder != writer) {
        const auto matched = interest_requests_.MatchedWriterHandles();
        take_over = interest_down_since_.contains(holder) ||
                    std::find(matched.begin(), matched.end(), holder) == matched.end();
      }
      if (Status st = interests_->Declare(in, writer, take_over); !st.ok()) {
        RefuseInterest(client, in.id(), st.message());
        return;
      }
      interests_changed_ = true;
      auto [stream, fresh] = streams_.try_emplace(in.id());
      if (fresh) {
        dds::Qos qos;
        transport::qos::EventsWriter(qos.get(), config_.dds.event_history,
                                     std::chrono::milliseconds(config_.dds.write_timeout_ms));
        // A subscriber whose reader matches the new writer late still receives the recent parts.
        dds_qset_durability(qos.get(), DDS_DURABILITY_TRANSIENT_LOCAL);
        // No latency budget: with one, Cyclone's asynchronous write can drop parts of a stream
        // that then stays quiet (docs/DESIGN.md, "Interests").
        const std::string partition = transport::InterestPartition(config_.dds.partition, in.id());
        if (Status st = connection_->CreateWriter(transport::TopicId::kEvents, qos,
                                                  &stream->second.writer, &partition);
            !st.ok()) {
          streams_.erase(stream);
          (void)interests_->Drop(in.id(), writer);
          RefuseInterest(client, in.id(), "its stream cannot be created: " + st.ToString());
          return;
        }
        stream->second.epoch = transport::RandomId();
        // The stream starts with a snapshot (the set before the interest's first frame: empty),
        // a point to sync from for a subscriber that reads it from the start.
        PublishInterestSnapshot(in.id());
      }
      spdlog::info("interest {} {} by client {}", Hex(in.id()), fresh ? "declared" : "changed",
                   Hex(client));
      return;
    }
    case wire::InterestRequest::kDrop: {
      const uint64_t id = req.drop();
      if (Status st = interests_->Drop(id, writer); !st.ok()) {
        RefuseInterest(client, id, "drop: " + st.message());
        return;
      }
      RetireStream(id);
      interests_changed_ = true;
      spdlog::info("interest {} dropped by client {}", Hex(id), Hex(client));
      return;
    }
    case wire::InterestRequest::kQuery:
      AnswerSpotQuery(client, writer, req.query());
      return;
    default:
      RefuseInterest(client, 0, "the request declares, drops or queries nothing");
      return;
  }
}

void Daemon::RefuseInterest(uint64_t client, uint64_t interest, std::string why) {
  ++interest_refusals_total_;
  spdlog::warn("refused from client {}: {}", Hex(client), why);
  if (pending_refusals_.size() >= config_.limits.max_rejections_reported) return;
  wire::InterestRefusal& r = pending_refusals_.emplace_back();
  r.set_client(client);
  r.set_interest(interest);
  r.set_message(std::move(why));
}

void Daemon::AnswerSpotQuery(uint64_t client, dds_instance_handle_t writer,
                             const wire::SpotQuery& query) {
  if (!reply_writers_.contains(client) &&
      reply_writers_.size() >= std::max<uint64_t>(config_.limits.max_interests, 1)) {
    RefuseInterest(client, 0,
                   "spot query " + std::to_string(query.query()) + ": " +
                       std::to_string(reply_writers_.size()) +
                       " clients already have a reply writer (limits.max_interests); they are "
                       "freed when their clients go away");
    return;
  }
  auto [reply, fresh] = reply_writers_.try_emplace(client);
  if (fresh) {
    dds::Qos qos;
    transport::qos::RepliesWriter(qos.get(),
                                  std::chrono::milliseconds(config_.dds.write_timeout_ms));
    const std::string partition = transport::ClientPartition(config_.dds.partition, client);
    if (Status st = connection_->CreateWriter(transport::TopicId::kReplies, qos,
                                              &reply->second.writer, &partition);
        !st.ok()) {
      reply_writers_.erase(reply);
      RefuseInterest(client, 0,
                     "spot query " + std::to_string(query.query()) +
                         ": its reply writer cannot be created: " + st.ToString());
      return;
    }
  }
  reply->second.owner = writer;
  std::string error;
  const size_t k = static_cast<size_t>(host_->Dimension());
  if (query.dim() != k) {
    error = "the box has dim " + std::to_string(query.dim()) + "; the daemon's dimension is " +
            std::to_string(k);
  } else if (Status st = host_->SpotQuery(
                 std::span<const double>(query.lo().data(), static_cast<size_t>(query.lo_size())),
                 std::span<const double>(query.hi().data(), static_cast<size_t>(query.hi_size())),
                 &spot_keys_);
             !st.ok()) {
    error = st.message();
  }
  if (!error.empty()) spot_keys_.clear();
  const size_t per_part = static_cast<size_t>(config_.limits.max_pairs_per_event_batch);
  const size_t parts = std::max<size_t>(1, (spot_keys_.size() + per_part - 1) / per_part);
  for (size_t part = 0, next = 0; part < parts; ++part) {
    answer_.Clear();
    answer_.set_version(wire::SCHEMA_VERSION_1);
    answer_.set_client(client);
    answer_.set_query(query.query());
    answer_.set_part(static_cast<uint32_t>(part));
    answer_.set_last_part(part + 1 == parts);
    answer_.set_frame(frames_.load());
    answer_.set_epoch(epoch_);
    answer_.set_error(error);
    const size_t end = std::min(spot_keys_.size(), next + per_part);
    answer_.mutable_keys()->Add(spot_keys_.begin() + static_cast<std::ptrdiff_t>(next),
                                spot_keys_.begin() + static_cast<std::ptrdiff_t>(end));
    next = end;
    buffer_.clear();
    Status st = answer_.SerializeToString(&buffer_)
                    ? reply->second.writer.Write(++reply->second.seq, buffer_)
                    : Status(StatusCode::kResourceExhausted, "the answer does not serialise");
    if (!st.ok()) {
      spdlog::error("spot query {} of client {}: part {} not delivered ({})", query.query(),
                    Hex(client), part, st.ToString());
    }
  }
  if (!error.empty()) {
    spdlog::warn("spot query {} of client {} refused: {}", query.query(), Hex(client), error);
  }
}

std::chrono::steady_clock::time_point Daemon::CheckInterestOwners() {
  if (interest_requests_.get() == 0) return Clock::time_point::max();
  interest_liveliness_->TakeChanges(&interest_liveliness_changes_);
  const auto now = Clock::now();
  for (const auto& change : interest_liveliness_changes_) {
    if (change.alive) {
      interest_down_since_.erase(change.writer);
    } else {
      interest_down_since_.try_emplace(change.writer, now);
    }
  }
  auto next = Clock::time_point::max();
  if (config_.producers.lease_s <= 0) {  // no lease: interests stay until dropped
    interest_down_since_.clear();
    return next;
  }
  if (interest_down_since_.empty()) return next;
  const auto lease = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(config_.producers.lease_s));
  for (auto it = interest_down_since_.begin(); it != interest_down_since_.end();) {
    const auto due = it->second + lease;
    if (now < due) {
      next = std::min(next, due);
      ++it;
      continue;
    }
    const dds_instance_handle_t writer = it->first;
    const std::vector<uint64_t> dropped = interests_->DropOwner(writer);
    for (uint64_t id : dropped) {
      RetireStream(id);
      dropped_now_.push_back(id);
      spdlog::info("interest {} dropped: its writer has not been alive for producers.lease_s",
                   Hex(id));
    }
    if (!dropped.empty()) interests_changed_ = true;
    for (auto r = reply_writers_.begin(); r != reply_writers_.end();) {
      if (r->second.owner != writer) {
        ++r;
        continue;
      }
      reaper_->Delete(std::move(r->second.writer));
      r = reply_writers_.erase(r);
    }
    it = interest_down_since_.erase(it);
  }
  interests_count_.store(interests_->size());
  if (!dropped_now_.empty()) {  // the report tells a client that is in fact alive
    PublishStatus(wire::SERVING, false);
    dropped_now_.clear();
  }
  return next;
}

void Daemon::PublishInterestEvents(uint64_t frame, uint32_t source_producer, uint64_t source_frame,
                                   uint64_t source_sent_ns, bool restate) {
  interests_changed_ = false;
  // A shard publishes every frame on every stream, empty or not: a merging subscriber needs
  // each shard's part of each frame. A daemon alone publishes only the frames with events.
  const bool every_frame = !shard_.name().empty();
  if (every_frame) {
    for (auto& [id, stream] : streams_) stream.published = false;
  }
  auto publish = [&](uint64_t id, Stream& stream, const std::vector<uint64_t>& uncollide,
                     const std::vector<uint64_t>& collide) {
    stream.published = true;
    ForEachEventPart(frame, uncollide, collide, [&] {
      event_msg_.set_interest(id);
      event_msg_.set_overlaps(interests_->SetSize(id));
      event_msg_.set_source_producer(source_producer);
      event_msg_.set_source_frame(source_frame);
      event_msg_.set_source_sent_time_ns(source_sent_ns);
      event_msg_.set_restate(restate);
      event_msg_.set_resyncing(!resync_.empty());
      WriteStreamPart(id, stream);
    });
  };
  interests_->ForEachDelta([&](uint64_t id, const InterestTable::Delta& delta) {
    const auto stream = streams_.find(id);
    if (stream != streams_.end()) publish(id, stream->second, delta.uncollide, delta.collide);
  });
  if (every_frame) {
    const std::vector<uint64_t> none;
    for (auto& [id, stream] : streams_) {
      if (!stream.published) publish(id, stream, none, none);
    }
  }
  if (!stop_.load()) (void)ServeInterestSnapshots();  // those that waited for this frame
}

void Daemon::RetireStream(uint64_t id) {
  const auto stream = streams_.find(id);
  if (stream == streams_.end()) return;
  reaper_->Delete(std::move(stream->second.writer));
  streams_.erase(stream);
}

std::chrono::steady_clock::time_point Daemon::ServeInterestSnapshots() {
  const auto interval = std::chrono::milliseconds(config_.limits.snapshot_interval_ms);
  const auto now = Clock::now();
  auto next = Clock::time_point::max();
  for (auto& [id, stream] : streams_) {
    // A changed interest's set is the last frame's only after the next frame: served then.
    if (!stream.snapshot_due || !interests_->SnapshotReady(id)) continue;
    if (stream.last_snapshot != Clock::time_point{} && now < stream.last_snapshot + interval) {
      next = std::min(next, stream.last_snapshot + interval);
    } else {
      PublishInterestSnapshot(id);
    }
  }
  return next;
}

void Daemon::PublishInterestSnapshot(uint64_t id) {
  const auto stream = streams_.find(id);
  if (stream == streams_.end()) return;
  Stream& st = stream->second;
  st.snapshot_due = false;
  st.last_snapshot = Clock::now();
  interests_->Snapshot(id, &snapshot_pairs_);
  ForEachSnapshotPart([&] {
    event_msg_.set_interest(id);
    event_msg_.set_overlaps(snapshot_pairs_.size());
    event_msg_.set_source_producer(last_source_producer_);
    event_msg_.set_source_frame(last_source_frame_);
    event_msg_.set_resyncing(!resync_.empty());
    WriteStreamPart(id, st);
  });
  spdlog::debug("interest {} snapshot of frame {}: {} pairs", Hex(id), frames_.load(),
                snapshot_pairs_.size());
}

void Daemon::WriteStreamPart(uint64_t id, Stream& st) {
  event_msg_.set_sequence(++st.seq);
  event_msg_.set_objects(host_->Objects());
  event_msg_.set_epoch(st.epoch);
  event_msg_.set_published_time_ns(transport::WallClockNs());
  buffer_.clear();
  Status s = event_msg_.SerializeToString(&buffer_)
                 ? st.writer.Write(event_msg_.sequence(), buffer_)
                 : Status(StatusCode::kResourceExhausted, "the part does not serialise");
  if (!s.ok()) {
    ++event_write_failures_;
    spdlog::error("interest {} frame {} {}part {}: not delivered ({}); its subscriber sees a gap",
                  Hex(id), event_msg_.frame(), event_msg_.snapshot() ? "snapshot " : "",
                  event_msg_.part(), s.ToString());
  }
}

}  // namespace bp::service
