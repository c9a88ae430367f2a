#include "engine_host.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <limits>
#include <type_traits>
#include <unordered_map>

#include "bp/engines.h"

namespace bp::service {
namespace {

// The config (config.h, which does not include the engines) names the engines bp::NewEngine builds.
static_assert(kAlgorithms == kEngineAlgorithms);

std::string ItemName(wire::Op op, uint32_t index, uint64_t id) {
  const char* what = op == wire::OP_INSERT ? "insert" : op == wire::OP_UPDATE ? "update" : "erase";
  return std::string(what) + "[" + std::to_string(index) + "] id " + std::to_string(id);
}

// A coordinate in a message, in the shortest form that reads back as the same value of its own
// type ("1e+300", a float's "0.1"), where std::to_string would print every digit of a large
// value.
template <class S>
std::string ShortNumber(S v) {
  char text[32];
  const auto result = std::to_chars(text, text + sizeof(text), v);
  return std::string(text, result.ptr);
}

// Converts one wire coordinate to the engine's type. Floating engines round outward (lo down,
// hi up) so that a narrowing conversion can only grow a box, never lose a pair.
template <class T, class S>
bool ConvertCoordinate(S v, bool is_lo, T* out, wire::RejectReason* reason, std::string* why) {
  if (std::isnan(v) || std::isinf(v)) {
    *reason = wire::NOT_FINITE;
    *why = std::isnan(v) ? "NaN" : "infinite";
    return false;
  }
  if constexpr (std::is_floating_point_v<T>) {
    if constexpr (sizeof(S) > sizeof(T)) {
      if (std::fabs(v) > static_cast<S>(std::numeric_limits<T>::max())) {
        *reason = wire::NOT_FINITE;
        *why = ShortNumber(v) + ", out of the engine's float range";
        return false;
      }
      T t = static_cast<T>(v);
      if (is_lo && static_cast<S>(t) > v)
        t = std::nextafter(t, -std::numeric_limits<T>::infinity());
      if (!is_lo && static_cast<S>(t) < v)
        t = std::nextafter(t, std::numeric_limits<T>::infinity());
      *out = t;
    } else {
      *out = static_cast<T>(v);
    }
    return true;
  } else {
    if (std::trunc(v) != v) {
      *reason = wire::NOT_INTEGRAL;
      *why = ShortNumber(v) + ", not an integer (the engine's coordinates are integers)";
      return false;
    }
    // Compared in double, where every int32 bound is exact: as a float, INT32_MAX rounds up to
    // 2^31, which is out of range (and its conversion undefined).
    const double d = static_cast<double>(v);
    if (d < static_cast<double>(std::numeric_limits<T>::min()) ||
        d > static_cast<double>(std::numeric_limits<T>::max())) {
      *reason = wire::NOT_FINITE;
      *why = ShortNumber(v) + ", out of the engine's integer range";
      return false;
    }
    *out = static_cast<T>(v);
    return true;
  }
}

template <int K, class T>
class TypedHost final : public EngineHost {
 public:
  using Engine = Broadphase<K, T, uint64_t>;
  using BoxT = Box<K, T>;

  TypedHost(std::unique_ptr<Engine> engine, uint64_t max_objects)
      : engine_(std::move(engine)), max_objects_(max_objects) {}

  void Apply(const wire::UpdateBatch& batch, const std::function<void(Reject&&)>& reject,
             ApplyCounts* out) override {
    const uint32_t producer = batch.producer();
    auto refuse = [&](wire::Op op, uint32_t index, uint64_t id, wire::RejectReason reason,
                      std::string why) {
      ++out->rejected;
      reject(Reject{op, index, id, reason, ItemName(op, index, id) + ": " + why});
    };

    // Erases reach the engine in runs through EraseMany, as updates do through UpdateMany.
    keys_.clear();
    item_index_.clear();
    auto flush_erases = [&]() {
      if (keys_.empty()) return;
      for (uint64_t key : keys_) NoteErase(key);
      const size_t refused = engine_->EraseMany(keys_, [&](size_t k, const Status&) {
        const uint32_t index = item_index_[k];
        refuse(wire::OP_ERASE, index, batch.erases(static_cast<int>(index)), wire::UNKNOWN_ID,
               "no such object of producer " + std::to_string(producer));
      });
      objects_ -= keys_.size() - refused;
      out->erases += keys_.size() - refused;
      keys_.clear();
      item_index_.clear();
    };
    for (int i = 0; i < batch.erases_size(); ++i) {
      const uint32_t index = static_cast<uint32_t>(i);
      const uint64_t id = batch.erases(i);
      if (id >= kLocalIdLimit) {
        flush_erases();  // refusals stay in index order
        refuse(wire::OP_ERASE, index, id, wire::ID_OUT_OF_RANGE, "ids must be below 2^48");
        continue;
      }
      keys_.push_back(GlobalKey(producer, id));
      item_index_.push_back(index);
    }
    flush_erases();
    ApplyBoxes(batch, wire::OP_INSERT, batch.inserts(), refuse, out);
    ApplyBoxes(batch, wire::OP_UPDATE, batch.updates(), refuse, out);
  }

