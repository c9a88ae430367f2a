// bp::workload implementation: see bp/workload.h and shared/WORKLOADS.md.
// Compiled with -ffp-contract=off: every floating-point operation below is rounded separately,
// exactly as the specification's text reads, so the scene is bit-exact.
#include "bp/workload.h"

#include <algorithm>
#include <cmath>

namespace bp::workload {

namespace {

__extension__ using U128 = unsigned __int128;

inline uint64_t Rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

}  // namespace

uint64_t Mix64(uint64_t z) {
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
  return z ^ (z >> 31);
}

uint64_t SplitMix64(uint64_t& state) {
  state += 0x9E3779B97F4A7C15ULL;
  return Mix64(state);
}

Xoshiro256::Xoshiro256(uint64_t seed) {
  uint64_t state = seed;
  for (auto& word : s_) word = SplitMix64(state);
}

uint64_t Xoshiro256::Next() {
  const uint64_t result = Rotl(s_[1] * 5, 7) * 9;
  const uint64_t t = s_[1] << 17;
  s_[2] ^= s_[0];
  s_[3] ^= s_[1];
  s_[1] ^= s_[2];
  s_[0] ^= s_[3];
  s_[2] ^= t;
  s_[3] = Rotl(s_[3], 45);
  return result;
}

double Xoshiro256::Uniform01() { return static_cast<double>(Next() >> 11) * 0x1.0p-53; }

uint64_t Xoshiro256::Below(uint64_t bound) {
  return static_cast<uint64_t>((static_cast<U128>(Next()) * bound) >> 64);
}

Scene::Scene(const SceneParams& params) : params_(params), rng_(params.seed) {
  const double w = params_.width;
  const double n = static_cast<double>(params_.n);
  if (params_.dim == 2) {
    side_ = std::sqrt(n * (w * w) / params_.density);
  } else {
    side_ = std::cbrt(n * (w * w * w) / params_.density);
  }
  lim_ = side_ - w;
  speed_ = params_.speed_fraction * w;
  int e = 0;
  (void)std::frexp(2 * side_ + 2 * w, &e);  // 2 side + 2 w < 2^e
  grid_ = std::ldexp(1.0, e - 24);
  inv_grid_ = std::ldexp(1.0, 24 - e);

  slots_.resize(params_.n);
  chosen_.assign(params_.n, 0);
  initial_.reserve(params_.n);
  for (uint32_t i = 0; i < params_.n; ++i) {
    Slot& slot = slots_[i];
    slot.id = i;
    RandomPosition(slot);
    if (i < params_.moving) RandomVelocity(slot);
    initial_.push_back(BoxOf(slot));
    initial_.back().moves = i < params_.moving;
  }
  next_id_ = params_.n;
}

void Scene::RandomPosition(Slot& slot) {
  for (int a = 0; a < 3; ++a) {
    slot.p[static_cast<size_t>(a)] = a < params_.dim ? rng_.Uniform01() * lim_ : 0.0;
  }
  slot.v = {0.0, 0.0, 0.0};
}

void Scene::RandomVelocity(Slot& slot) {
  const auto dim = static_cast<size_t>(params_.dim);
  double r2 = 0;
  do {
    r2 = 0;
    for (size_t a = 0; a < dim; ++a) {
      slot.v[a] = 2 * rng_.Uniform01() - 1;
    }
    for (size_t a = 0; a < dim; ++a) r2 += slot.v[a] * slot.v[a];
  } while (r2 > 1 || r2 < 1e-6);
  const double scale = speed_ / std::sqrt(r2);
  for (size_t a = 0; a < dim; ++a) slot.v[a] *= scale;
}

float Scene::Snap(double x) const {
  return static_cast<float>(std::floor(x * inv_grid_ + 0.5) * grid_);
}

SceneBox Scene::BoxOf(const Slot& slot) const {
  SceneBox box;
  box.id = slot.id;
  const auto fw = static_cast<float>(params_.width);
  for (int a = 0; a < 3; ++a) {
    const auto i = static_cast<size_t>(a);
    if (a < params_.dim) {
      box.lo[i] = Snap(slot.p[i]);
      box.hi[i] = box.lo[i] + fw;
    } else {
      box.lo[i] = 0.0f;
      box.hi[i] = fw;
    }
  }
  return box;
}

void Scene::NextFrame(FrameOps* out) {
  out->Clear();
  const uint32_t n = params_.n;
  const uint32_t churn = std::min(params_.churn, n);
  std::vector<uint32_t> replaced;
  replaced.reserve(churn);
  // 1. Churn.
  while (replaced.size() < churn) {
    const auto i = static_cast<uint32_t>(rng_.Below(n));
    if (chosen_[i]) continue;
    chosen_[i] = 1;
    replaced.push_back(i);
    Slot& slot = slots_[i];
    out->erases.push_back(slot.id);
    slot.id = next_id_++;
    RandomPosition(slot);
    if (i < params_.moving) RandomVelocity(slot);
    out->inserts.push_back(BoxOf(slot));
    out->inserts.back().moves = i < params_.moving;
  }
  // 2. Motion.
  const uint32_t moving = std::min(params_.moving, n);
  const auto dim = static_cast<size_t>(params_.dim);
  out->updates.reserve(moving);
  for (uint32_t i = 0; i < moving; ++i) {
    if (chosen_[i]) continue;
    Slot& slot = slots_[i];
    for (size_t a = 0; a < dim; ++a) {
      double x = slot.p[a] + slot.v[a];
      if (x < 0) {
        x = -x;
        slot.v[a] = -slot.v[a];
      } else if (x > lim_) {
        x = 2 * lim_ - x;
        slot.v[a] = -slot.v[a];
      }
      slot.p[a] = x;
    }
    out->updates.push_back(BoxOf(slot));
  }
  for (uint32_t i : replaced) chosen_[i] = 0;
}

}  // namespace bp::workload
