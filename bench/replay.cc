// bpreplay: a recorded update stream (bpctl record) replayed through engines and the peer
// libraries in one process, timed frame by frame: the recorded world joins the scene table
// beside bpbench's synthetic scenes. Frames close on end_of_frame batches, as in the daemon's
// default mode; a batch applies its erases, then its inserts, then its updates, as the daemon
// does. One JSON line per engine and peer on stdout: median, mean, p90 and max frame
// milliseconds, the most pairs after a frame, events, and the hash chain of the overlap set over
// all frames, which must agree with the first line's (every engine and peer found the same pairs at
// every frame).
//
//   bpreplay bullet.rec                              grid_dense, grid_segmented_sap,
//                                                    segmented_sap, dynamic_octree
//   bpreplay bullet.rec -e grid_dense,brute_force --peers all -r 3
//   bpreplay bullet.rec --window 601:900       also the median and p90 of frames 601 to 900
//
// The peer adapters set no static or category filter: they are given every object alike, and
// the pairs our engines would not report (two static objects, categories that do not accept
// each other) are dropped from their sets after the timed part, with the exact closed box test.
// Items the daemon would refuse are left out and counted (see Load). A restate (a producer
// stating its objects again after a daemon restart) is not replayed as the daemon applies it:
// its inserts of live ids are left out; `bpctl check` replays such recordings with the daemon's
// own admission.
// Exit status: 0 when every line agrees; 1 when a chain differs; 2 on bad arguments or input.
#include <algorithm>
#include <array>
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <iterator>
#include <memory>
#include <sstream>
#include <string>
#include <unordered_map>
#include <vector>

#include "peer.h"
#include <CLI/CLI.hpp>
#include <unistd.h>

#include "bp/engines.h"
#include "bp/object_options.h"
#include "bp/transport/recording.h"
#include "bp/workload.h"

namespace {

using Clock = std::chrono::steady_clock;
using bp::bench::PeerBox;

double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

double Quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[static_cast<size_t>(q * static_cast<double>(v.size() - 1) + 0.5)];
}

// One batch of the stream, ids made dense (0, 1, ... in order of first insert) so that pairs
// fit the set hash's 32-bit halves.
struct Batch {
  std::vector<uint64_t> erases;
  std::vector<uint64_t> insert_ids, update_ids;
  std::vector<PeerBox> inserts, updates;
  std::vector<bp::ObjectOptions> insert_options;
};
using Frame = std::vector<Batch>;

struct Stream {
  std::vector<Frame> frames;
  PeerBox bounds;  // every box of the stream
  size_t max_live = 0;
  uint64_t batches = 0, skipped_batches = 0, skipped_items = 0;
};

