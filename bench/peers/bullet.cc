// Bullet 3 (Debian's libbullet-dev, single precision) as a bpbench peer: btDbvtBroadphase (two
// dynamic AABB trees with fattened boxes) and bt32BitAxisSweep3 (incremental sweep and prune over
// quantised coordinates), each with Bullet's defaults: the hashed pair cache, and for the axis
// sweep its raycast accelerator (a btDbvtBroadphase kept up to date beside it), as a Bullet user
// constructs them. Refresh is
// calculateOverlappingPairs; the cache then holds every pair of overlapping fat or quantised
// boxes, a superset of the exact set.
#include <unordered_map>

#include "peer.h"
#include <btBulletCollisionCommon.h>

namespace bp::bench {
namespace {

btVector3 Vec(const std::array<double, 3>& v) {
  return btVector3(static_cast<btScalar>(v[0]), static_cast<btScalar>(v[1]),
                   static_cast<btScalar>(v[2]));
}

uint64_t IdOf(const btBroadphaseProxy* proxy) {
  return static_cast<uint64_t>(reinterpret_cast<uintptr_t>(proxy->m_clientObject));
}

class BulletPeer final : public Peer {
 public:
  explicit BulletPeer(std::unique_ptr<btBroadphaseInterface> broadphase)
      : dispatcher_(&config_), broadphase_(std::move(broadphase)) {}
  ~BulletPeer() override {
    for (auto& [id, proxy] : proxies_) broadphase_->destroyProxy(proxy, &dispatcher_);
  }

  void Insert(uint64_t id, const PeerBox& box) override {
    // The id travels as the proxy's user pointer (ids are below 2^48 in every scene).
    void* user = reinterpret_cast<void*>(static_cast<uintptr_t>(id));
    proxies_[id] = broadphase_->createProxy(Vec(box.lo), Vec(box.hi), BOX_SHAPE_PROXYTYPE, user,
                                            btBroadphaseProxy::DefaultFilter,
                                            btBroadphaseProxy::AllFilter, &dispatcher_);
  }
  void Update(uint64_t id, const PeerBox& box) override {
    broadphase_->setAabb(proxies_.at(id), Vec(box.lo), Vec(box.hi), &dispatcher_);
  }
  void Erase(uint64_t id) override {
    auto it = proxies_.find(id);
    broadphase_->destroyProxy(it->second, &dispatcher_);
    proxies_.erase(it);
  }
  void Refresh() override { broadphase_->calculateOverlappingPairs(&dispatcher_); }
  void ForEachCandidate(const std::function<void(uint64_t, uint64_t)>& f) override {
    btBroadphasePairArray& pairs =
        broadphase_->getOverlappingPairCache()->getOverlappingPairArray();
    for (int i = 0; i < pairs.size(); ++i) f(IdOf(pairs[i].m_pProxy0), IdOf(pairs[i].m_pProxy1));
  }

 private:
  btDefaultCollisionConfiguration config_;
  btCollisionDispatcher dispatcher_;
  std::unique_ptr<btBroadphaseInterface> broadphase_;
  std::unordered_map<uint64_t, btBroadphaseProxy*> proxies_;
};

}  // namespace

void AddBulletPeers(std::vector<PeerInfo>* out) {
  out->push_back({"bullet_dbvt", "Bullet 3.24 btDbvtBroadphase", 0, "",
                  [](const PeerWorld&) -> std::unique_ptr<Peer> {
                    return std::make_unique<BulletPeer>(std::make_unique<btDbvtBroadphase>());
                  }});
  out->push_back({"bullet_sap", "Bullet 3.24 bt32BitAxisSweep3", 20000,
                  "its build takes minutes above about 20k objects (WORKLOADS.md)",
                  [](const PeerWorld& world) -> std::unique_ptr<Peer> {
                    unsigned handles = std::max<unsigned>(world.max_objects + 2, 16);
                    return std::make_unique<BulletPeer>(std::make_unique<bt32BitAxisSweep3>(
                        Vec(world.bounds.lo), Vec(world.bounds.hi), handles));
                  }});
}

}  // namespace bp::bench
