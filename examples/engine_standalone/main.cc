// The engine alone: three boxes, two queries, events printed, through an engine's class
// (bp/segmented_sap.h, header-only) and through an engine chosen by name (bp::NewEngine,
// broadphase::engines). Exits 0 iff both report the right events.
#include <cstdint>
#include <cstdio>
#include <memory>
#include <utility>
#include <vector>

#include "bp/engines.h"
#include "bp/segmented_sap.h"

namespace {

struct Printer final : bp::EventSink<uint64_t> {
  void Collide(const uint64_t& a, const uint64_t& b) override {
    std::printf("collide %llu %llu\n", static_cast<unsigned long long>(a),
                static_cast<unsigned long long>(b));
    events.emplace_back(a, b);
  }
  void Uncollide(const uint64_t& a, const uint64_t& b) override {
    std::printf("uncollide %llu %llu\n", static_cast<unsigned long long>(a),
                static_cast<unsigned long long>(b));
    events.emplace_back(b, a);  // reversed, to tell the kinds apart below
  }
  std::vector<std::pair<uint64_t, uint64_t>> events;
};

// Three boxes, two queries; true iff the engine reports exactly the expected events.
bool Run(bp::Broadphase<3, float>& engine) {
  std::printf("%s:\n", engine.Name().c_str());
  Printer sink;
  bool ok = engine.Insert(1, {{0, 0, 0}, {1, 1, 1}}).ok() &&
            engine.Insert(2, {{1, 0, 0}, {2, 1, 1}}).ok() &&  // touches 1
            engine.Insert(3, {{5, 5, 5}, {6, 6, 6}}).ok();
  engine.Query(sink);
  ok = ok && engine.Update(2, {{4.5f, 4.5f, 4.5f}, {5, 5, 5}}).ok();  // leaves 1, touches 3
  engine.Query(sink);
  std::vector<std::pair<uint64_t, uint64_t>> expected = {{1, 2}, {2, 1}, {2, 3}};
  return ok && sink.events == expected;
}

}  // namespace

int main() {
  bp::SegmentedSap<3, float> sap;
  bp::EngineSpec spec;
  spec.algorithm = "grid_dense";
  std::unique_ptr<bp::Broadphase<3, float>> grid = bp::NewEngine<3, float>(spec);
  return Run(sap) && grid != nullptr && Run(*grid) ? 0 : 1;
}
