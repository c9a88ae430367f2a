// CGAL 5.5 (Debian's libcgal-dev) as a bpbench peer: box_self_intersection_d over every live box,
// closed boxes, recomputed from scratch at every Refresh (CGAL keeps no state between calls).
#include <unordered_map>

#include "peer.h"
#include <CGAL/Box_intersection_d/Box_with_info_d.h>
#include <CGAL/box_intersection_d.h>

namespace bp::bench {
namespace {

using CgalBox = CGAL::Box_intersection_d::Box_with_info_d<double, 3, uint64_t>;

CgalBox Make(uint64_t id, const PeerBox& box) {
  double lo[3] = {box.lo[0], box.lo[1], box.lo[2]};
  double hi[3] = {box.hi[0], box.hi[1], box.hi[2]};
  return CgalBox(lo, hi, id);
}

class CgalPeer final : public Peer {
 public:
  void Insert(uint64_t id, const PeerBox& box) override {
    index_[id] = boxes_.size();
    boxes_.push_back(Make(id, box));
  }
  void Update(uint64_t id, const PeerBox& box) override { boxes_[index_.at(id)] = Make(id, box); }
  void Erase(uint64_t id) override {
    auto it = index_.find(id);
    const size_t i = it->second;
    index_.erase(it);
    if (i + 1 != boxes_.size()) {
      boxes_[i] = boxes_.back();
      index_[boxes_[i].info()] = i;
    }
    boxes_.pop_back();
  }
  void Refresh() override {
    pairs_.clear();
    // CGAL permutes the range it is given: hand it a copy, so that index_ stays valid.
    scratch_.assign(boxes_.begin(), boxes_.end());
    CGAL::box_self_intersection_d(
        scratch_.begin(), scratch_.end(),
        [this](const CgalBox& a, const CgalBox& b) { pairs_.emplace_back(a.info(), b.info()); },
        std::ptrdiff_t{10}, CGAL::Box_intersection_d::CLOSED);
  }
  void ForEachCandidate(const std::function<void(uint64_t, uint64_t)>& f) override {
    for (const auto& [a, b] : pairs_) f(a, b);
  }

 private:
  std::vector<CgalBox> boxes_, scratch_;
  std::unordered_map<uint64_t, size_t> index_;
  std::vector<std::pair<uint64_t, uint64_t>> pairs_;
};

}  // namespace

void AddCgalPeers(std::vector<PeerInfo>* out) {
  out->push_back(
      {"cgal", "CGAL 5.5 box_self_intersection_d", 0, "",
       [](const PeerWorld&) -> std::unique_ptr<Peer> { return std::make_unique<CgalPeer>(); }});
}

}  // namespace bp::bench
