// ShardedPublisher (bp/client/sharded.h): routes a producer's batches to the shards of a world.
#include <algorithm>
#include <array>
#include <bit>
#include <cfloat>
#include <cinttypes>
#include <cmath>
#include <thread>

#include "bp/client/sharded.h"

namespace bp::client {
namespace {

constexpr uint64_t kLocalIdLimit = uint64_t{1} << 48;

// The box a float daemon may hold for coordinate x given as a double: outward rounding makes
// it at most one float ulp larger. Routing with it never misses a block the daemon's box
// touches (a box routed to one shard too many costs only its copy).
double Down(double x) {
  if (!(std::fabs(x) <= static_cast<double>(FLT_MAX))) return x;  // refused by a float daemon
  float f = static_cast<float>(x);
  if (static_cast<double>(f) > x) f = std::nextafter(f, -FLT_MAX);
  return std::min(x, static_cast<double>(f));
}
double Up(double x) { return -Down(-x); }

bool UsesDouble(const wire::BoxArray& a) { return a.lo64_size() > 0 || a.hi64_size() > 0; }

// "" when array is well formed for k dimensions, else what is wrong with it.
std::string Malformed(const wire::BoxArray& a, int k, bool attributes_allowed) {
  const int n = a.ids_size();
  const bool f32 = a.lo32_size() > 0 || a.hi32_size() > 0, f64 = UsesDouble(a);
  if (f32 && f64) return "has both float and double coordinates";
  const int lo = f64 ? a.lo64_size() : a.lo32_size(), hi = f64 ? a.hi64_size() : a.hi32_size();
  if (lo != n * k || hi != n * k) {
    return "has " + std::to_string(n) + " ids but " + std::to_string(lo) + " lo and " +
           std::to_string(hi) + " hi coordinates (" + std::to_string(k) + " per id)";
  }
  for (int size : {a.static_flags_size(), a.category_size(), a.mask_size()}) {
    if (size == 0) continue;
    if (!attributes_allowed) return "carries attributes (only inserts may)";
    if (size != n) return "has attribute arrays of the wrong length (0 or one per id)";
  }
  return "";
}

struct Corners {
  std::array<double, 3> lo{}, hi{};
};

Corners Read(const wire::BoxArray& a, int i, int k) {
  Corners c;
  const int at = i * k;
  for (int d = 0; d < k; ++d) {
    if (UsesDouble(a)) {
      c.lo[size_t(d)] = a.lo64(at + d);
      c.hi[size_t(d)] = a.hi64(at + d);
    } else {
      c.lo[size_t(d)] = a.lo32(at + d);
      c.hi[size_t(d)] = a.hi32(at + d);
    }
  }
  return c;
}

// Appends box i of from (ids, corners) to to, in double precision when wide.
void CopyBox(const wire::BoxArray& from, int i, int k, bool wide, wire::BoxArray* to) {
  to->add_ids(from.ids(i));
  const int at = i * k;
  for (int d = 0; d < k; ++d) {
    if (wide) {
      to->add_lo64(UsesDouble(from) ? from.lo64(at + d) : from.lo32(at + d));
    } else {
      to->add_lo32(from.lo32(at + d));
    }
  }
  for (int d = 0; d < k; ++d) {
    if (wide) {
      to->add_hi64(UsesDouble(from) ? from.hi64(at + d) : from.hi32(at + d));
    } else {
      to->add_hi32(from.hi32(at + d));
    }
  }
}

size_t Items(const wire::UpdateBatch& b) {
  return static_cast<size_t>(b.inserts().ids_size() + b.updates().ids_size() + b.erases_size());
}

size_t Lowest(ShardMap::Mask mask) { return mask == 0 ? 0 : size_t(std::countr_zero(mask)); }

}  // namespace

Status CheckShards(Connection& connection, const ShardMap& map, std::chrono::milliseconds timeout,
                   std::string* coordinate) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::vector<wire::DaemonStatus> reports;
  for (size_t s = 0; s < map.size(); ++s) {
    const std::string partition =
        transport::ShardPartition(connection.options().partition, map.name(s));
    std::unique_ptr<Connection> scoped = connection.Scoped(partition);
    std::unique_ptr<StatusSubscriber> status;
    if (Status st = StatusSubscriber::Create(*scoped, 16, &status); !st.ok()) return st;
    bool heard = false;
    while (!heard) {
      const auto now = std::chrono::steady_clock::now();
      if (now >= deadline) {
        return Status(StatusCode::kDeadlineExceeded,
                      "shard '" + map.name(s) + "' (partition '" + partition +
                          "'): no daemon reported on its status topic in time");
      }
      reports.clear();
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - now);
      if (Status st = status->Poll(std::min(left, std::chrono::milliseconds(100)), &reports);
          !st.ok()) {
        return st;
      }
      for (const wire::DaemonStatus& r : reports) {
        if (r.health() == wire::STOPPING) continue;
        heard = true;
        if (coordinate != nullptr) *coordinate = r.coordinate();
        if (r.shard().name().empty()) {
          return Status(StatusCode::kInvalidArgument,
                        "daemon " + r.daemon() + " in the partition of shard '" + map.name(s) +
                            "' is not a shard (no shards.map in its configuration)");
        }
        if (r.shard().name() != map.name(s) || r.shard().map_digest() != map.digest()) {
          char text[200];
          std::snprintf(text, sizeof(text),
                        "serves shard '%s' of a map with digest %016" PRIx64
                        "; this process's map has digest %016" PRIx64,
                        r.shard().name().c_str(), r.shard().map_digest(), map.digest());
          return Status(StatusCode::kInvalidArgument,
                        "shard '" + map.name(s) + "': daemon " + r.daemon() + " " + text +
                            ": every daemon and client of a world must load the same shard map");
        }
      }
    }
  }
  return Status::Ok();
}