// Reads a recording into frames. Batches the daemon refuses whole (unparsable, another schema
// version, producer 0 or above 65535) and items it refuses (an unknown or duplicate id, an id
// of 2^48 or more, a box that is not finite or inverted, of another dimension than 3, in both
// precisions or with arrays of the wrong length, attributes of the wrong length or on an
// update) are left out and counted.
bool Load(const std::string& path, Stream* out) {
  bp::wire::RecordingReader reader;
  if (bp::Status s = reader.Open(path); !s.ok()) {
    std::fprintf(stderr, "bpreplay: %s\n", s.ToString().c_str());
    return false;
  }
  std::unordered_map<uint64_t, uint64_t> dense;  // key -> dense id (kept after an erase)
  std::unordered_map<uint64_t, bool> live;       // dense id -> live
  bp::wire::RecordedBatch recorded;
  bp::wire::UpdateBatch batch;
  Frame frame;
  out->bounds.lo = {1e300, 1e300, 1e300};
  out->bounds.hi = {-1e300, -1e300, -1e300};
  size_t live_count = 0;
  // Reads array's box i; false if it has no valid box.
  auto box_of = [&](const bp::wire::BoxArray& a, int i, PeerBox* b) {
    const bool wide = a.lo64_size() > 0 || a.hi64_size() > 0;
    const int n = a.ids_size();
    if ((wide && (a.lo32_size() > 0 || a.hi32_size() > 0)) ||
        (wide ? a.lo64_size() : a.lo32_size()) != 3 * n ||
        (wide ? a.hi64_size() : a.hi32_size()) != 3 * n) {
      return false;
    }
    for (int k = 0; k < 3; ++k) {
      const double lo = wide ? a.lo64(3 * i + k) : a.lo32(3 * i + k);
      const double hi = wide ? a.hi64(3 * i + k) : a.hi32(3 * i + k);
      if (!std::isfinite(lo) || !std::isfinite(hi) || lo > hi) return false;
      b->lo[static_cast<size_t>(k)] = lo;
      b->hi[static_cast<size_t>(k)] = hi;
    }
    return true;
  };
  for (;;) {
    bool end = false;
    if (bp::Status s = reader.Next(&recorded, &end); !s.ok()) {
      std::fprintf(stderr, "bpreplay: %s%s\n", s.ToString().c_str(),
                   out->batches > 0 ? "; replaying the complete batches" : "");
      if (out->batches == 0) return false;
      break;
    }
    if (end) break;
    ++out->batches;
    if (!batch.ParseFromString(recorded.payload()) ||
        batch.version() != bp::wire::SCHEMA_VERSION_1 || batch.producer() == 0 ||
        batch.producer() > 65535) {
      ++out->skipped_batches;
      continue;
    }
    // Boxes of another dimension are refused; the batch's erases and frame boundary stand.
    const bool boxes_ok = batch.dim() == 3;
    const uint64_t producer = uint64_t{batch.producer()} << 48;
    constexpr uint64_t kLocalIdLimit = uint64_t{1} << 48;
    Batch b;
    for (uint64_t local : batch.erases()) {
      auto it = local < kLocalIdLimit ? dense.find(producer | local) : dense.end();
      if (it == dense.end() || !live[it->second]) {
        ++out->skipped_items;
        continue;
      }
      live[it->second] = false;
      --live_count;
      b.erases.push_back(it->second);
    }
    const bp::wire::BoxArray& ins = batch.inserts();
    const int n = ins.ids_size();
    const bool attributes_ok = (ins.static_flags_size() == 0 || ins.static_flags_size() == n) &&
                               (ins.category_size() == 0 || ins.category_size() == n) &&
                               (ins.mask_size() == 0 || ins.mask_size() == n);
    for (int i = 0; i < n; ++i) {
      PeerBox box;
      if (!boxes_ok || !attributes_ok || ins.ids(i) >= kLocalIdLimit || !box_of(ins, i, &box)) {
        ++out->skipped_items;
        continue;
      }
      auto [it, fresh] = dense.try_emplace(producer | ins.ids(i), dense.size());
      if (live[it->second]) {
        ++out->skipped_items;
        continue;
      }
      bp::ObjectOptions options;
      if (ins.static_flags_size() == n) options.is_static = ins.static_flags(i);
      if (ins.category_size() == n) options.category = ins.category(i);
      if (ins.mask_size() == n) options.mask = ins.mask(i);
      live[it->second] = true;
      ++live_count;
      b.insert_ids.push_back(it->second);
      b.inserts.push_back(box);
      b.insert_options.push_back(options);
    }
    const bp::wire::BoxArray& ups = batch.updates();
    const bool update_attributes =
        ups.static_flags_size() != 0 || ups.category_size() != 0 || ups.mask_size() != 0;
    for (int i = 0; i < ups.ids_size(); ++i) {
      PeerBox box;
      auto it = ups.ids(i) < kLocalIdLimit ? dense.find(producer | ups.ids(i)) : dense.end();
      if (!boxes_ok || update_attributes || it == dense.end() || !live[it->second] ||
          !box_of(ups, i, &box)) {
        ++out->skipped_items;
        continue;
      }
      b.update_ids.push_back(it->second);
      b.updates.push_back(box);
    }
    for (const auto* boxes : {&b.inserts, &b.updates}) {
      for (const PeerBox& box : *boxes) {
        for (size_t k = 0; k < 3; ++k) {
          out->bounds.lo[k] = std::min(out->bounds.lo[k], box.lo[k]);
          out->bounds.hi[k] = std::max(out->bounds.hi[k], box.hi[k]);
        }
      }
    }
    out->max_live = std::max(out->max_live, live_count);
    frame.push_back(std::move(b));
    if (batch.end_of_frame()) out->frames.push_back(std::move(frame)), frame.clear();
  }
  if (!frame.empty()) out->frames.push_back(std::move(frame));  // as the daemon at its stop
  return !out->frames.empty();
}

