// bp::service::EngineHost: the daemon's engine behind a runtime choice of algorithm, dimension
// and coordinate type, with the service-boundary validation of every item of an UpdateBatch.
//
// The host owns the id space: a producer's local id (< 2^48) becomes the engine key
// (producer << 48) | id, so a producer can only name its own objects. It applies a batch in the
// documented order (erases, inserts, updates), rejects each bad item with a reason and applies
// the rest (a restate batch's insert of a live id replaces that object), and converts wire
// coordinates to the engine's type: doubles to a float engine are
// rounded outward (lo down, hi up), so a conversion never loses a pair; an integer engine takes
// integral values in range only.
//
// An insert's category, mask and static flag become the engine object's ObjectOptions: the engine
// itself never tracks the pairs they reject (bp/object_options.h: the category/mask rule of Box2D
// and Bullet; static objects never pair with each other). They are fixed from insert to erase; an
// erase and reinsert in one frame may change them, and only real status changes are reported.
//
// Thread safety: not thread-safe; the daemon's loop is its only caller.
// Invariants: Objects() is the engine's live count as of the calls made so far (buffered
// included); Overlaps() counts reported (filter-passing) overlapping pairs as of the last Query.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "broadphase.pb.h"
#include "config.h"

#include "bp/broadphase.h"
#include "bp/status.h"

namespace bp::service {

/// Producer-local ids are below 2^48; the producer id takes the upper 16 bits of a key.
inline constexpr int kProducerShift = 48;
inline constexpr uint64_t kLocalIdLimit = uint64_t{1} << kProducerShift;
/// The engine key of a producer's object.
inline constexpr uint64_t GlobalKey(uint32_t producer, uint64_t local) {
  return (uint64_t{producer} << kProducerShift) | local;
}

/// Category bit 63 is the regions' (daemon-owned objects with producer 0, the regions of
/// interests): a region pairs with every object whose mask has this bit (the default mask does)
/// and whose category has another bit, and never with another region.
inline constexpr uint64_t kRegionCategory = uint64_t{1} << 63;

/// One refused item of a batch.
struct Reject {
  wire::Op op = wire::OP_UNSPECIFIED;
  uint32_t index = 0;  ///< position in its array
  uint64_t id = 0;     ///< producer-local id (0 for the whole batch)
  wire::RejectReason reason = wire::REJECT_REASON_UNSPECIFIED;
  std::string message;
};

/// What Apply did.
struct ApplyCounts {
  uint64_t inserts = 0;
  uint64_t updates = 0;
  uint64_t erases = 0;
  uint64_t rejected = 0;
};

class EngineHost {
 public:
  virtual ~EngineHost() = default;
  /// Validates batch (its version and producer are checked by the caller) and buffers every
  /// valid item; reject receives each refused one.
  virtual void Apply(const wire::UpdateBatch& batch, const std::function<void(Reject&&)>& reject,
                     ApplyCounts* out) = 0;
  /// Erases every object of producer (buffered, like Apply's erases) except, with keep (sorted
  /// producer-local ids), those it lists (the end of a restate); returns how many it erased.
  /// O(live objects): for a producer that went away or restated.
  virtual uint64_t EraseProducer(uint32_t producer, const std::vector<uint64_t>* keep) = 0;
  /// Runs the engine's query; replaces uncollide and collide by the frame's reported pairs,
  /// flattened (a0, b0, a1, b1, ...) in canonical order.
  virtual void Query(std::vector<uint64_t>* uncollide, std::vector<uint64_t>* collide) = 0;
  /// Live objects, counting the calls buffered since the last query.
  virtual uint64_t Objects() const = 0;
  /// Reported overlapping pairs as of the last query.
  virtual uint64_t Overlaps() const = 0;
  /// Replaces pairs by every overlapping pair (a < b) as of the last query, sorted.
  virtual void Snapshot(std::vector<std::pair<uint64_t, uint64_t>>* pairs) const = 0;
  /// Inserts (insert) or moves the region key (< 2^48) to the box [lo, hi] (K values each). The
  /// box is converted like an update's doubles; with round_outward, coordinates an integer
  /// engine cannot hold are rounded outward instead of refused. InvalidArgument names the axis
  /// and the reason. Regions are not counted in Objects().
  virtual Status PlaceRegion(uint64_t key, std::span<const double> lo, std::span<const double> hi,
                             bool round_outward, bool insert) = 0;
  /// The check PlaceRegion and SpotQuery make of a box, alone.
  virtual Status CheckBox(std::span<const double> lo, std::span<const double> hi,
                          bool round_outward) const = 0;
  /// Erases a region placed before.
  virtual void EraseRegion(uint64_t key) = 0;
  /// The category of a live object (1, the default, for one the host does not know).
  virtual uint64_t Category(uint64_t key) const = 0;
  /// Moves into *out (sorted, unique) the keys whose category may have changed since the last
  /// call: objects with a non-default category inserted or erased (an erase and reinsert in one
  /// frame changes the category without an event).
  virtual void TakeRecategorized(std::vector<uint64_t>* out) = 0;
  /// Replaces keys by the objects (not regions) whose boxes overlap [lo, hi] as of the last
  /// query, sorted. InvalidArgument if the box does not convert exactly to the engine's type.
  virtual Status SpotQuery(std::span<const double> lo, std::span<const double> hi,
                           std::vector<uint64_t>* keys) const = 0;
  /// The engine's counters.
  virtual Stats GetStats() const = 0;
  /// The engine's algorithm name.
  virtual std::string Name() const = 0;
  /// The dimension K.
  virtual int Dimension() const = 0;
};

/// The checks of a whole batch, before its items: size (bytes), protobuf decoding, schema
/// version, producer id, item count. True with *batch decoded if its items may be applied;
/// otherwise false and *out_reject says why (op OP_BATCH). The daemon and `bpctl check` share it.
bool AdmitBatch(std::span<const uint8_t> payload, const LimitsConfig& limits,
                wire::UpdateBatch* batch, Reject* out_reject);

/// Builds the engine the config names. InvalidArgument for an unknown algorithm, dimension or
/// coordinate type. max_objects bounds the live count (CAPACITY rejections beyond it).
Status MakeEngineHost(const EngineConfig& config, uint64_t max_objects,
                      std::unique_ptr<EngineHost>* out);

}  // namespace bp::service
