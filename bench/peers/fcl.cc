// FCL 0.7 (Debian's libfcl-dev) as a bpbench peer: DynamicAABBTreeCollisionManager in double.
// An object's AABB is set directly to the scene's box (no geometry transform, so no rounding).
// Refresh is update() over the moved objects and collide(): FCL's broadphase has no persistent
// pair set, so the pairs are enumerated every frame, as a user of its broadphase does.
#include <unordered_map>

#include "peer.h"
#include <fcl/broadphase/broadphase_dynamic_AABB_tree.h>
#include <fcl/geometry/shape/box.h>

namespace bp::bench {
namespace {

// A collision object whose world AABB is given, not computed.
class BoxObject final : public fcl::CollisionObjectd {
 public:
  BoxObject(const std::shared_ptr<fcl::CollisionGeometryd>& shape, uint64_t id)
      : fcl::CollisionObjectd(shape), id_(id) {}
  void SetBox(const PeerBox& box) {
    aabb.min_ = fcl::Vector3d(box.lo[0], box.lo[1], box.lo[2]);
    aabb.max_ = fcl::Vector3d(box.hi[0], box.hi[1], box.hi[2]);
  }
  uint64_t id() const { return id_; }

 private:
  uint64_t id_;
};

class FclPeer final : public Peer {
 public:
  FclPeer() : shape_(std::make_shared<fcl::Boxd>(1, 1, 1)) {}
  ~FclPeer() override { manager_.clear(); }

  void Insert(uint64_t id, const PeerBox& box) override {
    auto obj = std::make_unique<BoxObject>(shape_, id);
    obj->SetBox(box);
    manager_.registerObject(obj.get());
    objects_[id] = std::move(obj);
  }
  void Update(uint64_t id, const PeerBox& box) override {
    objects_.at(id)->SetBox(box);
    moved_.push_back(id);
  }
  void Erase(uint64_t id) override {
    auto it = objects_.find(id);
    manager_.unregisterObject(it->second.get());
    objects_.erase(it);
  }
  void Refresh() override {
    if (!moved_.empty()) {
      // Moved ids, looked up now: an object erased after its move is simply gone.
      std::vector<fcl::CollisionObjectd*> live;
      live.reserve(moved_.size());
      for (uint64_t id : moved_) {
        auto it = objects_.find(id);
        if (it != objects_.end()) live.push_back(it->second.get());
      }
      manager_.update(live);
      moved_.clear();
    }
    pairs_.clear();
    manager_.collide(&pairs_, [](fcl::CollisionObjectd* a, fcl::CollisionObjectd* b, void* data) {
      static_cast<std::vector<std::pair<uint64_t, uint64_t>>*>(data)->emplace_back(
          static_cast<BoxObject*>(a)->id(), static_cast<BoxObject*>(b)->id());
      return false;  // keep going
    });
  }
  void ForEachCandidate(const std::function<void(uint64_t, uint64_t)>& f) override {
    for (const auto& [a, b] : pairs_) f(a, b);
  }

 private:
  std::shared_ptr<fcl::CollisionGeometryd> shape_;
  fcl::DynamicAABBTreeCollisionManagerd manager_;
  std::unordered_map<uint64_t, std::unique_ptr<BoxObject>> objects_;
  std::vector<uint64_t> moved_;
  std::vector<std::pair<uint64_t, uint64_t>> pairs_;
};

}  // namespace

void AddFclPeers(std::vector<PeerInfo>* out) {
  out->push_back(
      {"fcl_dynamic_tree", "FCL 0.7 DynamicAABBTreeCollisionManager", 0, "",
       [](const PeerWorld&) -> std::unique_ptr<Peer> { return std::make_unique<FclPeer>(); }});
}

}  // namespace bp::bench