  uint64_t EraseProducer(uint32_t producer, const std::vector<uint64_t>* keep) override {
    std::vector<uint64_t> keys;
    engine_->ForEachObject([&](const uint64_t& key) {
      if ((key >> kProducerShift) == producer &&
          (keep == nullptr ||
           !std::binary_search(keep->begin(), keep->end(), key & (kLocalIdLimit - 1)))) {
        keys.push_back(key);
      }
    });
    for (uint64_t key : keys) NoteErase(key);
    const uint64_t erased = keys.size() - engine_->EraseMany(keys);
    objects_ -= erased;
    return erased;
  }

  void Query(std::vector<uint64_t>* uncollide, std::vector<uint64_t>* collide) override {
    uncollide->clear();
    collide->clear();
    struct Sink final : EventSink<uint64_t> {
      std::vector<uint64_t>* uncollide;
      std::vector<uint64_t>* collide;
      void Collide(const uint64_t& a, const uint64_t& b) override {
        collide->push_back(a);
        collide->push_back(b);
      }
      void Uncollide(const uint64_t& a, const uint64_t& b) override {
        uncollide->push_back(a);
        uncollide->push_back(b);
      }
    } sink;
    sink.uncollide = uncollide;
    sink.collide = collide;
    engine_->Query(sink);
    overlaps_ += collide->size() / 2;
    overlaps_ -= uncollide->size() / 2;
  }

  void Snapshot(std::vector<std::pair<uint64_t, uint64_t>>* pairs) const override {
    pairs->clear();
    pairs->reserve(overlaps_);
    engine_->ForEachOverlap(
        [&](const uint64_t& a, const uint64_t& b) { pairs->emplace_back(a, b); });
    std::sort(pairs->begin(), pairs->end());
  }

  Status PlaceRegion(uint64_t key, std::span<const double> lo, std::span<const double> hi,
                     bool round_outward, bool insert) override {
    BoxT box;
    if (Status s = ConvertDoubles(lo, hi, round_outward, &box); !s.ok()) return s;
    if (!insert) return engine_->Update(key, box);
    ObjectOptions options;
    options.category = kRegionCategory;
    options.mask = ~kRegionCategory;
    return engine_->Insert(key, box, options);
  }

  Status CheckBox(std::span<const double> lo, std::span<const double> hi,
                  bool round_outward) const override {
    BoxT box;
    return ConvertDoubles(lo, hi, round_outward, &box);
  }

  void EraseRegion(uint64_t key) override { (void)engine_->Erase(key); }

  uint64_t Category(uint64_t key) const override {
    const auto it = categories_.find(key);
    return it == categories_.end() ? 1 : it->second;
  }

  void TakeRecategorized(std::vector<uint64_t>* out) override {
    std::sort(recategorized_.begin(), recategorized_.end());
    recategorized_.erase(std::unique(recategorized_.begin(), recategorized_.end()),
                         recategorized_.end());
    out->swap(recategorized_);
    recategorized_.clear();
  }

  Status SpotQuery(std::span<const double> lo, std::span<const double> hi,
                   std::vector<uint64_t>* keys) const override {
    keys->clear();
    BoxT box;
    if (Status s = ConvertDoubles(lo, hi, false, &box); !s.ok()) return s;
    engine_->ForEachOverlapping(box, [&](const uint64_t& key) {
      if (key >= kLocalIdLimit) keys->push_back(key);
    });
    std::sort(keys->begin(), keys->end());
    return Status::Ok();
  }

  uint64_t Objects() const override { return objects_; }
  uint64_t Overlaps() const override { return overlaps_; }
  Stats GetStats() const override { return engine_->GetStats(); }
  std::string Name() const override { return engine_->Name(); }
  int Dimension() const override { return K; }