// What one engine's or peer's runs measured.
struct Run {
  std::vector<double> frame_ms, run_medians;
  uint64_t pairs_max = 0, collides = 0, uncollides = 0, chain = 0;  // pairs_max: after any frame
  uint64_t unknown_candidates = 0;  // peers: pairs naming an object not live (a disagreement)
};

template <class T>
bp::Box<3, T> ToBox(const PeerBox& b) {
  bp::Box<3, T> out;
  for (size_t k = 0; k < 3; ++k) {
    out.lo[k] = static_cast<T>(b.lo[k]);
    out.hi[k] = static_cast<T>(b.hi[k]);
  }
  return out;
}

// The events of a query, folded into the set hash as they come.
class HashSink final : public bp::EventSink<uint64_t> {
 public:
  void Collide(const uint64_t& a, const uint64_t& b) override {
    set_.Collide(a, b);
    ++collides;
  }
  void Uncollide(const uint64_t& a, const uint64_t& b) override {
    set_.Uncollide(a, b);
    ++uncollides;
  }
  const bp::workload::SetHash& set() const { return set_; }
  uint64_t collides = 0, uncollides = 0;

 private:
  bp::workload::SetHash set_;
};

template <class T>
Run RunEngine(const std::string& algorithm, unsigned threads, const Stream& stream, int repeats,
              bool progress) {
  using Item = typename bp::Broadphase<3, T>::Item;
  // The stream in the engine's types, converted once, outside the timed part.
  struct Typed {
    std::vector<uint64_t> erases;
    std::vector<Item> inserts, updates;
    std::vector<bp::ObjectOptions> options;
  };
  std::vector<std::vector<Typed>> frames;
  for (const Frame& f : stream.frames) {
    std::vector<Typed> typed;
    for (const Batch& b : f) {
      Typed t;
      t.erases = b.erases;
      for (size_t i = 0; i < b.inserts.size(); ++i) {
        t.inserts.push_back({b.insert_ids[i], ToBox<T>(b.inserts[i])});
        t.options.push_back(b.insert_options[i]);
      }
      for (size_t i = 0; i < b.updates.size(); ++i) {
        t.updates.push_back({b.update_ids[i], ToBox<T>(b.updates[i])});
      }
      typed.push_back(std::move(t));
    }
    frames.push_back(std::move(typed));
  }
  bp::EngineSpec spec;
  spec.algorithm = algorithm;
  spec.grid_dense.threads = spec.grid_segmented_sap.threads = spec.grid_batch_sap.threads = threads;
  Run r;
  for (int rep = 0; rep < repeats; ++rep) {
    std::unique_ptr<bp::Broadphase<3, T>> engine = bp::NewEngine<3, T>(spec);
    HashSink sink;
    bp::workload::HashChain chain;
    std::vector<double> run;
    for (size_t f = 0; f < frames.size(); ++f) {
      const auto start = Clock::now();
      for (const Typed& t : frames[f]) {
        engine->EraseMany(t.erases);
        engine->InsertMany(t.inserts, t.options);
        engine->UpdateMany(t.updates);
      }
      engine->Query(sink);
      run.push_back(MsSince(start));
      chain.AddFrame(sink.set().value());
      r.pairs_max = std::max(r.pairs_max, sink.set().pairs());
      if (progress && (f % 20 == 0 || f + 1 == frames.size())) {
        std::fprintf(stderr, "\r%-24s repeat %d/%d frame %zu/%zu", algorithm.c_str(), rep + 1,
                     repeats, f + 1, frames.size());
      }
    }
    r.frame_ms.insert(r.frame_ms.end(), run.begin(), run.end());
    r.run_medians.push_back(Quantile(run, 0.5));
    r.collides = sink.collides;
    r.uncollides = sink.uncollides;
    r.chain = chain.value();
  }
  if (progress) std::fprintf(stderr, "\r%-80s\r", "");
  return r;
}

