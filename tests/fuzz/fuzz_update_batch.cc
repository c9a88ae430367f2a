// libFuzzer target: the daemon's decode and validation path for UpdateBatch payloads.
//
// Input: one configuration byte, then records of [u16 little-endian length][payload bytes];
// a short last record takes what is left. Bit 0 of the configuration byte picks the
// dimension (2, 3), bits 1-2 the coordinate type (float, double, int32), bits 3-5 the algorithm.
// Each payload goes through exactly what the daemon does with a received sample: AdmitBatch (size,
// protobuf decoding, version, producer, item count), then EngineHost::Apply, then a query. It is
// applied to the chosen engine and to brute force, and the two must agree on everything: the
// rejections (operation, index, id, reason), the counts, the live objects, the events and the
// snapshot of the overlap set.
// Every item of an admitted batch must be counted exactly once, applied or rejected (nothing is
// dropped silently), and every rejection must carry a reason and a message naming the item.
// On a mismatch the target prints what differs and aborts, so libFuzzer saves the input.
// Replaying one input with BP_FUZZ_VERBOSE=1 prints each batch and the events.
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "engine_host.h"

namespace {

using bp::service::ApplyCounts;
using bp::service::EngineHost;
using bp::service::Reject;

[[noreturn]] void Fail(const std::string& what) {
  std::fprintf(stderr, "fuzz_update_batch: %s\n", what.c_str());
  std::abort();
}

std::unique_ptr<EngineHost> MakeHost(int dimension, bp::service::CoordinateType coordinate,
                                     const std::string& algorithm) {
  bp::service::EngineConfig config;
  config.algorithm = algorithm;
  config.dimension = dimension;
  config.coordinate = coordinate;
  config.threads = 1;  // one thread: a run does not depend on the machine's CPUs
  std::unique_ptr<EngineHost> host;
  // A small capacity, so that CAPACITY rejections happen too.
  bp::Status s = bp::service::MakeEngineHost(config, 40, &host);
  if (!s.ok()) Fail("MakeEngineHost: " + s.ToString());
  return host;
}

bool SameReject(const Reject& a, const Reject& b) {
  return a.op == b.op && a.index == b.index && a.id == b.id && a.reason == b.reason &&
         a.message == b.message;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  static const char* const kAlgorithms[] = {"grid_dense",    "grid_segmented_sap", "grid_batch_sap",
                                            "segmented_sap", "batch_sap",          "dynamic_octree",
                                            "grid_dense",    "segmented_sap"};
  const uint8_t config = data[0];
  const int dimension = 2 + (config & 1);
  const auto coordinate = static_cast<bp::service::CoordinateType>((config >> 1 & 3) % 3);
  const std::string algorithm = kAlgorithms[config >> 3 & 7];
  static const bool verbose = std::getenv("BP_FUZZ_VERBOSE") != nullptr;
  if (verbose)
    std::fprintf(stderr, "engine %s, %d-D, coordinate %d\n", algorithm.c_str(), dimension,
                 static_cast<int>(coordinate));
  std::unique_ptr<EngineHost> host = MakeHost(dimension, coordinate, algorithm);
  std::unique_ptr<EngineHost> oracle = MakeHost(dimension, coordinate, "brute_force");

  bp::service::LimitsConfig limits;
  limits.max_batch_bytes = 1 << 16;
  limits.max_batch_items = 300;
  bp::wire::UpdateBatch batch;
  std::vector<Reject> rejects_host, rejects_oracle;
  std::vector<uint64_t> un_host, co_host, un_oracle, co_oracle;
  std::vector<std::pair<uint64_t, uint64_t>> snap_host, snap_oracle;
  size_t at = 1;
  for (int record = 0; record < 16 && at < size; ++record) {
    size_t len = data[at];
    if (at + 1 < size) len |= size_t{data[at + 1]} << 8;
    at += 2;
    len = at <= size ? std::min(len, size - at) : 0;
    std::span<const uint8_t> payload(data + std::min(at, size), len);
    at += len;

    Reject refused;
    const bool admitted = bp::service::AdmitBatch(payload, limits, &batch, &refused);
    if (verbose) {
      std::fprintf(stderr, "record %d: %s\n", record,
                   admitted ? batch.ShortDebugString().c_str() : refused.message.c_str());
    }
    if (!admitted) {
      if (refused.reason == bp::wire::REJECT_REASON_UNSPECIFIED || refused.message.empty())
        Fail("a refused batch without a reason or message");
      continue;
    }
    rejects_host.clear();
    rejects_oracle.clear();
    ApplyCounts counts_host, counts_oracle;
    host->Apply(
        batch, [&](Reject&& r) { rejects_host.push_back(std::move(r)); }, &counts_host);
    oracle->Apply(
        batch, [&](Reject&& r) { rejects_oracle.push_back(std::move(r)); }, &counts_oracle);
    const uint64_t items = static_cast<uint64_t>(batch.inserts().ids_size()) +
                           static_cast<uint64_t>(batch.updates().ids_size()) +
                           static_cast<uint64_t>(batch.erases_size());
    const uint64_t counted =
        counts_host.inserts + counts_host.updates + counts_host.erases + counts_host.rejected;
    if (counted != items) {
      Fail("items " + std::to_string(items) + " but counted " + std::to_string(counted) +
           " (applied or rejected)");
    }
    if (counts_host.rejected != rejects_host.size()) Fail("rejected count != rejections");
    if (counts_host.inserts != counts_oracle.inserts ||
        counts_host.updates != counts_oracle.updates ||
        counts_host.erases != counts_oracle.erases ||
        counts_host.rejected != counts_oracle.rejected) {
      Fail("counts differ from brute force");
    }
    if (rejects_host.size() != rejects_oracle.size()) Fail("rejections differ from brute force");
    for (size_t i = 0; i < rejects_host.size(); ++i) {
      const Reject& r = rejects_host[i];
      if (!SameReject(r, rejects_oracle[i])) {
        Fail("rejection " + std::to_string(i) + " differs: " + r.message + " / " +
             rejects_oracle[i].message);
      }
      if (r.reason == bp::wire::REJECT_REASON_UNSPECIFIED || r.message.empty())
        Fail("a rejection without a reason or message");
    }
    if (host->Objects() != oracle->Objects()) Fail("live objects differ from brute force");
    host->Query(&un_host, &co_host);
    oracle->Query(&un_oracle, &co_oracle);
    if (un_host != un_oracle) Fail(algorithm + ": uncollides differ from brute force");
    if (co_host != co_oracle) Fail(algorithm + ": collides differ from brute force");
    if (host->Overlaps() != oracle->Overlaps()) Fail("overlap counts differ from brute force");
    host->Snapshot(&snap_host);
    oracle->Snapshot(&snap_oracle);
    if (snap_host != snap_oracle) Fail(algorithm + ": snapshot differs from brute force");
    if (snap_host.size() != host->Overlaps()) Fail("snapshot size differs from the overlap count");
  }
  return 0;
}
