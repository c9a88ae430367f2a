// The extreme and stiff numeric suite: every engine, in 2-D and 3-D with float, double
// and int32 coordinates, against the model oracle on scenes built to break arithmetic and
// bookkeeping rather than to look like a simulation:
//   huge          coordinates near ±1e30 (float), ±1e300 (double), ±2^31 (int32), and the type's
//                 lowest() and max(); with cells of 0.3 the cell indices would overflow;
//   zeros         +0.0 and -0.0 (equal), denormals and the smallest normals;
//   mixed_scales  boxes of width 1e-6 next to boxes of width 1e6;
//   identical     every box the same, moved together, erased and reinserted;
//   touching      unit tiles on an integer lattice: faces, edges and corners touch on every axis;
//   cell_bounds   coordinates on multiples of the test grids' cell sizes (0.3, 1, 3) and one ulp
//                 either side;
//   teleports     small boxes jumping between the far corners of the world and the origin.
// In every frame some calls are bad (NaN, ±inf, inverted boxes, unknown or live keys): each
// must be refused with an error, and change nothing. Every query's events must equal the
// oracle's exactly, the validators must pass, and nothing may be missed or invented.
// Replay one seed with BP_TEST_SEED=<seed>.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "test_support.h"
#include <gtest/gtest.h>

namespace bp::test {
namespace {

using Pairs = std::vector<std::pair<uint64_t, uint64_t>>;

// Every engine family, with the options that stress it most.
template <int K, class T>
struct NamedEngine {
  std::string name;
  std::function<std::unique_ptr<Broadphase<K, T>>()> make;
};

template <int K, class T>
std::vector<NamedEngine<K, T>> AllEngines() {
  std::vector<NamedEngine<K, T>> out;
  auto add = [&out]<class Make>(Make) {
    out.push_back({Make::Name(), [] { return Make::template Create<K, T>(); }});
  };
  add(MakeBruteForce{});
  add(MakeSegmentedSap<32, 7>{});
  add(MakeSegmentedSap<4, -1, 0, 0>{});
  add(MakeSegmentedSap<4, 0, 1, 1>{});
  add(MakeBatchSap<7>{});
  add(MakeBatchSap<0>{});
  add(MakeGrid<CellKind::kSegmented, 0>{});
  add(MakeGrid<CellKind::kBatch, 0>{});
  add(MakeGrid<CellKind::kDense, 0>{});
  // Cells of 0.3: huge coordinates clamp to the edge cells (indices that would overflow).
  add(MakeGrid<CellKind::kSegmented, 3, 64>{});
  add(MakeGrid<CellKind::kDense, 3, 8>{});
  add(MakeGrid<CellKind::kDensePortable, 3, 8>{});
  // Cells of 1 and 3: lattice coordinates lie exactly on cell boundaries.
  add(MakeGrid<CellKind::kBatch, 10, 8>{});
  add(MakeGrid<CellKind::kDense, 30, 16>{});
  add(MakeDynamicOctree<>{});
  add(MakeDynamicOctree<1, 4>{});
  return out;
}

enum class Kind { kHuge, kZeros, kMixedScales, kIdentical, kTouching, kCellBounds, kTeleports };

struct ExtremeScenario {
  const char* name;
  Kind kind;
  int initial;  // objects inserted before the first query
  int frames;   // queries after the first
  int ops;      // at most this many calls per frame
};

constexpr ExtremeScenario kExtremeScenarios[] = {
    {"huge", Kind::kHuge, 80, 25, 40},
    {"zeros", Kind::kZeros, 80, 25, 40},
    {"mixed_scales", Kind::kMixedScales, 120, 25, 50},
    {"identical", Kind::kIdentical, 60, 20, 40},
    {"touching", Kind::kTouching, 100, 25, 50},
    {"cell_bounds", Kind::kCellBounds, 120, 25, 50},
    {"teleports", Kind::kTeleports, 100, 25, 60},
};

template <class Shape>
class ExtremeTest : public ::testing::Test {
 protected:
  static constexpr int K = Shape::K;
  using T = typename Shape::T;
  using L = std::numeric_limits<T>;
  using BoxType = Box<K, T>;
  static constexpr bool kFloat = std::is_floating_point_v<T>;

