// The engine alone: three boxes, two queries, events printed. Exits 0 iff the events are right.
#include <cstdint>
#include <cstdio>
#include <utility>
#include <vector>

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

}  // namespace

int main() {
  bp::SegmentedSap<3, float> engine;
  Printer sink;
  bool ok = engine.Insert(1, {{0, 0, 0}, {1, 1, 1}}).ok() &&
            engine.Insert(2, {{1, 0, 0}, {2, 1, 1}}).ok() &&  // touches 1
            engine.Insert(3, {{5, 5, 5}, {6, 6, 6}}).ok();
  engine.Query(sink);
  ok = ok && engine.Update(2, {{4.5f, 4.5f, 4.5f}, {5, 5, 5}}).ok();  // leaves 1, touches 3
  engine.Query(sink);
  std::vector<std::pair<uint64_t, uint64_t>> expected = {{1, 2}, {2, 1}, {2, 3}};
  return ok && sink.events == expected ? 0 : 1;
}