 private:
  // Checks the shape of a box array; on failure rejects every item with the reason.
  template <class Refuse>
  bool CheckShape(const wire::UpdateBatch& batch, wire::Op op, const wire::BoxArray& boxes,
                  Refuse& refuse) {
    const size_t n = static_cast<size_t>(boxes.ids_size());
    if (n == 0) return true;
    std::string why;
    wire::RejectReason reason = wire::WRONG_DIMENSION;
    const bool has32 = boxes.lo32_size() > 0 || boxes.hi32_size() > 0;
    const bool has64 = boxes.lo64_size() > 0 || boxes.hi64_size() > 0;
    const size_t lo = static_cast<size_t>(has32 ? boxes.lo32_size() : boxes.lo64_size());
    const size_t hi = static_cast<size_t>(has32 ? boxes.hi32_size() : boxes.hi64_size());
    const size_t expected = n * static_cast<size_t>(K);
    auto attribute_ok = [n](int size) { return size == 0 || static_cast<size_t>(size) == n; };
    if (batch.dim() != static_cast<uint32_t>(K)) {
      why = batch.dim() == 0 ? "the batch does not set dim"
                             : "the batch's dim is " + std::to_string(batch.dim());
      why += "; the daemon's dimension is " + std::to_string(K);
    } else if (has32 && has64) {
      reason = wire::MALFORMED;
      why = "the array has both float and double coordinates";
    } else if (lo != expected || hi != expected) {
      why = std::to_string(n) + " ids need " + std::to_string(expected) + " lo and hi values (" +
            std::to_string(K) + " per box); got " + std::to_string(lo) + " lo and " +
            std::to_string(hi) + " hi";
    } else if (!attribute_ok(boxes.static_flags_size()) || !attribute_ok(boxes.category_size()) ||
               !attribute_ok(boxes.mask_size())) {
      reason = wire::BAD_ATTRIBUTE;
      why = "static_flags, category and mask must be empty or have one value per id";
    } else if (op == wire::OP_UPDATE && (boxes.static_flags_size() > 0 ||
                                         boxes.category_size() > 0 || boxes.mask_size() > 0)) {
      reason = wire::BAD_ATTRIBUTE;
      why = "attributes are set at insert; erase and reinsert to change them";
    } else {
      return true;
    }
    for (size_t i = 0; i < n; ++i) {
      refuse(op, static_cast<uint32_t>(i), boxes.ids(static_cast<int>(i)), reason, why);
    }
    return false;
  }

  template <class S>
  bool ConvertBox(const S* lo, const S* hi, BoxT* box, wire::RejectReason* reason,
                  std::string* why) const {
    for (int a = 0; a < K; ++a) {
      const size_t axis = static_cast<size_t>(a);
      std::string detail;
      if (!ConvertCoordinate<T>(lo[a], true, &box->lo[axis], reason, &detail)) {
        *why = "lo on axis " + std::to_string(a) + " is " + detail;
        return false;
      }
      if (!ConvertCoordinate<T>(hi[a], false, &box->hi[axis], reason, &detail)) {
        *why = "hi on axis " + std::to_string(a) + " is " + detail;
        return false;
      }
      if (lo[a] > hi[a]) {
        *reason = wire::INVERTED;
        *why = "lo > hi on axis " + std::to_string(a) + " (" + ShortNumber(lo[a]) + " > " +
               ShortNumber(hi[a]) + ")";
        return false;
      }
    }
    return true;
  }