  void RunAll(const ExtremeScenario& sc) {
    for (const NamedEngine<K, T>& e : AllEngines<K, T>()) {
      for (uint64_t seed : TestSeeds(7000 + static_cast<uint64_t>(sc.kind), 2)) {
        Run(e, sc, seed);
        if (HasFailure()) return;
      }
    }
  }

 private:
  void Run(const NamedEngine<K, T>& e, const ExtremeScenario& sc, uint64_t seed) {
    SCOPED_TRACE("engine=" + e.name + " scenario=" + sc.name + " K=" + std::to_string(K) +
                 " seed=" + std::to_string(seed) +
                 " (replay with BP_TEST_SEED=" + std::to_string(seed) + ")");
    sc_ = &sc;
    rng_.seed(seed);
    engine_ = e.make();
    model_ = {};
    next_key_ = 1;
    for (int i = 0; i < sc.initial; ++i) Insert(next_key_++, NewBox());
    Check(0);
    for (int frame = 1; frame <= sc.frames && !HasFailure(); ++frame) {
      const int ops = static_cast<int>(Below(static_cast<uint64_t>(sc.ops) + 1));
      if (sc.kind == Kind::kIdentical && Below(4) == 0) {
        // Everything moves to one new box together.
        shared_ = NewShared();
        for (const auto& [key, box] : model_.boxes()) {
          (void)box;
          ASSERT_TRUE(engine_->Update(key, shared_).ok());
        }
        for (auto& [key, box] : model_.boxes()) box = shared_;
      }
      for (int i = 0; i < ops && !HasFailure(); ++i) RandomCall();
      Check(frame);
    }
  }

  uint64_t Below(uint64_t n) { return std::uniform_int_distribution<uint64_t>(0, n - 1)(rng_); }
  template <class V>
  V Pick(std::initializer_list<V> values) {
    return values.begin()[Below(values.size())];
  }

  // --- coordinate palettes -------------------------------------------------------------------

  // Near the type's ends: ±1e30 (float), ±1e300 (double), ±2^31 (int32), in eighths, and the
  // ends themselves.
  T Huge() {
    const int k = static_cast<int>(Below(17)) - 8;
    if (Below(6) == 0) return Below(2) == 0 ? L::lowest() : L::max();
    if constexpr (std::is_same_v<T, float>)
      return static_cast<T>(1e30f * static_cast<float>(k) / 8);
    else if constexpr (std::is_same_v<T, double>)
      return 1e300 * k / 8;
    else
      return static_cast<T>(static_cast<int64_t>(L::max()) / 8 * k);
  }
  T Tiny() {
    if constexpr (kFloat) {
      const T d = L::denorm_min();
      return Pick<T>({T(0), -T(0), d, -d, 2 * d, -2 * d, 3 * d, L::min(), -L::min(), L::min() - d,
                      -(L::min() - d)});
    } else {
      return static_cast<T>(static_cast<int>(Below(5)) - 2);
    }
  }
  // Multiples of 0.3, 1 and 3 (the test grids' cell sizes), in the coordinate type, and for
  // floating point one ulp either side.
  T OnCellBound() {
    const double step = Pick<double>({0.3, 1.0, 3.0});
    const double x = step * (static_cast<double>(Below(41)) - 20);
    T v = static_cast<T>(kFloat ? x : std::round(x));
    if constexpr (kFloat) {
      const int side = static_cast<int>(Below(3)) - 1;
      if (side != 0) v = std::nextafter(v, side < 0 ? -L::infinity() : L::infinity());
    }
    return v;
  }
  T Lattice(int n) { return static_cast<T>(static_cast<int>(Below(static_cast<uint64_t>(n)))); }

