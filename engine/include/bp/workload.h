// bp::workload: the paper's synthetic benchmark scene, bit-exact as pinned down in
// docs/WORKLOADS.md (uniform cubes, density 5%, speed 10% of the width, bouncing, churn),
// and the pair-set hashes whose golden values that page lists. Shared by tests and bpbench.
//
// Thread safety: a Scene is not thread-safe; distinct Scenes are independent.
// Invariants:
//  1. Every coordinate a Scene emits is float-exact and a multiple of grid(), and
//     |coordinate / grid()| < 2^24, so float, double and integer engines see identical boxes.
//  2. For a given SceneParams the sequence of frames is a pure function of the seed.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <type_traits>
#include <vector>

#include "bp/box.h"

namespace bp::workload {

/// splitmix64: advances state and returns the next value.
uint64_t SplitMix64(uint64_t& state);
/// The finalising mix of splitmix64, without the increment.
uint64_t Mix64(uint64_t z);

/// xoshiro256**, seeded by four splitmix64 draws from seed.
class Xoshiro256 {
 public:
  /// Seeds s[0..3] with splitmix64(seed_state) four times, seed_state = seed.
  explicit Xoshiro256(uint64_t seed);
  /// The next 64 random bits.
  uint64_t Next();
  /// double(Next() >> 11) * 2^-53, in [0, 1).
  double Uniform01();
  /// (uint128(Next()) * bound) >> 64, in [0, bound).
  uint64_t Below(uint64_t bound);

 private:
  std::array<uint64_t, 4> s_{};
};

/// The scene's layout. kUniform is WORKLOADS.md's scene, bit-exact (the golden values hold only
/// for it); the others are the scenes "where uniform grids suffer" of WORKLOADS.md's last list,
/// built from the same generator:
///  - kClustered: slot i with i % 10 != 9 (cluster_fraction 0.9 of the slots) lives and bounces
///    in a cube of cluster_volume (1%) of the environment at its centre; the rest are uniform.
///  - kMixed: each object draws its width log-uniformly in [min_width, max_width] cube widths
///    (1e-3 to 1e3) when it is placed, and moves at speed_fraction of its own width; the side
///    keeps the volumetric density (the mean of width^dim replaces w^dim). Both corners are
///    snapped, so widths below the snap grid become points, as they would in float.
///  - kFast: moving slot i with i % 10 == 0 moves fast_speed (25) cube widths per frame, which
///    crosses several cells of any grid sized for these densities; the rest as uniform.
enum class Shape : uint8_t { kUniform, kClustered, kMixed, kFast };

/// The scene's parameters (WORKLOADS.md, "Parameters").
struct SceneParams {
  int dim = 3;                    ///< 3, or 2 for the planar variant
  uint32_t n = 10000;             ///< live objects
  uint32_t moving = 1000;         ///< moving slots (slots 0..moving-1)
  uint32_t churn = 50;            ///< removals (= insertions) per frame
  double density = 0.05;          ///< volumetric density
  double width = 1.0;             ///< cube width w
  double speed_fraction = 0.1;    ///< speed as a fraction of w
  uint64_t seed = 12345;          ///< random seed
  Shape shape = Shape::kUniform;  ///< the layout (see Shape)
  double cluster_fraction = 0.9;  ///< kClustered: share of the slots in the cluster (in tenths)
  double cluster_volume = 0.01;   ///< kClustered: the cluster's share of the environment
  double min_width = 1e-3;        ///< kMixed: smallest width, in cube widths
  double max_width = 1e3;         ///< kMixed: largest width, in cube widths
  double fast_speed = 25;         ///< kFast: speed of the fast movers, cube widths per frame
  /// Added to every coordinate when a box is converted to an engine box (ToBox), in the engine's
  /// coordinate type: a world far from the origin. Floating-point coordinates only.
  double offset = 0;
};

/// "uniform", "clustered", "mixed" or "fast".
const char* ShapeName(Shape shape);
/// The shape named name; false if there is none.
bool ParseShape(const char* name, Shape* shape);

/// One box of the scene: an id and float corners; axes >= dim have lo = 0, hi = w.
struct SceneBox {
  uint64_t id = 0;
  std::array<float, 3> lo{};
  std::array<float, 3> hi{};
  bool moves = false;  ///< its slot is a moving one (else it rests for its whole life)
};

/// The operations of one frame, to be applied as removals, then moves, then insertions.
struct FrameOps {
  std::vector<uint64_t> erases;   ///< ids removed (churn), in generation order
  std::vector<SceneBox> updates;  ///< moved boxes, slot order
  std::vector<SceneBox> inserts;  ///< new boxes (churn), in generation order
  void Clear() {
    erases.clear();
    updates.clear();
    inserts.clear();
  }
};

/// The scene generator: initial boxes, then one frame at a time.
class Scene {
 public:
  /// Builds the initial scene (frame 0): slots 0..n-1 with ids 0..n-1.
  explicit Scene(const SceneParams& params);