Run RunPeer(const bp::bench::PeerInfo& info, const Stream& stream, int repeats, bool progress) {
  bp::bench::PeerWorld world;
  world.bounds = stream.bounds;
  for (size_t k = 0; k < 3; ++k) {  // slack around the stream's boxes (the axis sweep's bounds)
    world.bounds.lo[k] -= 1;
    world.bounds.hi[k] += 1;
  }
  world.max_objects = static_cast<uint32_t>(stream.max_live);
  Run r;
  for (int rep = 0; rep < repeats; ++rep) {
    std::unique_ptr<bp::bench::Peer> peer = info.make(world);
    // The exact boxes and the options of the live objects, untimed.
    std::unordered_map<uint64_t, std::pair<PeerBox, bp::ObjectOptions>> live;
    std::vector<uint64_t> pairs, previous, diff;
    bp::workload::HashChain chain;
    std::vector<double> run;
    r.collides = r.uncollides = 0;
    for (size_t f = 0; f < stream.frames.size(); ++f) {
      const auto start = Clock::now();
      for (const Batch& b : stream.frames[f]) {
        for (uint64_t id : b.erases) peer->Erase(id);
        for (size_t i = 0; i < b.inserts.size(); ++i) peer->Insert(b.insert_ids[i], b.inserts[i]);
        for (size_t i = 0; i < b.updates.size(); ++i) peer->Update(b.update_ids[i], b.updates[i]);
      }
      peer->Refresh();
      run.push_back(MsSince(start));
      for (const Batch& b : stream.frames[f]) {
        for (uint64_t id : b.erases) live.erase(id);
        for (size_t i = 0; i < b.inserts.size(); ++i) {
          live[b.insert_ids[i]] = {b.inserts[i], b.insert_options[i]};
        }
        for (size_t i = 0; i < b.updates.size(); ++i) live[b.update_ids[i]].first = b.updates[i];
      }
      previous.swap(pairs);
      pairs.clear();
      peer->ForEachCandidate([&](uint64_t a, uint64_t b) {
        auto x = live.find(a), y = live.find(b);
        if (x == live.end() || y == live.end()) {
          ++r.unknown_candidates;  // a pair of an object the peer should not hold
          return;
        }
        if (!bp::Accepts(x->second.second, y->second.second)) return;
        if (bp::bench::Overlap(x->second.first, y->second.first)) {
          pairs.push_back(bp::workload::PairKey(a, b));
        }
      });
      std::sort(pairs.begin(), pairs.end());
      pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
      uint64_t set_hash = 0;
      for (uint64_t k : pairs) set_hash += bp::workload::PairHash(k);
      chain.AddFrame(set_hash);
      r.pairs_max = std::max<uint64_t>(r.pairs_max, pairs.size());
      diff.clear();
      std::set_difference(pairs.begin(), pairs.end(), previous.begin(), previous.end(),
                          std::back_inserter(diff));
      r.collides += diff.size();
      diff.clear();
      std::set_difference(previous.begin(), previous.end(), pairs.begin(), pairs.end(),
                          std::back_inserter(diff));
      r.uncollides += diff.size();
      if (progress && (f % 20 == 0 || f + 1 == stream.frames.size())) {
        std::fprintf(stderr, "\r%-24s repeat %d/%d frame %zu/%zu", info.name.c_str(), rep + 1,
                     repeats, f + 1, stream.frames.size());
      }
    }
    r.frame_ms.insert(r.frame_ms.end(), run.begin(), run.end());
    r.run_medians.push_back(Quantile(run, 0.5));
    r.chain = chain.value();
  }
  if (progress) std::fprintf(stderr, "\r%-80s\r", "");
  return r;
}

