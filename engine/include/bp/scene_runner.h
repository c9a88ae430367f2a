// bp::workload::SceneRunner: drives any engine through a WORKLOADS.md scene frame by frame and
// keeps what the golden table checks (pairs, events, set hash, chain). Frame generation is not
// timed; applying the frame and querying is. Shared by the golden tests and bpbench.
//
// Thread safety: none; one runner drives one engine.
#pragma once

#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

#include "bp/broadphase.h"
#include "bp/workload.h"

namespace bp::workload {

template <int K, Coordinate T>
class SceneRunner {
 public:
  /// static_rest: objects of resting slots are inserted static (no static-static pairs; the
  /// golden hashes then no longer apply).
  /// unpaired_every: every n-th object by id (0: none) gets mask 0, so that it pairs with
  /// nothing (the golden hashes then no longer apply either).
  SceneRunner(Broadphase<K, T>& engine, const SceneParams& params, bool static_rest = false,
              uint32_t unpaired_every = 0)
      : engine_(engine),
        scene_(params),
        static_rest_(static_rest),
        unpaired_every_(unpaired_every) {}

  /// Inserts frame 0 and queries it; returns the milliseconds taken.
  double Build() {
    auto start = Clock::now();
    for (const SceneBox& b : scene_.Initial()) {
      Check(engine_.Insert(b.id, Convert(b), Options(b)), b.id);
    }
    engine_.Query(sink_);
    double ms = Ms(start);
    pairs_frame0_ = sink_.hash.pairs();
    chain_.AddFrame(sink_.hash.value());
    return ms;
  }

  /// Generates the next frame, then applies and queries it; returns the milliseconds taken by
  /// the engine alone. The frame's boxes are converted to the engine's type before the clock
  /// starts, as a simulator hands its own boxes over.
  double Step() {
    scene_.NextFrame(&ops_);
    items_.clear();
    for (const SceneBox& b : ops_.updates) items_.push_back({b.id, Convert(b)});
    inserts_.clear();
    insert_options_.clear();
    for (const SceneBox& b : ops_.inserts) {
      inserts_.push_back({b.id, Convert(b)});
      insert_options_.push_back(Options(b));
    }
    uint64_t collides = sink_.collides;
    uint64_t uncollides = sink_.uncollides;
    auto start = Clock::now();
    engine_.EraseMany(ops_.erases, [&](size_t i, const Status& s) { Check(s, ops_.erases[i]); });
    engine_.UpdateMany(items_, [&](size_t i, const Status& s) { Check(s, items_[i].key); });
    engine_.InsertMany(inserts_, insert_options_,
                       [&](size_t i, const Status& s) { Check(s, inserts_[i].key); });
    calls_ms_ = Ms(start);
    engine_.Query(sink_);
    double ms = Ms(start);
    collides_ += sink_.collides - collides;
    uncollides_ += sink_.uncollides - uncollides;
    chain_.AddFrame(sink_.hash.value());
    ++frames_;
    return ms;
  }

  uint64_t pairs_frame0() const { return pairs_frame0_; }
  uint64_t pairs() const { return sink_.hash.pairs(); }
  uint64_t collides() const { return collides_; }      ///< over frames 1..
  uint64_t uncollides() const { return uncollides_; }  ///< over frames 1..
  uint64_t set_hash() const { return sink_.hash.value(); }
  uint64_t chain() const { return chain_.value(); }
  uint64_t frames() const { return frames_; }
  /// Milliseconds of the last Step's calls before its query (erases, updates, inserts).
  double calls_ms() const { return calls_ms_; }
  /// Calls the engine refused (must stay 0), and the first refusal.
  uint64_t errors() const { return errors_; }
  const std::string& first_error() const { return first_error_; }
  const Scene& scene() const { return scene_; }

 private:
  using Clock = std::chrono::steady_clock;
  struct HashSink final : EventSink<uint64_t> {
    void Collide(const uint64_t& a, const uint64_t& b) override {
      hash.Collide(a, b);
      ++collides;
    }
    void Uncollide(const uint64_t& a, const uint64_t& b) override {
      hash.Uncollide(a, b);
      ++uncollides;
    }
    SetHash hash;
    uint64_t collides = 0;
    uint64_t uncollides = 0;
  };

  static double Ms(Clock::time_point start) {
    return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
  }
  Box<K, T> Convert(const SceneBox& b) const {
    return ToBox<K, T>(b, scene_.grid(), scene_.params().offset);
  }
  ObjectOptions Options(const SceneBox& b) const {
    ObjectOptions o;
    o.is_static = static_rest_ && !b.moves;
    if (unpaired_every_ != 0 && b.id % unpaired_every_ == 0) o.mask = 0;
    return o;
  }
  void Check(const Status& s, uint64_t id) {
    if (s.ok()) return;
    if (errors_++ == 0) first_error_ = "id " + std::to_string(id) + ": " + s.ToString();
  }

  Broadphase<K, T>& engine_;
  Scene scene_;
  bool static_rest_;
  uint32_t unpaired_every_;
  FrameOps ops_;
  std::vector<typename Broadphase<K, T>::Item> items_;    // the frame's updates
  std::vector<typename Broadphase<K, T>::Item> inserts_;  // the frame's inserts
  std::vector<ObjectOptions> insert_options_;             // and their options
  HashSink sink_;
  HashChain chain_;
  uint64_t pairs_frame0_ = 0;
  uint64_t collides_ = 0;
  uint64_t uncollides_ = 0;
  uint64_t frames_ = 0;
  double calls_ms_ = 0;
  uint64_t errors_ = 0;
  std::string first_error_;
};

}  // namespace bp::workload
