// The registry of peer libraries compiled into bpbench (see peer.h).
#include <algorithm>
#include <chrono>
#include <iterator>
#include <sstream>
#include <unordered_map>

#include "peer.h"

#include "bp/box.h"

namespace bp::bench {

const std::vector<PeerInfo>& Peers() {
  static const std::vector<PeerInfo> peers = [] {
    std::vector<PeerInfo> out;
#ifdef BP_HAVE_BULLET
    AddBulletPeers(&out);
#endif
#ifdef BP_HAVE_FCL
    AddFclPeers(&out);
#endif
#ifdef BP_HAVE_CGAL
    AddCgalPeers(&out);
#endif
    return out;
  }();
  return peers;
}

bool SelectPeers(const std::string& list, std::vector<const PeerInfo*>* out,
                 std::string* out_unknown) {
  std::stringstream names(list);
  for (std::string name; std::getline(names, name, ',');) {
    if (name.empty()) continue;
    bool found = false;
    for (const auto& p : Peers()) {
      if (name == "all" || name == p.name) {
        out->push_back(&p);
        found = true;
      }
    }
    if (!found && name != "all") {
      *out_unknown = name;
      return false;
    }
  }
  return true;
}

bool Overlap(const PeerBox& a, const PeerBox& b) {
  for (size_t k = 0; k < 3; ++k) {
    if (!(a.lo[k] <= b.hi[k] && b.lo[k] <= a.hi[k])) return false;
  }
  return true;
}

}  // namespace bp::bench

namespace bp::bench {
namespace {

using Clock = std::chrono::steady_clock;

double Ms(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t m = v.size() / 2;
  return v.size() % 2 != 0 ? v[m] : 0.5 * (v[m - 1] + v[m]);
}

// The scene box as an engine of <K, T> sees it, widened to double and padded to 3-D.
template <int K, Coordinate T>
PeerBox Convert(const workload::SceneBox& b, double grid, double offset) {
  const Box<K, T> e = workload::ToBox<K, T>(b, grid, offset);
  PeerBox out;
  for (size_t a = 0; a < 3; ++a) {
    out.lo[a] = a < static_cast<size_t>(K) ? static_cast<double>(e.lo[a]) : 0.0;
    out.hi[a] = a < static_cast<size_t>(K) ? static_cast<double>(e.hi[a]) : 1.0;
  }
  return out;
}

template <int K, Coordinate T>
PeerRun RunTyped(const PeerInfo& info, const workload::SceneParams& params, int frames, int repeats,
                 const std::function<void(int, int)>& progress) {
  PeerRun r;
  for (int rep = 0; rep < repeats; ++rep) {
    workload::Scene scene(params);
    const double grid = scene.grid(), offset = params.offset;
    auto convert = [&](const workload::SceneBox& b) { return Convert<K, T>(b, grid, offset); };
    // The world: the scene's cube, one width of slack, as the engine's coordinates.
    workload::SceneBox world_box;
    const auto side = static_cast<float>(scene.side() + params.width);
    world_box.lo = {-1.0f, -1.0f, -1.0f};
    world_box.hi = {side, side, side};
    PeerWorld world;
    world.bounds = convert(world_box);
    world.bounds.lo[2] = std::min(world.bounds.lo[2], -1.0);
    world.bounds.hi[2] = std::max(world.bounds.hi[2], 2.0);
    world.max_objects = params.n + params.churn;

    std::unique_ptr<Peer> peer = info.make(world);
    std::unordered_map<uint64_t, PeerBox> live;  // the exact boxes, untimed
    live.reserve(params.n * 2);
    std::vector<uint64_t> pairs, previous, diff;
    uint64_t set_hash = 0;
    workload::HashChain chain;
    // The exact set from the peer's candidates, sorted; counts candidates on the first repeat.
    auto exact = [&] {
      pairs.clear();
      uint64_t candidates = 0;
      peer->ForEachCandidate([&](uint64_t a, uint64_t b) {
        ++candidates;
        if (Overlap(live.at(a), live.at(b))) pairs.push_back(workload::PairKey(a, b));
      });
      std::sort(pairs.begin(), pairs.end());
      const size_t before = pairs.size();
      pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
      set_hash = 0;
      for (uint64_t k : pairs) set_hash += workload::PairHash(k);
      if (rep == 0) {
        r.candidates += candidates;
        r.duplicates += before - pairs.size();
      }
    };

    auto start = Clock::now();
    for (const workload::SceneBox& b : scene.Initial()) peer->Insert(b.id, convert(b));
    peer->Refresh();
    const double build = Ms(start);
    if (rep == 0) r.build_ms = build;
    for (const workload::SceneBox& b : scene.Initial()) live[b.id] = convert(b);
    exact();
    if (rep == 0) r.candidates = r.duplicates = 0;  // per frame: frames 1.. only
    r.pairs0 = pairs.size();
    chain.AddFrame(set_hash);
    uint64_t collides = 0, uncollides = 0;
    std::vector<double> run;
    workload::FrameOps ops;
    for (int f = 1; f <= frames; ++f) {
      scene.NextFrame(&ops);
      start = Clock::now();
      for (uint64_t id : ops.erases) peer->Erase(id);
      for (const workload::SceneBox& b : ops.updates) peer->Update(b.id, convert(b));
      for (const workload::SceneBox& b : ops.inserts) peer->Insert(b.id, convert(b));
      peer->Refresh();
      run.push_back(Ms(start));
      for (uint64_t id : ops.erases) live.erase(id);
      for (const workload::SceneBox& b : ops.updates) live[b.id] = convert(b);
      for (const workload::SceneBox& b : ops.inserts) live[b.id] = convert(b);
      previous.swap(pairs);
      exact();
      diff.clear();
      std::set_difference(pairs.begin(), pairs.end(), previous.begin(), previous.end(),
                          std::back_inserter(diff));
      collides += diff.size();
      diff.clear();
      std::set_difference(previous.begin(), previous.end(), pairs.begin(), pairs.end(),
                          std::back_inserter(diff));
      uncollides += diff.size();
      chain.AddFrame(set_hash);
      if (progress) progress(rep, f);
    }
    r.frame_ms.insert(r.frame_ms.end(), run.begin(), run.end());
    r.run_medians.push_back(Median(run));
    r.pairs = pairs.size();
    r.collides = collides;
    r.uncollides = uncollides;
    r.set_hash = set_hash;
    r.chain = chain.value();
  }
  return r;
}

}  // namespace

PeerRun RunPeer(const PeerInfo& peer, const workload::SceneParams& params, int frames, int repeats,
                const std::string& coord, const std::function<void(int, int)>& progress) {
  const bool planar = params.dim == 2;
  if (coord == "double") {
    return planar ? RunTyped<2, double>(peer, params, frames, repeats, progress)
                  : RunTyped<3, double>(peer, params, frames, repeats, progress);
  }
  if (coord == "int32") {
    return planar ? RunTyped<2, int32_t>(peer, params, frames, repeats, progress)
                  : RunTyped<3, int32_t>(peer, params, frames, repeats, progress);
  }
  return planar ? RunTyped<2, float>(peer, params, frames, repeats, progress)
                : RunTyped<3, float>(peer, params, frames, repeats, progress);
}

}  // namespace bp::bench