ShardedPublisher::~ShardedPublisher() = default;

Status ShardedPublisher::Create(Connection& connection, const ShardMap& map, uint32_t producer,
                                const PublisherOptions& options,
                                std::unique_ptr<ShardedPublisher>* out) {
  std::unique_ptr<ShardedPublisher> p(new ShardedPublisher());
  p->map_ = &map;
  p->connection_ = &connection;
  for (size_t s = 0; s < map.size(); ++s) {
    p->connections_.push_back(
        connection.Scoped(transport::ShardPartition(connection.options().partition, map.name(s))));
    std::unique_ptr<UpdatePublisher> shard;
    if (Status st = UpdatePublisher::Create(*p->connections_.back(), producer, options, &shard);
        !st.ok()) {
      return Status(st.code(), "shard '" + map.name(s) + "': " + st.message());
    }
    p->shards_.push_back(std::move(shard));
  }
  p->parts_.resize(map.size());
  p->pending_.assign(map.size(), false);
  *out = std::move(p);
  return Status::Ok();
}

Status ShardedPublisher::WaitForDaemon(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::string coordinate;
  if (Status s = CheckShards(*connection_, *map_, timeout, &coordinate); !s.ok()) return s;
  coordinate_ = coordinate == "double"  ? Coordinate::kDouble
                : coordinate == "int32" ? Coordinate::kInt32
                                        : Coordinate::kFloat;
  for (size_t s = 0; s < shards_.size(); ++s) {
    const auto left = std::max(std::chrono::milliseconds(1),
                               std::chrono::duration_cast<std::chrono::milliseconds>(
                                   deadline - std::chrono::steady_clock::now()));
    if (Status st = shards_[s]->WaitForDaemon(left); !st.ok()) {
      return Status(st.code(), "shard '" + map_->name(s) + "': " + st.message());
    }
  }
  return Status::Ok();
}

