#include "bp/client/overlap_view.h"

#include <algorithm>
#include <random>

#include "bp/client/batch_builder.h"

namespace bp::client {

void OverlapView::Lose(std::string why) {
  if (synced_) ++resyncs_;
  synced_ = false;
  building_ = false;
  pairs_.clear();
  pending_.clear();
  last_loss_ = std::move(why);
}

bool OverlapView::Apply(const wire::EventBatch& part) {
  const bool was_synced = synced_;
  const bool first = !started_;
  started_ = true;
  if (part.epoch() != epoch_) {
    if (!first) {
      ++restarts_;
      Lose("the daemon restarted (epoch changed)");
    }
    epoch_ = part.epoch();
  } else if (part.sequence() != last_seq_ + 1) {
    ++gaps_;
    Lose("gap: sequence " + std::to_string(last_seq_) + " then " + std::to_string(part.sequence()));
  }
  last_seq_ = part.sequence();

  if (!synced_) {
    if (part.snapshot()) {
      if (part.part() == 0) {
        building_ = true;
        building_frame_ = part.frame();
        pending_.clear();
      }
      if (building_ && part.frame() == building_frame_) {
        for (int i = 0; i + 1 < part.snapshot_pairs_size(); i += 2)
          pending_.insert(Key(part.snapshot_pairs(i), part.snapshot_pairs(i + 1)));
        if (part.last_part()) {
          pairs_.swap(pending_);
          pending_.clear();
          building_ = false;
          synced_ = true;
          mid_frame_ = false;
          frame_ = part.frame();
          ++snapshots_;
        }
      }
    }
    // Just lost it, or never had it and no snapshot is arriving: ask now.
    return !synced_ && !building_ && (first || was_synced);
  }
  if (part.snapshot()) return false;  // another subscriber's; the set already matches
  for (int i = 0; i + 1 < part.uncollide_size(); i += 2) {
    if (pairs_.erase(Key(part.uncollide(i), part.uncollide(i + 1))) == 0) {
      ++contradictions_;
      Lose("frame " + std::to_string(part.frame()) + " uncollides a pair the view does not hold");
      return true;
    }
  }
  for (int i = 0; i + 1 < part.collide_size(); i += 2) {
    if (!pairs_.insert(Key(part.collide(i), part.collide(i + 1))).second) {
      ++contradictions_;
      Lose("frame " + std::to_string(part.frame()) + " collides a pair the view already holds");
      return true;
    }
  }
  // Between the parts of a multi-part frame the set is neither frame's: not synced() then.
  mid_frame_ = !part.last_part();
  if (part.last_part()) frame_ = part.frame();
  return false;
}

std::vector<std::pair<uint64_t, uint64_t>> OverlapView::SortedPairs() const {
  std::vector<std::pair<uint64_t, uint64_t>> out(pairs_.begin(), pairs_.end());
  std::sort(out.begin(), out.end());
  return out;
}

Status SnapshotRequester::Create(Connection& connection, std::unique_ptr<SnapshotRequester>* out) {
  std::unique_ptr<SnapshotRequester> r(new SnapshotRequester());
  dds::Qos qos;
  qos::RequestsWriter(qos.get());
  if (Status s = connection.CreateWriter(TopicId::kRequests, qos, &r->writer_); !s.ok()) {
    return s;
  }
  std::random_device random;
  r->requester_ = uint64_t{random()} << 32 | random();
  *out = std::move(r);
  return Status::Ok();
}

Status SnapshotRequester::Request(const std::string& reason, uint64_t interest) {
  msg_.Clear();
  msg_.set_version(wire::SCHEMA_VERSION_1);
  msg_.set_requester(requester_);
  msg_.set_reason(reason);
  msg_.set_interest(interest);
  buffer_.clear();
  msg_.SerializeToString(&buffer_);
  return writer_.Write(++seq_, buffer_);
}

}  // namespace bp::client