  BoxType FromValues(T a, T b) {  // sorted into lo <= hi
    return a <= b ? Cube<K, T>(a, b) : Cube<K, T>(b, a);
  }
  // A box whose axes are drawn independently from one palette.
  template <class Draw>
  BoxType PerAxis(Draw&& draw) {
    BoxType box;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      T x = draw(), y = draw();
      box.lo[a] = std::min(x, y);
      box.hi[a] = std::max(x, y);
    }
    return box;
  }
  BoxType NewShared() {
    return PerAxis([&] { return static_cast<T>(static_cast<int>(Below(7)) - 3); });
  }

  BoxType NewBox() {
    switch (sc_->kind) {
      case Kind::kHuge:
        return PerAxis([&] { return Huge(); });
      case Kind::kZeros:
        return PerAxis([&] { return Tiny(); });
      case Kind::kMixedScales: {
        // Small and huge boxes around the same few centres.
        BoxType box;
        const double width = Pick<double>({0, 1e-6, 1e-3, 1, 1e3, 1e6});
        for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
          const double centre = static_cast<double>(Below(9)) - 4;
          if constexpr (kFloat) {
            box.lo[a] = static_cast<T>(centre - width / 2);
            box.hi[a] = static_cast<T>(centre + width / 2);
            if (box.hi[a] < box.lo[a]) box.hi[a] = box.lo[a];
          } else {
            const double w = std::max(1.0, width);
            box.lo[a] = static_cast<T>(centre - std::floor(w / 2));
            box.hi[a] = static_cast<T>(centre + std::ceil(w / 2));
          }
        }
        return box;
      }
      case Kind::kIdentical:
        return shared_;
      case Kind::kTouching: {
        // A unit tile [i, i + 1]^K on a 6^K lattice: neighbours share faces, edges or corners.
        BoxType box;
        for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
          box.lo[a] = Lattice(6);
          box.hi[a] = static_cast<T>(box.lo[a] + 1);
        }
        if (Below(8) == 0) box = FromValues(Lattice(6), Lattice(6));  // a cube or a point
        return box;
      }
      case Kind::kCellBounds:
        return PerAxis([&] { return OnCellBound(); });
      case Kind::kTeleports: {
        // A small box at one of the far corners or at the origin.
        BoxType box;
        for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
          T at = Pick<T>({L::lowest(), static_cast<T>(L::lowest() / 2), T(0),
                          static_cast<T>(L::max() / 2), L::max()});
          T w = static_cast<T>(Below(3));
          if (at == L::max()) at = static_cast<T>(at - w);  // exact in every type: keeps lo <= hi
          if (at >= static_cast<T>(L::max() - w)) w = T(0);
          box.lo[a] = at;
          box.hi[a] = static_cast<T>(at + w);
        }
        return box;
      }
    }
    return BoxType{};
  }

  // A box the engine must refuse: NaN, ±inf (floating point) or lo > hi on some axis.
  BoxType BadBox() {
    BoxType box = NewBox();
    const size_t a = Below(static_cast<size_t>(K));
    const int what = kFloat ? static_cast<int>(Below(4)) : 3;
    if constexpr (kFloat) {
      if (what == 0) (Below(2) == 0 ? box.lo : box.hi)[a] = L::quiet_NaN();
      if (what == 1) box.lo[a] = L::infinity(), box.hi[a] = L::infinity();
      if (what == 2) box.lo[a] = -L::infinity();
    }
    if (what == 3) {
      if (box.lo[a] == box.hi[a]) {
        box.lo[a] = L::max();
        box.hi[a] = L::lowest();
      } else {
        std::swap(box.lo[a], box.hi[a]);
      }
    }
    return box;
  }

  // --- calls ---------------------------------------------------------------------------------

  void Insert(uint64_t key, const BoxType& box) {
    Status s = engine_->Insert(key, box);
    ASSERT_TRUE(s.ok()) << s.ToString();
    model_.boxes()[key] = box;
  }
  uint64_t RandomLiveKey() {
    auto it = model_.boxes().begin();
    std::advance(it, static_cast<long>(Below(model_.boxes().size())));
    return it->first;
  }
  void RandomCall() {
    auto& boxes = model_.boxes();
    const uint64_t dice = Below(100);
    if (boxes.empty() || dice < 15) {
      Insert(next_key_++, NewBox());
    } else if (dice < 25) {
      const uint64_t key = RandomLiveKey();
      ASSERT_TRUE(engine_->Erase(key).ok());
      boxes.erase(key);
    } else if (dice < 35) {
      // A bad call: must be refused and change nothing.
      const uint64_t key = RandomLiveKey();
      Status s;
      switch (Below(4)) {
        case 0:
          s = engine_->Insert(next_key_, BadBox());
          break;
        case 1:
          s = engine_->Update(key, BadBox());
          break;
        case 2:
          s = engine_->Insert(key, NewBox());
          break;  // live key
        default:
          s = engine_->Update(next_key_ + 1000, NewBox());
          break;  // unknown key
      }
      ASSERT_FALSE(s.ok()) << "a bad call was accepted";
    } else {
      const uint64_t key = RandomLiveKey();
      BoxType box = NewBox();
      ASSERT_TRUE(engine_->Update(key, box).ok());
      boxes[key] = box;
    }
  }

  void Check(int frame) {
    SCOPED_TRACE("frame " + std::to_string(frame));
    sink_.Clear();
    engine_->Query(sink_);
    Pairs collides, uncollides;
    model_.Query(&collides, &uncollides);
    ASSERT_EQ(sink_.collides, collides) << "collides differ";
    ASSERT_EQ(sink_.uncollides, uncollides) << "uncollides differ";
    Status v = engine_->Validate();
    ASSERT_TRUE(v.ok()) << v.ToString();
  }

  const ExtremeScenario* sc_ = nullptr;
  std::mt19937_64 rng_;
  std::unique_ptr<Broadphase<K, T>> engine_;
  ModelOracle<K, T> model_;
  RecordingSink<uint64_t> sink_;
  uint64_t next_key_ = 1;
  BoxType shared_ = Cube<K, T>(T(0), T(1));
};

