// bp::workload implementation: see bp/workload.h and docs/WORKLOADS.md.
// Compiled with -ffp-contract=off: every floating-point operation below is rounded separately,
// exactly as the specification's text reads, so the scene is bit-exact.
#include "bp/workload.h"

#include <algorithm>
#include <cmath>
#include <string_view>

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

const char* ShapeName(Shape shape) {
  switch (shape) {
    case Shape::kUniform:
      return "uniform";
    case Shape::kClustered:
      return "clustered";
    case Shape::kMixed:
      return "mixed";
    case Shape::kFast:
      return "fast";
  }
  return "?";
}

bool ParseShape(const char* name, Shape* shape) {
  for (Shape s : {Shape::kUniform, Shape::kClustered, Shape::kMixed, Shape::kFast}) {
    if (std::string_view(name) == ShapeName(s)) {
      *shape = s;
      return true;
    }
  }
  return false;
}

Scene::Scene(const SceneParams& params) : params_(params), rng_(params.seed) {
  const double w = params_.width;
  const double n = static_cast<double>(params_.n);
  // The mean of width^dim over the objects: w^dim, or for kMixed the log-uniform mean
  // (max^k - min^k) / (k ln(max / min)) in units of w^k.
  double mean_volume = params_.dim == 2 ? w * w : w * w * w;
  if (params_.shape == Shape::kMixed) {
    const double k = params_.dim;
    const double lo = params_.min_width, hi = params_.max_width;
    mean_volume *=
        hi > lo ? (std::pow(hi, k) - std::pow(lo, k)) / (k * std::log(hi / lo)) : std::pow(lo, k);
  }
  if (params_.dim == 2) {
    side_ = std::sqrt(n * mean_volume / params_.density);
  } else {
    side_ = std::cbrt(n * mean_volume / params_.density);
  }
  lim_ = side_ - w;
  speed_ = params_.speed_fraction * w;
  if (params_.shape == Shape::kClustered) {
    const double share =
        params_.dim == 2 ? std::sqrt(params_.cluster_volume) : std::cbrt(params_.cluster_volume);
    const double cluster_side = std::min(side_, std::max(side_ * share, w + 2 * speed_));
    cluster_.base = (side_ - cluster_side) / 2;
    cluster_.lim = cluster_side - w;
  }
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
    RandomPosition(i, slot);
    if (i < params_.moving) RandomVelocity(i, slot);
    initial_.push_back(BoxOf(slot));
    initial_.back().moves = i < params_.moving;
  }
  next_id_ = params_.n;
}

Scene::Region Scene::RegionOf(uint32_t slot_index) const {
  if (params_.shape == Shape::kClustered &&
      slot_index % 10 < static_cast<uint32_t>(std::lround(params_.cluster_fraction * 10))) {
    return cluster_;
  }
  return Region{0.0, lim_};
}

double Scene::SpeedOf(uint32_t slot_index, const Slot& slot) const {
  switch (params_.shape) {
    case Shape::kMixed:
      return params_.speed_fraction * slot.w;
    case Shape::kFast:
      if (slot_index % 10 == 0) return std::min(params_.fast_speed * params_.width, lim_ / 2);
      return speed_;
    default:
      return speed_;
  }
}

void Scene::RandomPosition(uint32_t slot_index, Slot& slot) {
  double lim = lim_, base = 0;
  slot.w = params_.width;
  if (params_.shape == Shape::kMixed) {
    // Log-uniform in [min_width, max_width], at most half the side so that it fits.
    const double u = rng_.Uniform01();
    const double lo = std::log(params_.min_width), hi = std::log(params_.max_width);
    slot.w = std::min(params_.width * std::exp(lo + u * (hi - lo)), side_ / 2);
    lim = side_ - slot.w;
  } else {
    const Region r = RegionOf(slot_index);
    base = r.base;
    lim = r.lim;
  }
  for (int a = 0; a < 3; ++a) {
    slot.p[static_cast<size_t>(a)] = a < params_.dim ? base + rng_.Uniform01() * lim : 0.0;
  }
  slot.v = {0.0, 0.0, 0.0};
}

void Scene::RandomVelocity(uint32_t slot_index, Slot& slot) {
  const auto dim = static_cast<size_t>(params_.dim);
  double r2 = 0;
  do {
    r2 = 0;
    for (size_t a = 0; a < dim; ++a) {
      slot.v[a] = 2 * rng_.Uniform01() - 1;
    }
    for (size_t a = 0; a < dim; ++a) r2 += slot.v[a] * slot.v[a];
  } while (r2 > 1 || r2 < 1e-6);
  const double scale = SpeedOf(slot_index, slot) / std::sqrt(r2);
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
      box.hi[i] = params_.shape == Shape::kMixed ? Snap(slot.p[i] + slot.w) : box.lo[i] + fw;
    } else {
      box.lo[i] = 0.0f;
      box.hi[i] = fw;
    }
  }
  return box;
}

// The specification's reflection, relative to the region's base: with base 0 (the uniform
// scene) p - 0 and 0 + x are exact, so the golden scene is unchanged.
void Scene::Bounce(Slot& slot, double base, double lim, size_t dim) {
  for (size_t a = 0; a < dim; ++a) {
    double x = (slot.p[a] - base) + slot.v[a];
    if (x < 0) {
      x = -x;
      slot.v[a] = -slot.v[a];
    } else if (x > lim) {
      x = 2 * lim - x;
      slot.v[a] = -slot.v[a];
    }
    slot.p[a] = base + x;
  }
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
    RandomPosition(i, slot);
    if (i < params_.moving) RandomVelocity(i, slot);
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
    const Region r = params_.shape == Shape::kMixed ? Region{0.0, side_ - slot.w} : RegionOf(i);
    Bounce(slot, r.base, r.lim, dim);
    out->updates.push_back(BoxOf(slot));
  }
  for (uint32_t i : replaced) chosen_[i] = 0;
}

}  // namespace bp::workload