  /// The boxes of frame 0 in id order.
  const std::vector<SceneBox>& Initial() const { return initial_; }
  /// Generates the next frame into *out (cleared first).
  void NextFrame(FrameOps* out);

  /// Dimension of the scene (2 or 3).
  int dim() const { return params_.dim; }
  /// The snap grid: a power of two; every coordinate is an integer multiple of it.
  double grid() const { return grid_; }
  /// Side length of the environment cube.
  double side() const { return side_; }
  /// The parameters.
  const SceneParams& params() const { return params_; }

 private:
  struct Slot {
    uint64_t id = 0;
    std::array<double, 3> p{};
    std::array<double, 3> v{};
    double w = 0;  // its width (kMixed draws one per placement)
  };
  // The cube a slot lives and bounces in: p[a] in [base, base + lim].
  struct Region {
    double base = 0, lim = 0;
  };
  Region RegionOf(uint32_t slot_index) const;
  double SpeedOf(uint32_t slot_index, const Slot& slot) const;
  void RandomPosition(uint32_t slot_index, Slot& slot);
  void RandomVelocity(uint32_t slot_index, Slot& slot);
  SceneBox BoxOf(const Slot& slot) const;
  static void Bounce(Slot& slot, double base, double lim, std::size_t dim);
  float Snap(double x) const;

  SceneParams params_;
  Xoshiro256 rng_;
  double side_ = 0, lim_ = 0, speed_ = 0, grid_ = 0, inv_grid_ = 0;
  Region cluster_;  // kClustered: the cluster's cube
  uint64_t next_id_ = 0;
  std::vector<Slot> slots_;
  std::vector<SceneBox> initial_;
  std::vector<uint8_t> chosen_;  // per slot: replaced this frame
};

/// Converts a scene box to an engine box with K = dim axes: float and double take the float
/// value plus offset, added in T (so rounded as an engine of T would see it); an integer type
/// takes coordinate / grid, which is exact (invariant 1), and must have offset 0.
template <int K, Coordinate T>
Box<K, T> ToBox(const SceneBox& box, double grid, double offset = 0) {
  Box<K, T> out;
  for (std::size_t a = 0; a < static_cast<std::size_t>(K); ++a) {
    if constexpr (std::is_floating_point_v<T>) {
      out.lo[a] = static_cast<T>(box.lo[a]);
      out.hi[a] = static_cast<T>(box.hi[a]);
      if (offset != 0) {
        out.lo[a] += static_cast<T>(offset);
        out.hi[a] += static_cast<T>(offset);
      }
    } else {
      out.lo[a] = static_cast<T>(std::llround(static_cast<double>(box.lo[a]) / grid));
      out.hi[a] = static_cast<T>(std::llround(static_cast<double>(box.hi[a]) / grid));
    }
  }
  return out;
}

/// min(a,b) << 32 | max(a,b), for ids below 2^32.
inline uint64_t PairKey(uint64_t a, uint64_t b) { return a < b ? (a << 32 | b) : (b << 32 | a); }
/// mix64(key ^ 0x5851F42D4C957F2D).
inline uint64_t PairHash(uint64_t key) { return Mix64(key ^ 0x5851F42D4C957F2DULL); }

/// The set hash (wrapping sum of PairHash over the set) and the chain over frames.
class HashChain {
 public:
  /// Folds in the set hash of the next frame (frame 0 first).
  void AddFrame(uint64_t set_hash) {
    chain_ = frames_ == 0 ? Mix64(set_hash) : Mix64(chain_ ^ (set_hash + frames_));
    ++frames_;
  }
  /// The chain value after the frames added so far.
  uint64_t value() const { return chain_; }

 private:
  uint64_t chain_ = 0;
  uint64_t frames_ = 0;
};

/// Maintains set_hash incrementally from collide/uncollide events on ids.
class SetHash {
 public:
  void Collide(uint64_t a, uint64_t b) {
    sum_ += PairHash(PairKey(a, b));
    ++pairs_;
  }
  void Uncollide(uint64_t a, uint64_t b) {
    sum_ -= PairHash(PairKey(a, b));
    --pairs_;
  }
  uint64_t value() const { return sum_; }
  uint64_t pairs() const { return pairs_; }

 private:
  uint64_t sum_ = 0;
  uint64_t pairs_ = 0;
};

}  // namespace bp::workload
