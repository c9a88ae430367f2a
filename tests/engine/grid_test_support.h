// What the grid's white-box tests share: a twin of an engine and brute force that must report
// the same events on every query, cubes, and a random scene far from or near the origin.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "test_support.h"
#include <gtest/gtest.h>

#include "bp/grid.h"
#include "bp/scene_runner.h"
#include "bp/segmented_sap.h"
#include "bp/workload.h"

namespace bp::test {

using SegmentedGridCore = detail::GridCore<detail::SegmentedSapCore<3, float>>;

// Runs the same calls on an engine and on brute force; every query must report the same events.
template <int K, class T, class Engine>
class Twin {
 public:
  using BoxType = Box<K, T>;
  explicit Twin(Engine* engine) : engine_(engine) {}

  void Insert(uint64_t key, const BoxType& b) {
    ASSERT_TRUE(engine_->Insert(key, b).ok());
    ASSERT_TRUE(oracle_.Insert(key, b).ok());
  }
  void Update(uint64_t key, const BoxType& b) {
    ASSERT_TRUE(engine_->Update(key, b).ok());
    ASSERT_TRUE(oracle_.Update(key, b).ok());
  }
  void Erase(uint64_t key) {
    ASSERT_TRUE(engine_->Erase(key).ok());
    ASSERT_TRUE(oracle_.Erase(key).ok());
  }
  void Query() {
    RecordingSink<uint64_t> got, want;
    engine_->Query(got);
    oracle_.Query(want);
    ASSERT_EQ(got.uncollides, want.uncollides) << "query " << queries_;
    ASSERT_EQ(got.collides, want.collides) << "query " << queries_;
    ASSERT_EQ(engine_->GetStats().overlaps, oracle_.GetStats().overlaps);
    events_ += got.collides.size() + got.uncollides.size();
    ++queries_;
  }
  size_t events() const { return events_; }

 private:
  Engine* engine_;
  BruteForce<K, T> oracle_;
  size_t queries_ = 0;
  size_t events_ = 0;
};

// A cube from lo, extent wide on every axis (test_support.h's Cube takes both corners).
template <int K, class T>
Box<K, T> CubeAt(T lo, T extent) {
  Box<K, T> b;
  for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
    b.lo[a] = lo;
    b.hi[a] = static_cast<T>(lo + extent);
  }
  return b;
}

// A random scene around `origin` with boxes of about `unit`, moved, churned and teleported.
template <int K, class T, class Engine>
void RandomScene(Engine* engine, double origin, double unit, uint64_t seed, int objects = 120,
                 int frames = 30) {
  SCOPED_TRACE("origin " + std::to_string(origin) + " unit " + std::to_string(unit));
  Twin<K, T, Engine> twin(engine);
  std::mt19937_64 rng(seed);
  auto coord = [&](double span) {
    double x = origin + std::uniform_real_distribution<double>(-span, span)(rng) * unit;
    return static_cast<T>(x);
  };
  auto box = [&]() {
    Box<K, T> b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      T lo = coord(8);
      T hi = static_cast<T>(static_cast<double>(lo) +
                            std::uniform_real_distribution<double>(0, 2)(rng) * unit);
      b.lo[a] = lo;
      b.hi[a] = hi < lo ? lo : hi;
    }
    return b;
  };
  std::vector<uint64_t> live;
  uint64_t next = 1;
  for (int i = 0; i < objects; ++i) {
    twin.Insert(next, box());
    live.push_back(next++);
  }
  twin.Query();
  for (int f = 0; f < frames && !::testing::Test::HasFailure(); ++f) {
    for (int i = 0; i < objects / 4; ++i) {
      size_t j = rng() % live.size();
      switch (rng() % 5) {
        case 0:
          twin.Erase(live[j]);
          live[j] = next;
          twin.Insert(next++, box());
          break;
        default:
          twin.Update(live[j], box());
      }
    }
    twin.Query();
  }
  EXPECT_GT(twin.events(), 0u);
}

}  // namespace bp::test
