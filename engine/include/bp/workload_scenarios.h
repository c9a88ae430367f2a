// The named scenarios of docs/WORKLOADS.md and their golden values (seed 12345), shared by the
// golden tests and bpbench. Two independent implementations of WORKLOADS.md agree on these.
//
// Thread safety: constant data.
#pragma once

#include <cstdint>
#include <string_view>

#include "bp/workload.h"

namespace bp::workload {

/// One row of the golden table: the scene and what its 100 frames must produce.
struct GoldenScenario {
  std::string_view name;
  int dim;
  uint32_t n, moving, churn, frames;
  uint64_t pairs_frame0, pairs_end;
  uint64_t collides, uncollides;  // summed over frames 1..frames
  uint64_t set_hash_end, chain;

  SceneParams Params() const {
    SceneParams p;
    p.dim = dim;
    p.n = n;
    p.moving = moving;
    p.churn = churn;
    return p;
  }
};

inline constexpr GoldenScenario kGoldenScenarios[] = {
    {"S2a", 3, 3000, 150, 1, 100, 618, 616, 461, 463, 0x4c5481efcc6b8142, 0x6274793c8a9520a7},
    {"S2b", 3, 3000, 150, 10, 100, 618, 606, 814, 826, 0x99bc3a682398a0b2, 0x56762576cf62e0f8},
    {"S2c", 3, 3000, 150, 40, 100, 618, 642, 2096, 2072, 0x24f0cde31b8772da, 0xf9bf9debdb1ec8ad},
    {"S1-10k", 3, 10000, 1000, 50, 100, 2091, 2036, 4844, 4899, 0x452f9a10ed565172,
     0x8345d52362006c12},
    {"S1-100k", 3, 100000, 10000, 500, 100, 20185, 20225, 48547, 48507, 0x9daf7bc27bdb0bf0,
     0x116364493e9a2610},
    {"S1-200k", 3, 200000, 20000, 1000, 100, 40554, 40327, 96223, 96450, 0x5f410c55499b8fec,
     0x00f104cfea5b41a5},
    {"S3", 3, 100000, 100000, 0, 100, 20087, 20237, 194523, 194373, 0x88b27919275dcb9d,
     0x8fb8ee8db6ed1fca},
    {"S4", 3, 100000, 1000, 50, 100, 20014, 20169, 4948, 4793, 0x4e3138f6f44efe52,
     0x6d6113b0730825f8},
    {"2-D", 2, 10000, 1000, 50, 100, 975, 980, 2159, 2154, 0x147c669596380529, 0xf11fe373f509505a},
};

/// The golden row named name, or nullptr.
inline const GoldenScenario* FindGolden(std::string_view name) {
  for (const GoldenScenario& g : kGoldenScenarios) {
    if (g.name == name) return &g;
  }
  return nullptr;
}

}  // namespace bp::workload
