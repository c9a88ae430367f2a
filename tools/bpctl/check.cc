// bpctl check: replays a recording through an embedded engine and the brute-force oracle, with
// the daemon's own admission and validation (AdmitBatch, EngineHost), and reports the first
// difference. Frames close on end_of_frame batches, as in the daemon's default mode.
#include <set>

#include "common.h"
#include "engine_host.h"
#include <fmt/format.h>

#include "bp/transport/recording.h"

namespace bp::bpctl {
namespace {

using Pair = std::pair<uint64_t, uint64_t>;

// fmt, not std::string operator+: g++ 12 -O3 reports false -Wrestrict positives on the latter.
std::string PairName(const Pair& p) {
  return fmt::format("({}, {})", KeyName(p.first), KeyName(p.second));
}

// The first difference between two canonical event lists, or "" when equal.
std::string Difference(const char* kind, const std::vector<uint64_t>& expected,
                       const std::vector<uint64_t>& got) {
  std::set<Pair> e, g;
  for (size_t i = 0; i + 1 < expected.size(); i += 2) e.emplace(expected[i], expected[i + 1]);
  for (size_t i = 0; i + 1 < got.size(); i += 2) g.emplace(got[i], got[i + 1]);
  for (const Pair& p : e) {
    if (!g.count(p)) return fmt::format("{} {}: expected, not reported", kind, PairName(p));
  }
  for (const Pair& p : g) {
    if (!e.count(p)) return fmt::format("{} {}: reported, not expected", kind, PairName(p));
  }
  if (expected != got) return fmt::format("{}: same pairs in another order", kind);
  return "";
}

}  // namespace

int Check(const Common& common, const CheckOptions& options, CheckResult* out) {
  CheckResult local;
  CheckResult& result = out ? *out : local;
  result = CheckResult();
  wire::RecordingReader reader;
  if (Status s = reader.Open(options.file); !s.ok()) {
    std::fprintf(stderr, "bpctl check: %s\n", s.ToString().c_str());
    return 1;
  }
  service::EngineConfig engine_config = common.config.engine;
  if (!options.engine.empty()) engine_config.algorithm = options.engine;
  service::EngineConfig oracle_config = engine_config;
  oracle_config.algorithm = "brute_force";
  std::unique_ptr<service::EngineHost> engine, oracle;
  const uint64_t max_objects = common.config.limits.max_objects;
  if (Status s = service::MakeEngineHost(engine_config, max_objects, &engine); !s.ok()) {
    std::fprintf(stderr, "bpctl check: %s\n", s.ToString().c_str());
    return 2;
  }
  if (Status s = service::MakeEngineHost(oracle_config, max_objects, &oracle); !s.ok()) {
    std::fprintf(stderr, "bpctl check: %s\n", s.ToString().c_str());
    return 2;
  }
  if (common.config.frames.boundary == service::FrameBoundary::kTick) {
    std::fprintf(stderr,
                 "bpctl check: warning: the config closes frames on a tick, which a recording "
                 "cannot reproduce; check closes them on end_of_frame batches\n");
  }
  wire::RecordedBatch recorded;
  wire::UpdateBatch batch;
  std::vector<uint64_t> unc_e, col_e, unc_g, col_g;
  std::string first_rejection;
  bool dirty = false;  // a batch was applied since the last frame
  // Closes a frame on both engines and compares; false (after printing it) on a difference.
  auto close_frame = [&]() -> bool {
    dirty = false;
    ++result.frames;
    oracle->Query(&unc_e, &col_e);
    engine->Query(&unc_g, &col_g);
    for (size_t i = 0; i + 1 < unc_g.size(); i += 2) {
      result.uncollides.push_back({result.frames, {unc_g[i], unc_g[i + 1]}});
    }
    for (size_t i = 0; i + 1 < col_g.size(); i += 2) {
      result.collides.push_back({result.frames, {col_g[i], col_g[i + 1]}});
    }
    result.events += (unc_g.size() + col_g.size()) / 2;
    std::string diff = Difference("uncollide", unc_e, unc_g);
    if (diff.empty()) diff = Difference("collide", col_e, col_g);
    if (diff.empty()) return true;
    std::printf("DIFFERENCE at frame %llu (batch %llu, producer %u frame %llu): %s\n",
                static_cast<unsigned long long>(result.frames),
                static_cast<unsigned long long>(result.batches - 1), batch.producer(),
                static_cast<unsigned long long>(batch.frame()), diff.c_str());
    result.identical = false;
    return false;
  };
  for (;;) {
    bool end = false;
    if (Status s = reader.Next(&recorded, &end); !s.ok()) {
      if (s.code() != StatusCode::kDataLoss || result.batches == 0) {
        std::fprintf(stderr, "bpctl check: %s\n", s.ToString().c_str());
        return 1;
      }
      // A recorder killed mid-write leaves a partial last batch: check the complete ones.
      std::fprintf(stderr, "bpctl check: warning: %s; checking the complete batches\n",
                   s.message().c_str());
      break;
    }
    if (end) break;
    ++result.batches;
    service::Reject refused;
    const auto* bytes = reinterpret_cast<const uint8_t*>(recorded.payload().data());
    if (!service::AdmitBatch(std::span<const uint8_t>(bytes, recorded.payload().size()),
                             common.config.limits, &batch, &refused)) {
      ++result.rejected;
      if (first_rejection.empty()) first_rejection = refused.message;
      continue;
    }
    service::ApplyCounts counts_e, counts_g;  // the same for both when the rejections agree
    std::vector<std::string> rejects_e, rejects_g;
    engine->Apply(
        batch, [&](service::Reject&& r) { rejects_e.push_back(r.message); }, &counts_e);
    oracle->Apply(
        batch, [&](service::Reject&& r) { rejects_g.push_back(r.message); }, &counts_g);
    result.rejected += rejects_e.size();
    if (first_rejection.empty() && !rejects_e.empty()) first_rejection = rejects_e.front();
    if (rejects_e != rejects_g) {
      std::fprintf(stderr, "bpctl check: batch %llu: the engines rejected different items\n",
                   static_cast<unsigned long long>(result.batches - 1));
      result.identical = false;
      return 1;
    }
    dirty = true;
    if (!batch.end_of_frame()) continue;
    if (!close_frame()) return 1;
  }
  // The daemon finishes an open frame when it stops; so does check at the end of the file.
  if (dirty && !close_frame()) return 1;
  if (!options.quiet) {
    std::printf(
        "%s: %llu batches, %llu frames, %llu events, %llu rejected items: engine '%s' "
        "identical to brute force\n",
        options.file.c_str(), static_cast<unsigned long long>(result.batches),
        static_cast<unsigned long long>(result.frames),
        static_cast<unsigned long long>(result.events),
        static_cast<unsigned long long>(result.rejected), engine->Name().c_str());
    if (!first_rejection.empty()) std::printf("  first rejection: %s\n", first_rejection.c_str());
  }
  return 0;
}

}  // namespace bp::bpctl