size_t ShardedPublisher::pending() const {
  return static_cast<size_t>(std::count(pending_.begin(), pending_.end(), true));
}

size_t ShardedPublisher::border_objects() const {
  return static_cast<size_t>(std::count_if(placed_.begin(), placed_.end(), [](const auto& p) {
    return std::popcount(p.second.shards) > 1;
  }));
}

Status ShardedPublisher::SendPending() {
  for (size_t s = 0; s < shards_.size(); ++s) {
    if (!pending_[s]) continue;
    if (Status st = shards_[s]->Publish(&parts_[s]); !st.ok()) {
      return Status(st.code(), "shard '" + map_->name(s) + "': " + st.message());
    }
    pending_[s] = false;
  }
  return Status::Ok();
}

Status ShardedPublisher::Maintain() {
  if (Status s = SendPending(); !s.ok()) return s;
  for (size_t s = 0; s < shards_.size(); ++s) {
    const uint64_t restates = shards_[s]->restates();
    if (Status st = shards_[s]->Maintain(); !st.ok()) {
      return Status(st.code(), "shard '" + map_->name(s) + "': " + st.message());
    }
    if (shards_[s]->restates() == restates || !closed_any_ || mid_frame_) continue;
    // The shard was restated between frames: close the last frame there again, so that its
    // restored set is keyed by that frame (the merge aligns shards by frame number) and
    // subscribers need not wait for the producer's next frame.
    wire::UpdateBatch& close = parts_[s];
    close.Clear();
    close.set_dim(static_cast<uint32_t>(map_->dimension()));
    close.set_frame(last_closed_frame_);
    close.set_end_of_frame(true);
    if (Status st = shards_[s]->Publish(&close); !st.ok()) pending_[s] = true;
  }
  return Status::Ok();
}

Status ShardedPublisher::Flush(std::chrono::milliseconds timeout) {
  if (Status s = SendPending(); !s.ok()) return s;
  for (size_t s = 0; s < shards_.size(); ++s) {
    if (Status st = shards_[s]->Flush(timeout); !st.ok()) {
      return Status(st.code(), "shard '" + map_->name(s) + "': " + st.message());
    }
  }
  return Status::Ok();
}