template <int K_, class T_>
struct Shape {
  static constexpr int K = K_;
  using T = T_;
};
using ExtremeShapes = ::testing::Types<Shape<3, float>, Shape<3, double>, Shape<3, int32_t>,
                                       Shape<2, float>, Shape<2, double>, Shape<2, int32_t>>;
TYPED_TEST_SUITE(ExtremeTest, ExtremeShapes);

TYPED_TEST(ExtremeTest, HugeCoordinatesAndOverflowingCellIndices) {
  this->RunAll(kExtremeScenarios[0]);
}
TYPED_TEST(ExtremeTest, SignedZerosAndDenormals) { this->RunAll(kExtremeScenarios[1]); }
TYPED_TEST(ExtremeTest, TinyBoxesNextToHugeOnes) { this->RunAll(kExtremeScenarios[2]); }
TYPED_TEST(ExtremeTest, AllBoxesIdentical) { this->RunAll(kExtremeScenarios[3]); }
TYPED_TEST(ExtremeTest, ExactTouchingOnEveryAxis) { this->RunAll(kExtremeScenarios[4]); }
TYPED_TEST(ExtremeTest, BoxesOnCellBoundaries) { this->RunAll(kExtremeScenarios[5]); }
TYPED_TEST(ExtremeTest, TeleportsAcrossTheWorld) { this->RunAll(kExtremeScenarios[6]); }

}  // namespace
}  // namespace bp::test
