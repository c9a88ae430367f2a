// MergedView and ShardedSubscriber (bp/client/sharded.h): one exact event stream out of the
// streams of a world's shards.
#include <algorithm>
#include <thread>

#include "bp/client/sharded.h"

namespace bp::client {
namespace {

void Append(std::vector<uint64_t>* to, const google::protobuf::RepeatedField<uint64_t>& from) {
  to->insert(to->end(), from.begin(), from.end());
}

}  // namespace

MergedView::MergedView(size_t shards) : shards_(shards) {}

void MergedView::Lose(Shard& s, std::string why) {
  if (s.synced) ++s.resyncs;
  s.synced = false;
  s.building = false;
  s.building_pairs.clear();
  s.has_base = false;
  s.base.clear();
  s.acc_uncollide.clear();
  s.acc_collide.clear();
  s.net.clear();
  // Superseded by the snapshot that will follow: it replaces the shard's whole set.
  s.queue.clear();
  s.newest = 0;
  s.resyncing = false;
  s.last_loss = std::move(why);
}

void MergedView::Push(Shard& s, uint64_t key, uint64_t sent_ns, bool reset,
                      std::vector<uint64_t> uncollide, std::vector<uint64_t> collide) {
  Entry e;
  e.key = key;
  e.sent_ns = sent_ns;
  s.newest = std::max(s.newest, key);
  e.reset = reset;
  e.uncollide = std::move(uncollide);
  e.collide = std::move(collide);
  s.queue.push_back(std::move(e));
}

bool MergedView::Apply(size_t index, const wire::EventBatch& part) {
  Shard& s = shards_[index];
  const bool was_synced = s.synced;
  const bool first = !s.started;
  s.started = true;
  if (part.epoch() != s.epoch) {
    if (std::find(s.retired.begin(), s.retired.end(), part.epoch()) != s.retired.end()) {
      return false;  // a late part of a daemon already replaced
    }
    if (!first) {
      ++s.restarts;
      Lose(s, "the shard's daemon restarted (epoch changed)");
      s.retired.push_back(s.epoch);
      if (s.retired.size() > 16) s.retired.erase(s.retired.begin());
    }
    s.epoch = part.epoch();
  } else if (part.sequence() != s.last_seq + 1) {
    Lose(s, "gap: sequence " + std::to_string(s.last_seq) + " then " +
                std::to_string(part.sequence()));
  }
  s.last_seq = part.sequence();

  // A snapshot is taken while unsynced; while synced only when it is of a frame newer than any
  // the shard delivered (asked for because the shard lagged: parts it published while this
  // reader was cut off from it never arrive, so no gap shows). Others' snapshots are skipped.
  if (part.snapshot() && part.part() == 0 &&
      (!s.synced || (part.source_producer() != 0 && part.source_frame() > s.newest))) {
    s.building = true;
    s.building_frame = part.frame();
    s.building_pairs.clear();
  }
  if (!s.synced && !part.snapshot()) return !s.building && (first || was_synced);
  if (part.snapshot()) {
    if (!s.building || part.frame() != s.building_frame) return false;
    Append(&s.building_pairs, part.snapshot_pairs());
    if (!part.last_part()) return false;
    s.building = false;
    s.synced = true;
    s.acc_uncollide.clear();  // contained in the snapshot
    s.acc_collide.clear();
    s.net.clear();
    s.resyncing = false;
    s.has_base = false;
    s.base.clear();
    if (part.source_producer() != 0 && !part.resyncing()) {
      // The set as of that producer frame (plus what frames closed since by no frame end
      // changed, which belongs to the next one).
      Push(s, part.source_frame(), 0, true, {}, std::move(s.building_pairs));
    } else {
      // No producer frame closed yet (a daemon just started), or the daemon waits for a
      // producer's restate: the base of the next good frame.
      s.has_base = true;
      s.base = std::move(s.building_pairs);
    }
    s.building_pairs.clear();
    return false;
  }
  Append(&s.acc_uncollide, part.uncollide());
  Append(&s.acc_collide, part.collide());
  // A frame while the daemon missed batches of a producer, or one its restate closed (the
  // frames between the shard's last good one and this may be missing): the next good frame
  // folds the frames before it.
  if (part.resyncing() || part.restate()) s.resyncing = true;
  // A frame of the daemon's own (expiry, restate) or one while it missed batches of a producer
  // (its set may lack them until the restate) counts into the next good producer frame.
  if (!part.last_part()) return false;
  if (part.source_producer() == 0 || part.restate() || part.resyncing()) {
    FoldFrame(s);
    return false;
  }
  // A producer's frame end: the shard's state at that frame.
  if (s.has_base) {
    // Base plus the changes since: as a whole set.
    FoldFrame(s);
    PairSet set;
    for (size_t i = 0; i + 1 < s.base.size(); i += 2) set.insert(Key(s.base[i], s.base[i + 1]));
    for (const auto& [p, in] : s.net) {
      if (in) {
        set.insert(p);
      } else {
        set.erase(p);
      }
    }
    std::vector<uint64_t> flat;
    flat.reserve(set.size() * 2);
    for (const Pair& p : set) {
      flat.push_back(p.first);
      flat.push_back(p.second);
    }
    Push(s, part.source_frame(), part.source_sent_time_ns(), true, {}, std::move(flat));
    s.has_base = false;
    s.base.clear();
  } else if (s.net.empty()) {
    Push(s, part.source_frame(), part.source_sent_time_ns(), false, std::move(s.acc_uncollide),
         std::move(s.acc_collide));
    s.queue.back().fold = s.resyncing;
  } else {
    FoldFrame(s);
    std::vector<uint64_t> uncollide, collide;
    for (const auto& [p, in] : s.net) {
      std::vector<uint64_t>& to = in ? collide : uncollide;
      to.push_back(p.first);
      to.push_back(p.second);
    }
    Push(s, part.source_frame(), part.source_sent_time_ns(), false, std::move(uncollide),
         std::move(collide));
    s.queue.back().fold = s.resyncing;
  }
  s.net.clear();
  s.resyncing = false;
  s.acc_uncollide.clear();
  s.acc_collide.clear();
  return false;
}

void MergedView::FoldFrame(Shard& s) {
  // Within a frame every uncollide precedes every collide; a pair's changes over frames cancel
  // in pairs (in then out, or out then in).
  auto change = [&](uint64_t a, uint64_t b, bool in) {
    auto [it, fresh] = s.net.try_emplace(Key(a, b), in);
    if (!fresh && it->second != in) s.net.erase(it);
  };
  for (size_t i = 0; i + 1 < s.acc_uncollide.size(); i += 2) {
    change(s.acc_uncollide[i], s.acc_uncollide[i + 1], false);
  }
  for (size_t i = 0; i + 1 < s.acc_collide.size(); i += 2) {
    change(s.acc_collide[i], s.acc_collide[i + 1], true);
  }
  s.acc_uncollide.clear();
  s.acc_collide.clear();
}

bool MergedView::NextKey(uint64_t* key) const {
  // The smallest frame some shard has delivered and not merged; a shard whose next entry is a
  // snapshot of a later frame cannot tell the frames before it: merge up to that one.
  uint64_t next = UINT64_MAX, reset = 0;
  for (const Shard& s : shards_) {
    if (!s.synced || s.queue.empty()) return false;
    next = std::min(next, s.queue.front().key);
    if (s.queue.front().reset || s.queue.front().fold) {
      reset = std::max(reset, s.queue.front().key);
    }
  }
  next = std::max(next, reset);
  if (emitted_) next = std::max(next, frame_ + 1);
  // Every shard must have delivered that frame (or a later one).
  for (const Shard& s : shards_) {
    if (s.queue.back().key < next) return false;
  }
  *key = next;
  return true;
}

std::vector<size_t> MergedView::waiting_for() const {
  uint64_t newest = 0;
  for (const Shard& s : shards_) {
    if (!s.queue.empty()) newest = std::max(newest, s.queue.back().key);
  }
  std::vector<size_t> out;
  for (size_t i = 0; i < shards_.size(); ++i) {
    const Shard& s = shards_[i];
    if (!s.synced || s.queue.empty() || s.queue.back().key < newest) out.push_back(i);
  }
  if (newest == 0) out.clear();  // nothing is due yet
  return out;
}

void MergedView::ApplyEntry(size_t index, const Entry& e,
                            std::unordered_map<Pair, bool, PairHash>* touched) {
  Shard& s = shards_[index];
  std::string contradiction;
  auto add = [&](const Pair& p) {
    if (!s.held.insert(p).second) {
      contradiction = "collides a pair it already holds";
      return;
    }
    auto [it, fresh] = counts_.try_emplace(p, 0);
    touched->try_emplace(p, !fresh);
    ++it->second;
  };
  auto remove = [&](const Pair& p) {
    if (s.held.erase(p) == 0) {
      contradiction = "uncollides a pair it does not hold";
      return;
    }
    auto it = counts_.find(p);
    touched->try_emplace(p, true);
    if (--it->second == 0) counts_.erase(it);
  };
  if (e.reset) {
    PairSet set;
    for (size_t i = 0; i + 1 < e.collide.size(); i += 2)
      set.insert(Key(e.collide[i], e.collide[i + 1]));
    std::vector<Pair> gone;
    for (const Pair& p : s.held) {
      if (set.count(p) == 0) gone.push_back(p);
    }
    for (const Pair& p : gone) remove(p);
    for (const Pair& p : set) {
      if (s.held.count(p) == 0) add(p);
    }
    return;
  }
  for (size_t i = 0; i + 1 < e.uncollide.size(); i += 2)
    remove(Key(e.uncollide[i], e.uncollide[i + 1]));
  for (size_t i = 0; i + 1 < e.collide.size(); i += 2) add(Key(e.collide[i], e.collide[i + 1]));
  if (!contradiction.empty()) {
    // A correct daemon never sends one: resync the shard from a snapshot.
    ++contradictions_;
    Lose(s, "frame " + std::to_string(e.key) + " " + contradiction);
  }
}

bool MergedView::Next(MergedFrame* out) {
  uint64_t key = 0;
  if (!NextKey(&key)) return false;
  std::unordered_map<Pair, bool, PairHash> touched;  // pair -> held before this frame
  uint64_t sent_ns = 0;
  for (size_t i = 0; i < shards_.size(); ++i) {
    Shard& s = shards_[i];
    while (!s.queue.empty() && s.queue.front().key <= key) {
      Entry e = std::move(s.queue.front());
      s.queue.pop_front();
      if (e.key == key) sent_ns = std::max(sent_ns, e.sent_ns);
      ApplyEntry(i, e, &touched);  // may clear the queue (a contradiction)
    }
  }
  out->frame = key;
  out->sent_time_ns = sent_ns;
  out->snapshot = !emitted_;
  out->skipped = emitted_ && key > frame_ + 1 ? key - frame_ - 1 : 0;
  out->uncollide.clear();
  out->collide.clear();
  std::vector<Pair> unc, col;
  if (out->snapshot) {
    col.reserve(counts_.size());
    for (const auto& [p, n] : counts_) col.push_back(p);
  } else {
    for (const auto& [p, before] : touched) {
      const bool now = counts_.count(p) != 0;
      if (before && !now) unc.push_back(p);
      if (!before && now) col.push_back(p);
    }
  }
  std::sort(unc.begin(), unc.end());
  std::sort(col.begin(), col.end());
  for (const Pair& p : unc) {
    out->uncollide.push_back(p.first);
    out->uncollide.push_back(p.second);
  }
  for (const Pair& p : col) {
    out->collide.push_back(p.first);
    out->collide.push_back(p.second);
  }
  emitted_ = true;
  frame_ = key;
  return true;
}

std::vector<std::pair<uint64_t, uint64_t>> MergedView::SortedPairs() const {
  std::vector<Pair> out;
  out.reserve(counts_.size());
  for (const auto& [p, n] : counts_) out.push_back(p);
  std::sort(out.begin(), out.end());
  return out;
}

Status ShardedSubscriber::Create(Connection& connection, const ShardMap& map, int32_t depth,
                                 std::unique_ptr<ShardedSubscriber>* out, uint64_t interest) {
  std::unique_ptr<ShardedSubscriber> sub(new ShardedSubscriber(map.size()));
  sub->map_ = &map;
  sub->interest_ = interest;
  sub->connection_ = &connection;
  for (size_t s = 0; s < map.size(); ++s) {
    sub->connections_.push_back(
        connection.Scoped(transport::ShardPartition(connection.options().partition, map.name(s))));
    std::unique_ptr<EventSubscriber> events;
    std::unique_ptr<SnapshotRequester> requester;
    Status st = EventSubscriber::Create(*sub->connections_.back(), depth, &events, interest);
    if (st.ok()) st = SnapshotRequester::Create(*sub->connections_.back(), &requester);
    if (!st.ok()) return Status(st.code(), "shard '" + map.name(s) + "': " + st.message());
    sub->subscribers_.push_back(std::move(events));
    sub->requesters_.push_back(std::move(requester));
  }
  sub->asked_.assign(map.size(), std::chrono::steady_clock::time_point{});
  sub->waited_since_.assign(map.size(), std::chrono::steady_clock::time_point{});
  *out = std::move(sub);
  return Status::Ok();
}

Status ShardedSubscriber::WaitForDaemons(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  if (Status s = CheckShards(*connection_, *map_, timeout); !s.ok()) return s;
  for (size_t s = 0; s < subscribers_.size(); ++s) {
    const auto left = std::max(std::chrono::milliseconds(1),
                               std::chrono::duration_cast<std::chrono::milliseconds>(
                                   deadline - std::chrono::steady_clock::now()));
    // An interest's stream has no writer until the shard accepts the declaration.
    Status st = interest_ != 0 ? Status::Ok() : subscribers_[s]->WaitForDaemon(left);
    if (st.ok()) st = requesters_[s]->WaitForDaemon(left);
    if (!st.ok()) return Status(st.code(), "shard '" + map_->name(s) + "': " + st.message());
  }
  return Status::Ok();
}

void ShardedSubscriber::Feed(size_t s, const wire::EventBatch& part) {
  if (view_.Apply(s, part)) asked_[s] = {};  // just lost its sync: ask at once
}

Status ShardedSubscriber::Poll(std::chrono::milliseconds timeout, std::vector<MergedFrame>* out) {
  using Clock = std::chrono::steady_clock;
  const auto deadline = Clock::now() + timeout;
  for (;;) {
    bool any = false;
    for (size_t s = 0; s < subscribers_.size(); ++s) {
      parts_.clear();
      if (Status st = subscribers_[s]->Poll(std::chrono::milliseconds(0), &parts_); !st.ok()) {
        return st;
      }
      any = any || !parts_.empty();
      for (const wire::EventBatch& part : parts_) Feed(s, part);
    }
    // A shard without its sync is asked for a snapshot, again after a second without one; so is
    // one the merged stream has waited on for a second (what it published while this reader
    // was cut off from it never arrives: a snapshot of a newer frame tells).
    const auto now = Clock::now();
    std::vector<bool> waited(subscribers_.size(), false);
    for (size_t s : view_.waiting_for()) waited[s] = true;
    for (size_t s = 0; s < subscribers_.size(); ++s) {
      if (!waited[s]) {
        waited_since_[s] = {};
      } else if (waited_since_[s] == Clock::time_point{}) {
        waited_since_[s] = now;
      }
    }
    for (size_t s = 0; s < subscribers_.size(); ++s) {
      const bool lagging = waited_since_[s] != Clock::time_point{} &&
                           now - waited_since_[s] >= std::chrono::seconds(1);
      if (!(view_.wants_snapshot(s) || lagging) || now - asked_[s] < std::chrono::seconds(1)) {
        continue;
      }
      if (Status st = requesters_[s]->Request(lagging                ? "lagging"
                                              : view_.resyncs(s) > 0 ? "resync"
                                                                     : "join",
                                              interest_);
          !st.ok()) {
        return Status(st.code(), "shard '" + map_->name(s) + "': " + st.message());
      }
      asked_[s] = now;
      ++requests_;
    }
    MergedFrame frame;
    bool merged = false;
    while (view_.Next(&frame)) {
      out->push_back(std::move(frame));
      merged = true;
    }
    if (merged || now >= deadline) return Status::Ok();
    if (!any) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
}

}  // namespace bp::client

namespace bp::client {

Status ShardedInterestClient::Create(Connection& connection, const ShardMap& map,
                                     std::unique_ptr<ShardedInterestClient>* out) {
  std::unique_ptr<ShardedInterestClient> c(new ShardedInterestClient());
  c->map_ = &map;
  for (size_t s = 0; s < map.size(); ++s) {
    c->connections_.push_back(
        connection.Scoped(transport::ShardPartition(connection.options().partition, map.name(s))));
    std::unique_ptr<InterestClient> client;
    std::unique_ptr<StatusSubscriber> status;
    Status st = InterestClient::Create(*c->connections_.back(), &client);
    if (st.ok()) st = StatusSubscriber::Create(*c->connections_.back(), 64, &status);
    if (!st.ok()) return Status(st.code(), "shard '" + map.name(s) + "': " + st.message());
    c->clients_.push_back(std::move(client));
    c->status_.push_back(std::move(status));
  }
  *out = std::move(c);
  return Status::Ok();
}

Status ShardedInterestClient::WaitForDaemons(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (size_t s = 0; s < clients_.size(); ++s) {
    const auto left = std::max(std::chrono::milliseconds(1),
                               std::chrono::duration_cast<std::chrono::milliseconds>(
                                   deadline - std::chrono::steady_clock::now()));
    if (Status st = clients_[s]->WaitForDaemon(left); !st.ok()) {
      return Status(st.code(), "shard '" + map_->name(s) + "': " + st.message());
    }
  }
  return Status::Ok();
}

Status ShardedInterestClient::Declare(const wire::Interest& interest) {
  if (interest.leave_margin() != 0) {
    return Status(StatusCode::kInvalidArgument,
                  "interest " + std::to_string(interest.id()) +
                      ": a leave margin is not available across shards (an object's membership "
                      "of a region is kept by the shard it was in)");
  }
  for (size_t s = 0; s < clients_.size(); ++s) {
    if (Status st = clients_[s]->Declare(interest); !st.ok()) {
      return Status(st.code(), "shard '" + map_->name(s) + "': " + st.message());
    }
  }
  return Status::Ok();
}

Status ShardedInterestClient::Drop(uint64_t id) {
  Status first;
  for (size_t s = 0; s < clients_.size(); ++s) {
    Status st = clients_[s]->Drop(id);
    if (!st.ok() && first.ok())
      first = Status(st.code(), "shard '" + map_->name(s) + "': " + st.message());
  }
  return first;
}

Status ShardedInterestClient::Maintain() {
  std::vector<wire::InterestRefusal> refusals;
  for (size_t s = 0; s < clients_.size(); ++s) {
    reports_.clear();
    if (Status st = status_[s]->Poll(std::chrono::milliseconds(0), &reports_); !st.ok()) return st;
    for (const wire::DaemonStatus& r : reports_) {
      refusals.clear();
      if (Status st = clients_[s]->OnStatus(r, &refusals); !st.ok()) {
        return Status(st.code(), "shard '" + map_->name(s) + "': " + st.message());
      }
      if (!refusals.empty()) {
        return Status(
            StatusCode::kInvalidArgument,
            "shard '" + map_->name(s) + "' refused the interest: " + refusals.front().message());
      }
    }
  }
  return Status::Ok();
}

}  // namespace bp::client