Status ShardedPublisher::Publish(wire::UpdateBatch* batch) {
  if (Status s = SendPending(); !s.ok()) return s;  // the new batch is not taken
  const int k = map_->dimension();
  const wire::BoxArray& inserts = batch->inserts();
  const wire::BoxArray& updates = batch->updates();
  auto refuse = [](std::string why) {
    return Status(StatusCode::kInvalidArgument, "batch refused by the shard router: " + why);
  };
  if (inserts.ids_size() + updates.ids_size() > 0 && batch->dim() != static_cast<uint32_t>(k)) {
    return refuse("dim " + std::to_string(batch->dim()) + " but the shard map is " +
                  std::to_string(k) + "-D");
  }
  if (std::string why = Malformed(inserts, k, true); !why.empty()) return refuse("inserts " + why);
  if (std::string why = Malformed(updates, k, false); !why.empty()) return refuse("updates " + why);
  if (batch->restate())
    return refuse("restate batches are the publisher's own (restate_on_restart)");
  if (batch->end_of_frame() && closed_any_ && batch->frame() <= last_closed_frame_) {
    return refuse("frame " + std::to_string(batch->frame()) + " closes after frame " +
                  std::to_string(last_closed_frame_) +
                  ": in a sharded world the frame numbers of frame-closing batches increase");
  }
  const bool wide = UsesDouble(inserts) || UsesDouble(updates);

  // Each touched id's placement before the batch and after it, and the box it ends with.
  struct Net {
    bool was_alive = false, alive = false, reinserted = false;
    Placed before, after;
    const wire::BoxArray* array = nullptr;  // the box it ends with: array's box index
    int index = 0;
  };
  std::unordered_map<uint64_t, Net> net;
  std::vector<uint64_t> order;  // ids in the order first touched: parts in a stable order
  net.reserve(static_cast<size_t>(inserts.ids_size() + updates.ids_size() + batch->erases_size()));
  auto state = [&](uint64_t id) -> Net& {
    auto [it, fresh] = net.try_emplace(id);
    if (fresh) {
      order.push_back(id);
      auto p = placed_.find(id);
      if (p != placed_.end()) {
        it->second.was_alive = it->second.alive = true;
        it->second.before = it->second.after = p->second;
      }
    }
    return it->second;
  };
  // The shards of box i of a, or 0 when the daemons refuse the box (not finite, lo > hi, out
  // of the daemons' coordinate range, not integral for int32 daemons): it then goes unchanged
  // to one shard, which reports it, and the router does not place it.
  auto route = [&](const wire::BoxArray& a, int i) -> ShardMap::Mask {
    Corners c = Read(a, i, k);
    for (int d = 0; d < k; ++d) {
      double& lo = c.lo[size_t(d)];
      double& hi = c.hi[size_t(d)];
      if (!std::isfinite(lo) || !std::isfinite(hi) || lo > hi) return 0;
      if (coordinate_ == Coordinate::kFloat) {
        constexpr double kMax = static_cast<double>(FLT_MAX);
        if (lo < -kMax || hi > kMax) return 0;
        lo = Down(lo);
        hi = Up(hi);
      } else if (coordinate_ == Coordinate::kInt32) {
        if (std::trunc(lo) != lo || std::trunc(hi) != hi || lo < -2147483648.0 ||
            hi > 2147483647.0) {
          return 0;
        }
      }
    }
    return map_->Route(c.lo.data(), c.hi.data());
  };
  // Items the daemons will refuse go unchanged to one shard, after the routed ones.
  struct Raw {
    size_t shard;
    int op;  // 0 erase, 1 insert, 2 update
    int index;
  };
  std::vector<Raw> raw;

  for (int i = 0; i < batch->erases_size(); ++i) {
    const uint64_t id = batch->erases(i);
    Net* n = id < kLocalIdLimit ? &state(id) : nullptr;
    if (n == nullptr || !n->alive) {
      raw.push_back({0, 0, i});
      continue;
    }
    n->alive = false;
    n->array = nullptr;
  }
  for (int i = 0; i < inserts.ids_size(); ++i) {
    const uint64_t id = inserts.ids(i);
    Net* n = id < kLocalIdLimit ? &state(id) : nullptr;
    if (n != nullptr && n->alive) {
      raw.push_back({Lowest(n->after.shards), 1, i});  // a duplicate: one shard refuses it
      continue;
    }
    const ShardMap::Mask mask = route(inserts, i);
    if (n == nullptr || mask == 0) {
      raw.push_back({0, 1, i});
      continue;
    }
    n->alive = true;
    n->reinserted = n->was_alive;
    n->after = Placed{};
    n->after.shards = mask;
    n->after.has_attributes =
        inserts.static_flags_size() + inserts.category_size() + inserts.mask_size() > 0;
    if (inserts.static_flags_size() > 0) n->after.is_static = inserts.static_flags(i);
    if (inserts.category_size() > 0) n->after.category = inserts.category(i);
    if (inserts.mask_size() > 0) n->after.mask = inserts.mask(i);
    n->array = &inserts;
    n->index = i;
  }
  for (int i = 0; i < updates.ids_size(); ++i) {
    const uint64_t id = updates.ids(i);
    Net* n = id < kLocalIdLimit ? &state(id) : nullptr;
    if (n == nullptr || !n->alive) {
      raw.push_back({0, 2, i});
      continue;
    }
    const ShardMap::Mask mask = route(updates, i);
    if (mask == 0) {
      raw.push_back({Lowest(n->after.shards), 2, i});  // NaN or inverted: refused, kept as is
      continue;
    }
    n->after.shards = mask;
    n->array = &updates;
    n->index = i;
  }

  // The shards' parts.
  for (size_t s = 0; s < parts_.size(); ++s) {
    wire::UpdateBatch& part = parts_[s];
    part.Clear();
    part.set_dim(batch->dim());
    part.set_frame(batch->frame());
    part.set_end_of_frame(batch->end_of_frame());
  }
  // Attributes travel only in parts where some insert has them (then for every insert there).
  std::vector<std::vector<Placed>> attributes(parts_.size());
  std::vector<bool> with_attributes(parts_.size(), false);
  auto add_insert = [&](size_t s, const wire::BoxArray& from, int i, const Placed& p) {
    CopyBox(from, i, k, wide, parts_[s].mutable_inserts());
    attributes[s].push_back(p);
    with_attributes[s] = with_attributes[s] || p.has_attributes;
  };
  for (const uint64_t id : order) {
    const Net& n = net.at(id);
    const ShardMap::Mask before = n.was_alive ? n.before.shards : 0;
    const ShardMap::Mask after = n.alive ? n.after.shards : 0;
    if (before != 0 && after != 0 && before != after) ++handovers_;
    for (ShardMap::Mask m = before | after; m != 0; m &= m - 1) {
      const size_t s = Lowest(m);
      const bool in_before = (before >> s) & 1, in_after = (after >> s) & 1;
      if (in_before && (!in_after || n.reinserted)) parts_[s].add_erases(id);
      if (in_after && (!in_before || n.reinserted)) {
        add_insert(s, *n.array, n.index, n.after);
      } else if (in_after && n.array != nullptr) {
        CopyBox(*n.array, n.index, k, wide, parts_[s].mutable_updates());
      }
    }
  }
  for (const Raw& r : raw) {
    wire::UpdateBatch& part = parts_[r.shard];
    if (r.op == 0) {
      part.add_erases(batch->erases(r.index));
    } else if (r.op == 1) {
      Placed p;
      p.has_attributes =
          inserts.static_flags_size() + inserts.category_size() + inserts.mask_size() > 0;
      if (inserts.static_flags_size() > 0) p.is_static = inserts.static_flags(r.index);
      if (inserts.category_size() > 0) p.category = inserts.category(r.index);
      if (inserts.mask_size() > 0) p.mask = inserts.mask(r.index);
      add_insert(r.shard, inserts, r.index, p);
    } else {
      CopyBox(updates, r.index, k, wide, part.mutable_updates());
    }
  }

  for (size_t s = 0; s < parts_.size(); ++s) {
    if (!with_attributes[s]) continue;
    wire::BoxArray* to = parts_[s].mutable_inserts();
    for (const Placed& p : attributes[s]) {
      to->add_static_flags(p.is_static);
      to->add_category(p.category);
      to->add_mask(p.mask);
    }
  }

  // Send. The first shard with a part decides: refused, nothing was sent and the batch is not
  // taken; else the batch is taken and a part another shard refuses is kept for later.
  bool taken = false;
  for (size_t s = 0; s < parts_.size(); ++s) {
    if (Items(parts_[s]) == 0 && !parts_[s].end_of_frame()) continue;
    Status st = shards_[s]->Publish(&parts_[s]);
    if (st.ok()) {
      taken = true;
    } else if (!taken) {
      return Status(st.code(), "shard '" + map_->name(s) + "': " + st.message());
    } else {
      pending_[s] = true;
    }
  }
  for (const auto& [id, n] : net) {
    if (n.alive) {
      placed_[id] = n.after;
    } else if (n.was_alive) {
      placed_.erase(id);
    }
  }
  if (batch->end_of_frame()) {
    closed_any_ = true;
    last_closed_frame_ = batch->frame();
  }
  mid_frame_ = !batch->end_of_frame();
  return Status::Ok();
}

}  // namespace bp::client
