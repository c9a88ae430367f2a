// Peer broadphase libraries behind one small interface, so that bpbench can drive them through
// the same scenes as our engines, in the same process: Bullet's btDbvtBroadphase and
// bt32BitAxisSweep3, FCL's DynamicAABBTreeCollisionManager and CGAL's box_intersection_d. Each
// adapter is compiled only when its Debian package is installed (bench/CMakeLists.txt).
//
// A peer keeps its own structure up to date (Insert/Update/Erase, then Refresh: the timed part)
// and lists the candidate pairs it holds afterwards (ForEachCandidate: untimed). Candidates may
// be a superset of the exact set (Bullet keeps the pairs of its fattened or quantised boxes); the
// driver filters them with the exact closed-interval test before hashing.
//
// Thread safety: none; one peer per thread.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "bp/workload.h"

namespace bp::bench {

/// A 3-D box in double (2-D scenes pad the third axis with [0, 1]).
struct PeerBox {
  std::array<double, 3> lo{}, hi{};
};

/// What a peer may need to know before the first insert: the world's bounds (axis sweep).
struct PeerWorld {
  PeerBox bounds;
  uint32_t max_objects = 0;  ///< most objects alive at once
};

class Peer {
 public:
  virtual ~Peer() = default;
  virtual void Insert(uint64_t id, const PeerBox& box) = 0;
  virtual void Update(uint64_t id, const PeerBox& box) = 0;
  virtual void Erase(uint64_t id) = 0;
  /// Brings the library's pair set up to date with the calls since the last Refresh.
  virtual void Refresh() = 0;
  /// Calls f(a, b) once for every pair the library holds after Refresh.
  virtual void ForEachCandidate(const std::function<void(uint64_t, uint64_t)>& f) = 0;
};

/// One peer library: its name, what it is, and a factory.
struct PeerInfo {
  std::string name;         ///< bpbench's name: bullet_dbvt, bullet_sap, fcl_dynamic_tree, cgal
  std::string description;  ///< the library's class or function
  /// Objects above which a run is skipped (0: no limit), with the reason.
  uint32_t max_objects = 0;
  std::string limit_reason;
  std::function<std::unique_ptr<Peer>(const PeerWorld&)> make;
};

/// The peers compiled into this bpbench.
const std::vector<PeerInfo>& Peers();

/// The peers named in list ("all", or names separated by commas), appended to out; false on a
/// name this build lacks, which *out_unknown then holds.
bool SelectPeers(const std::string& list, std::vector<const PeerInfo*>* out,
                 std::string* out_unknown);

/// The exact closed-box test the drivers filter the peers' candidates with.
bool Overlap(const PeerBox& a, const PeerBox& b);

/// What a peer's runs through a scene measured, in the terms of bpbench's own results: frame
/// times (the peer's updates and Refresh, timed; the exact filter and hashing, untimed), and the
/// exact overlap set after every frame as WORKLOADS.md hashes it.
struct PeerRun {
  std::vector<double> frame_ms;     ///< all frames of all repeats
  std::vector<double> run_medians;  ///< one per repeat
  double build_ms = 0;              ///< first repeat: inserting frame 0 and the first Refresh
  uint64_t pairs0 = 0, pairs = 0, collides = 0, uncollides = 0, set_hash = 0, chain = 0;
  uint64_t candidates = 0;  ///< pairs the peer held, summed over the frames of the first repeat
  uint64_t duplicates = 0;  ///< candidate pairs listed more than once (frames 1.., first repeat)
};

/// Drives the peer through `frames` frames of the scene, `repeats` times, with the scene's boxes
/// converted as an engine of coordinate type coord ("float", "double" or "int32") sees them.
/// progress: called after every frame with (repeat, frame).
PeerRun RunPeer(const PeerInfo& peer, const workload::SceneParams& params, int frames, int repeats,
                const std::string& coord, const std::function<void(int, int)>& progress);

// Registration hooks of the adapters (each defined only when its library is compiled in).
void AddBulletPeers(std::vector<PeerInfo>* out);
void AddFclPeers(std::vector<PeerInfo>* out);
void AddCgalPeers(std::vector<PeerInfo>* out);

}  // namespace bp::bench