// Frames first..last (1-based, inclusive) of every repeat: a part of the stream on its own (the
// settled end of a simulation, say).
struct Window {
  size_t first = 0, last = 0;  // 0: none
};

// The median over repeats of the window's median, and the window's p90 over all repeats.
void WindowStats(const Run& r, size_t frames, const Window& w, double* out_median,
                 double* out_p90) {
  std::vector<double> medians, all;
  for (size_t start = 0; start + frames <= r.frame_ms.size(); start += frames) {
    std::vector<double> part(r.frame_ms.begin() + static_cast<std::ptrdiff_t>(start + w.first - 1),
                             r.frame_ms.begin() + static_cast<std::ptrdiff_t>(start + w.last));
    medians.push_back(Quantile(part, 0.5));
    all.insert(all.end(), part.begin(), part.end());
  }
  *out_median = Quantile(medians, 0.5);
  *out_p90 = Quantile(all, 0.9);
}

void Print(const std::string& label, const std::string& name, const std::string& library,
           const Stream& s, int repeats, const Run& r, const Run& first, const Window& w) {
  double total = 0;
  for (double ms : r.frame_ms) total += ms;
  const double median = Quantile(r.run_medians, 0.5);
  std::string window;
  if (w.first != 0) {
    double wm = 0, wp = 0, fm = 0, fp = 0;
    WindowStats(r, s.frames.size(), w, &wm, &wp);
    WindowStats(first, s.frames.size(), w, &fm, &fp);
    char buf[200];
    std::snprintf(buf, sizeof buf,
                  "\"window\":[%zu,%zu],\"window_median_ms\":%.4f,\"window_p90_ms\":%.4f,"
                  "\"window_vs_first\":%.3f,",
                  w.first, w.last, wm, wp, wm / std::max(1e-9, fm));
    window = buf;
  }
  std::printf(
      "{\"recording\":\"%s\",\"engine\":\"%s\",%s\"frames\":%zu,\"max_objects\":%zu,"
      "\"repeats\":%d,%s\"median_ms\":%.4f,\"mean_ms\":%.4f,\"p90_ms\":%.4f,\"max_ms\":%.4f,"
      "\"vs_first\":%.3f,\"pairs_max\":%" PRIu64 ",\"collides\":%" PRIu64 ",\"uncollides\":%" PRIu64
      ",\"chain\":\"%016" PRIx64 "\",\"agrees\":%s,\"skipped_items\":%" PRIu64 "}\n",
      label.c_str(), name.c_str(),
      library.empty() ? "" : ("\"library\":\"" + library + "\",").c_str(), s.frames.size(),
      s.max_live, repeats, window.c_str(), median,
      total / static_cast<double>(std::max<size_t>(1, r.frame_ms.size())),
      Quantile(r.frame_ms, 0.9), Quantile(r.frame_ms, 1.0),
      median / std::max(1e-9, Quantile(first.run_medians, 0.5)), r.pairs_max, r.collides,
      r.uncollides, r.chain, r.chain == first.chain && r.unknown_candidates == 0 ? "true" : "false",
      s.skipped_items);
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "bpreplay: a recorded update stream through engines and peer libraries (JSON lines)"};
  std::string file, engines = "grid_dense,grid_segmented_sap,segmented_sap,dynamic_octree";
  std::string peer_list, coord = "float", label;
  int repeats = 3;
  unsigned threads = 1;
  app.add_option("recording", file, "a recording (bpctl record)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--engine,-e", engines,
                 "engines, separated by commas (" + bp::EngineAlgorithmList() + ")")
      ->capture_default_str();
  app.add_option("--peers", peer_list, "peer libraries after the engines: all, or names");
  app.add_option("--coord", coord, "the engines' coordinate type")
      ->check(CLI::IsMember({"float", "double"}))
      ->capture_default_str();
  app.add_option("--threads", threads, "grid engines' query threads")->check(CLI::Range(1u, 256u));
  app.add_option("--repeats,-r", repeats, "runs of the whole stream per engine")
      ->check(CLI::Range(1, 1000));
  app.add_option("--label", label, "the recording's name in the output (default: the file's)");
  std::string window_arg;
  app.add_option("--window", window_arg,
                 "FIRST:LAST: also report the median and p90 of these frames (1-based)");
  CLI11_PARSE(app, argc, argv);
  Window window;
  if (label.empty()) label = file.substr(file.find_last_of('/') + 1);
  if (label.find_first_of("\"\\") != std::string::npos) {
    std::fprintf(stderr, "bpreplay: a label holds no quote or backslash\n");
    return 2;
  }
  std::vector<std::string> names;
  std::stringstream list(engines);
  for (std::string name; std::getline(list, name, ',');) {
    if (name.empty()) continue;
    if (std::find(bp::kEngineAlgorithms.begin(), bp::kEngineAlgorithms.end(), name) ==
        bp::kEngineAlgorithms.end()) {
      std::fprintf(stderr, "bpreplay: unknown engine '%s' (%s)\n", name.c_str(),
                   bp::EngineAlgorithmList().c_str());
      return 2;
    }
    names.push_back(name);
  }
  std::vector<const bp::bench::PeerInfo*> peers;
  if (std::string unknown; !bp::bench::SelectPeers(peer_list, &peers, &unknown)) {
    std::fprintf(stderr, "bpreplay: peer '%s' is not in this build\n", unknown.c_str());
    return 2;
  }
  if (names.empty() && peers.empty()) {
    std::fprintf(stderr, "bpreplay: no engine and no peer to run\n");
    return 2;
  }
  Stream stream;
  if (!Load(file, &stream)) return 2;
  if (!window_arg.empty()) {
    if (std::sscanf(window_arg.c_str(), "%zu:%zu", &window.first, &window.last) != 2 ||
        window.first == 0 || window.first > window.last || window.last > stream.frames.size()) {
      std::fprintf(stderr, "bpreplay: --window wants FIRST:LAST within the %zu frames\n",
                   stream.frames.size());
      return 2;
    }
  }
  std::fprintf(stderr,
               "bpreplay: %s: %" PRIu64 " batches, %zu frames, at most %zu objects, %" PRIu64
               " items and %" PRIu64 " batches left out\n",
               file.c_str(), stream.batches, stream.frames.size(), stream.max_live,
               stream.skipped_items, stream.skipped_batches);
  const bool progress = isatty(STDERR_FILENO) != 0;
  bool agree = true;
  Run first;
  bool have_first = false;
  for (const std::string& name : names) {
    Run r = coord == "double" ? RunEngine<double>(name, threads, stream, repeats, progress)
                              : RunEngine<float>(name, threads, stream, repeats, progress);
    if (!have_first) first = r, have_first = true;
    Print(label, name, "", stream, repeats, r, first, window);
    agree = agree && r.chain == first.chain;
  }
  for (const bp::bench::PeerInfo* info : peers) {
    if (info->max_objects != 0 && stream.max_live > info->max_objects) {
      std::printf(
          "{\"recording\":\"%s\",\"engine\":\"%s\",\"library\":\"%s\",\"skipped\":\"%s\"}\n",
          label.c_str(), info->name.c_str(), info->description.c_str(), info->limit_reason.c_str());
      continue;
    }
    Run r = RunPeer(*info, stream, repeats, progress);
    if (!have_first) first = r, have_first = true;
    Print(label, info->name, info->description, stream, repeats, r, first, window);
    agree = agree && r.chain == first.chain && r.unknown_candidates == 0;
  }
  return agree ? 0 : 1;
}