  template <class Refuse>
  void ApplyBoxes(const wire::UpdateBatch& batch, wire::Op op, const wire::BoxArray& boxes,
                  Refuse& refuse, ApplyCounts* out) {
    if (!CheckShape(batch, op, boxes, refuse)) return;
    const bool use32 = boxes.lo32_size() > 0;
    const uint32_t producer = batch.producer();
    items_.clear();  // nothing of an earlier batch (whose reject callback may have thrown)
    item_index_.clear();
    // Updates reach the engine in runs through UpdateMany, which overlaps their look-ups. A run
    // ends before an item refused here, so that refusals stay in index order.
    auto flush = [&]() {
      if (items_.empty()) return;
      const size_t refused = engine_->UpdateMany(items_, [&](size_t k, const Status& s) {
        const uint32_t index = item_index_[k];
        const uint64_t id = boxes.ids(static_cast<int>(index));
        if (s.code() == StatusCode::kNotFound) {
          refuse(op, index, id, wire::UNKNOWN_ID,
                 "no such object of producer " + std::to_string(producer));
        } else {
          refuse(op, index, id, wire::ENGINE_REFUSED, s.ToString());
        }
      });
      out->updates += items_.size() - refused;
      items_.clear();
      item_index_.clear();
    };
    auto refuse_here = [&](uint32_t index, uint64_t id, wire::RejectReason reason,
                           std::string why) {
      flush();
      refuse(op, index, id, reason, std::move(why));
    };
    for (int i = 0; i < boxes.ids_size(); ++i) {
      const uint32_t index = static_cast<uint32_t>(i);
      const uint64_t id = boxes.ids(i);
      if (id >= kLocalIdLimit) {
        refuse_here(index, id, wire::ID_OUT_OF_RANGE, "ids must be below 2^48");
        continue;
      }
      BoxT box;
      wire::RejectReason reason = wire::REJECT_REASON_UNSPECIFIED;
      std::string why;
      const size_t at = static_cast<size_t>(i) * static_cast<size_t>(K);
      const bool converted =
          use32
              ? ConvertBox(boxes.lo32().data() + at, boxes.hi32().data() + at, &box, &reason, &why)
              : ConvertBox(boxes.lo64().data() + at, boxes.hi64().data() + at, &box, &reason, &why);
      if (!converted) {
        refuse_here(index, id, reason, std::move(why));
        continue;
      }
      const uint64_t key = GlobalKey(producer, id);
      if (op == wire::OP_UPDATE) {
        items_.push_back({key, box});
        item_index_.push_back(index);
        continue;
      }
      ObjectOptions options;
      if (boxes.category_size() > 0) options.category = boxes.category(i);
      if (boxes.mask_size() > 0) options.mask = boxes.mask(i);
      if (boxes.static_flags_size() > 0) options.is_static = boxes.static_flags(i);
      if (batch.restate() && engine_->Erase(key).ok()) {
        // Restated: the object the daemon holds is replaced (the engine turns erase + insert
        // into an update, or into a rekey when the attributes changed).
        NoteErase(key);
        if (Status s = engine_->Insert(key, box, options); !s.ok()) {
          --objects_;
          refuse(op, index, id, wire::ENGINE_REFUSED, s.ToString() + " (the object is erased)");
        } else {
          NoteInsert(key, options.category);
          ++out->updates;
        }
        continue;
      }
      if (objects_ >= max_objects_) {
        refuse(
            op, index, id, wire::CAPACITY,
            "the daemon holds limits.max_objects = " + std::to_string(max_objects_) + " objects");
        continue;
      }
      Status s = engine_->Insert(key, box, options);
      if (s.code() == StatusCode::kAlreadyExists) {
        refuse(op, index, id, wire::DUPLICATE_INSERT,
               "producer " + std::to_string(producer) + " already has an object with this id");
        continue;
      }
      if (!s.ok()) {
        refuse(op, index, id, wire::ENGINE_REFUSED, s.ToString());
        continue;
      }
      NoteInsert(key, options.category);
      ++objects_;
      ++out->inserts;
    }
    flush();
  }

  // Keeps the non-default categories of live objects, and the keys whose category may change.
  void NoteInsert(uint64_t key, uint64_t category) {
    if (category == 1) return;
    categories_[key] = category;
    recategorized_.push_back(key);
  }
  void NoteErase(uint64_t key) {
    if (categories_.empty()) return;
    if (categories_.erase(key) != 0) recategorized_.push_back(key);
  }

  // Converts a region or spot box; round_outward rounds what an integer engine cannot hold.
  Status ConvertDoubles(std::span<const double> lo, std::span<const double> hi, bool round_outward,
                        BoxT* box) const {
    if (lo.size() != static_cast<size_t>(K) || hi.size() != static_cast<size_t>(K)) {
      return Status(StatusCode::kInvalidArgument,
                    "a box needs " + std::to_string(K) + " lo and hi values; got " +
                        std::to_string(lo.size()) + " and " + std::to_string(hi.size()));
    }
    std::array<double, static_cast<size_t>(K)> l, h;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      l[a] = lo[a];
      h[a] = hi[a];
      if (round_outward && std::is_integral_v<T> && std::isfinite(l[a]) && std::isfinite(h[a])) {
        l[a] = std::max(std::floor(l[a]), static_cast<double>(std::numeric_limits<T>::min()));
        h[a] = std::min(std::ceil(h[a]), static_cast<double>(std::numeric_limits<T>::max()));
      }
    }
    wire::RejectReason reason{};
    std::string why;
    if (!ConvertBox(l.data(), h.data(), box, &reason, &why))
      return Status(StatusCode::kInvalidArgument, why);
    return Status::Ok();
  }
  std::unique_ptr<Engine> engine_;
  std::vector<typename Engine::Item> items_;  // a run of a batch's updates, for UpdateMany
  std::vector<uint64_t> keys_;                // a run of a batch's erases, for EraseMany
  std::vector<uint32_t> item_index_;          // their indexes in the batch
  uint64_t max_objects_;
  uint64_t objects_ = 0;
  std::unordered_map<uint64_t, uint64_t> categories_;  // live objects' non-default categories
  std::vector<uint64_t> recategorized_;                // see TakeRecategorized
  uint64_t overlaps_ = 0;
};

template <int K, class T>
Status Make(const EngineConfig& config, uint64_t max_objects, std::unique_ptr<EngineHost>* out) {
  EngineSpec spec;
  spec.algorithm = config.algorithm;
  const double cell_size = config.cell_size.value_or(0.0);
  const auto threads = static_cast<unsigned>(EngineThreads(config));
  auto grid = [&](auto& options) {
    options.cell_size = cell_size;
    options.threads = threads;
    // Keys are looked up on this thread only: spread over the engine's threads, the look-ups
    // cut the ingest's median but raised the update→event tail end to end (docs/TUNING.md,
    // daemon); the other parallel phases stay.
    options.parallel_lookups = false;
  };
  grid(spec.grid_segmented_sap);
  grid(spec.grid_batch_sap);
  grid(spec.grid_dense);
  // The config refuses a fractional margin for int32, so the conversion is exact there.
  std::unique_ptr<Broadphase<K, T, uint64_t>> engine =
      NewEngine<K, T>(spec, static_cast<T>(config.margin));
  if (engine == nullptr) {
    return Status(StatusCode::kInvalidArgument, "unknown engine algorithm '" + config.algorithm +
                                                    "' (known: " + EngineAlgorithmList() + ")");
  }
  *out = std::make_unique<TypedHost<K, T>>(std::move(engine), max_objects);
  return Status::Ok();
}

template <int K>
Status MakeForDimension(const EngineConfig& config, uint64_t max_objects,
                        std::unique_ptr<EngineHost>* out) {
  switch (config.coordinate) {
    case CoordinateType::kFloat:
      return Make<K, float>(config, max_objects, out);
    case CoordinateType::kDouble:
      return Make<K, double>(config, max_objects, out);
    case CoordinateType::kInt32:
      return Make<K, int32_t>(config, max_objects, out);
  }
  return Status(StatusCode::kInvalidArgument, "unknown coordinate type");
}

}  // namespace

bool AdmitBatch(std::span<const uint8_t> payload, const LimitsConfig& limits,
                wire::UpdateBatch* batch, Reject* out_reject) {
  batch->Clear();
  auto refuse = [&](wire::RejectReason reason, std::string why) {
    *out_reject = Reject{wire::OP_BATCH, 0, 0, reason, std::move(why)};
    return false;
  };
  // protobuf parses at most INT_MAX bytes, whatever limits.max_batch_bytes says.
  if (payload.size() > limits.max_batch_bytes ||
      payload.size() > static_cast<size_t>(std::numeric_limits<int>::max())) {
    return refuse(wire::OVERSIZE, "batch of " + std::to_string(payload.size()) +
                                      " bytes exceeds limits.max_batch_bytes = " +
                                      std::to_string(limits.max_batch_bytes));
  }
  if (!batch->ParseFromArray(payload.data(), static_cast<int>(payload.size()))) {
    batch->Clear();
    return refuse(wire::MALFORMED, "payload of " + std::to_string(payload.size()) +
                                       " bytes is not a valid UpdateBatch");
  }
  if (batch->version() != wire::SCHEMA_VERSION_1) {
    return refuse(wire::UNSUPPORTED_VERSION,
                  "schema version " + std::to_string(static_cast<int>(batch->version())) +
                      " is not supported (this daemon speaks version 1)");
  }
  if (batch->producer() == 0 || batch->producer() > 0xFFFF) {
    return refuse(wire::BAD_PRODUCER,
                  "producer id " + std::to_string(batch->producer()) + " is outside 1..65535");
  }
  const uint64_t items = static_cast<uint64_t>(batch->inserts().ids_size()) +
                         static_cast<uint64_t>(batch->updates().ids_size()) +
                         static_cast<uint64_t>(batch->erases_size());
  if (items > limits.max_batch_items) {
    return refuse(wire::OVERSIZE, "batch of " + std::to_string(items) +
                                      " items exceeds limits.max_batch_items = " +
                                      std::to_string(limits.max_batch_items));
  }
  return true;
}

Status MakeEngineHost(const EngineConfig& config, uint64_t max_objects,
                      std::unique_ptr<EngineHost>* out) {
  switch (config.dimension) {
    case 2:
      return MakeForDimension<2>(config, max_objects, out);
    case 3:
      return MakeForDimension<3>(config, max_objects, out);
    default:
      return Status(StatusCode::kInvalidArgument,
                    "engine.dimension must be 2 or 3, not " + std::to_string(config.dimension));
  }
}

}  // namespace bp::service
