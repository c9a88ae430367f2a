// bp::detail::DenseCellCore: a third cell type for bp::Grid, beyond the paper. A cell keeps its
// objects' boxes in flat arrays (per block of 16 slots, one row per axis bound: vectorisable) and
// finds the pair changes of a query by testing each changed object against every object of the
// cell, then and now: a pair changes iff the two tests differ. "Then" reads a scratch copy of the
// rows with the changed slots' old boxes put back (per thread, so it stays in the cache).
//
// Why: with the grid's cells small (tens of objects), sorting buys nothing, while the SAP cells'
// bookkeeping (sorted lists, positions, a pair set per cell, swaps that touch their neighbours'
// records) is scattered memory traffic, and that is where a large frame's time goes (the first
// touches of each moved extremum and of its neighbours' boxes). Here a changed
// object costs two sequential, vectorisable passes over at most a few kilobytes, and a cell
// reports only changes (the grid's witness counts need nothing else), so it holds no pair set.
// The cost per changed object is linear in the cell's population: keep the cells small (the
// grid's objects_per_cell) and prefer SAP cells for scenes whose objects crowd into few cells.
//
// "Then" has two forms. A cell of up to DenseCellOptions::matrix_slots slots (all of them on the
// paper's scenes) keeps its pairs as a bit matrix, slot by slot, so a changed object is tested
// once, now, and its row of the matrix is "then": on S3 (every object moving) that took a tenth
// off the frame. A larger cell would pay the matrix's square size: it tests its old box too.
//
// Exactness: a pair (a, b) of the cell is reported iff [a and b live then and their old boxes
// overlapped] (with a matrix: its bit) differs from [both live now and their new boxes overlap];
// a pair of two changed objects is decided once (by the lower slot; with a matrix, by the first
// of the two in the query's order, whose report flips the bit the second then agrees with).
// Unchanged pairs keep their status. So the cell's reports are exactly the changes of its
// overlap set, which is what a SAP cell's tracker drains. The differential suite runs the grid
// over this cell like over the others, with and without the matrix and across the cap.
//
// Thread safety: none; owned by one grid cell (the grid's pool applies each cell on one thread).
// Invariants (checked by Validate, between queries):
//  1. size_ is a multiple of kBlock; rows_ holds 2 K size_ coordinates and live_bits_ one 16-bit
//     word per block (bit h % kBlock of word h / kBlock: slot h is live).
//  2. live_ is the number of live slots; every live slot's box is valid (lo <= hi);
//     no change is pending.
//  3. With matrix_, pairs_ holds size_ rows of size_ / kBlock words and bit (a, b) is set iff
//     a != b, both are live, their boxes overlap and the filter accepts them; else it is empty.
//
// Why one file of about 800 lines: the cell's storage (rows, live bits, the pair matrix) and its
// scans, written once per kernel family (a target attribute each, which one template cannot
// carry), share every field of one class; the kernels themselves are apart
// (detail/dense_kernels.h).
#pragma once

#include <algorithm>
#include <bit>
#include <cstdint>
#include <cstring>
#include <limits>
#include <span>
#include <string>
#include <type_traits>
#include <vector>

#include "bp/box.h"
#include "bp/broadphase.h"
#include "bp/detail/assert.h"
#include "bp/detail/dense_kernels.h"
#include "bp/detail/front_end_contract.h"
#include "bp/detail/pair_tracker.h"
#include "bp/object_options.h"

namespace bp {

/// The dense cell's box-test kernels: they give the same events (the differential suite runs
/// each that the CPU has), at different speeds.
enum class DenseKernel : uint8_t {
  kAuto,      ///< the widest this CPU runs for the coordinate type
  kAvx512,    ///< AVX-512F (x86-64; float, double and int32 coordinates)
  kAvx2,      ///< AVX2 (x86-64; float, double and int32 coordinates)
  kPortable,  ///< portable C++ (GCC/Clang vector extensions for float, double and int32)
};

/// The name of a kernel: "auto", "avx512", "avx2" or "portable".
inline const char* DenseKernelName(DenseKernel k) {
  switch (k) {
    case DenseKernel::kAuto:
      return "auto";
    case DenseKernel::kAvx512:
      return "avx512";
    case DenseKernel::kAvx2:
      return "avx2";
    case DenseKernel::kPortable:
      return "portable";
  }
  return "?";
}

/// Tuning of the dense cell (its cost is set mostly by the grid's objects_per_cell).
struct DenseCellOptions {
  /// The box-test kernel. A kernel this CPU (or the coordinate type) lacks falls back to the
  /// next narrower one: AVX-512, AVX2, portable. DenseCellCore::kernel() says which runs.
  DenseKernel kernel = DenseKernel::kAuto;
  /// A cell of up to this many slots keeps its pairs as a bit matrix (slots x slots bits: 32 KiB
  /// at 512), so a changed object is tested against the cell's boxes once, now, instead of also
  /// against its old box; a cell that grows beyond it drops the matrix and tests then and now,
  /// and takes a matrix again once it has at most half as many slots (an empty cell takes one
  /// at once if its first query leaves it within the cap). 0: never (at most 1024).
  uint32_t matrix_slots = 512;
};

namespace detail {

/// The kernel a dense cell over coordinates T runs when `requested` is asked for on this CPU
/// (never kAuto): the requested one, or the next narrower one this CPU and T have.
template <class T>
DenseKernel ResolveDenseKernel(DenseKernel requested) {
  if (requested == DenseKernel::kPortable) return requested;
  if (requested == DenseKernel::kAuto || requested == DenseKernel::kAvx512) {
    if (kHasWideRows<T> && CpuHasAvx512()) return DenseKernel::kAvx512;
  }
  if (kHasAvx2Rows<T> && CpuHasAvx2()) return DenseKernel::kAvx2;
  return DenseKernel::kPortable;
}

template <int K, Coordinate T>
class DenseCellCore {
 public:
  static constexpr int kDim = K;
  static constexpr size_t kAxes = static_cast<size_t>(K);
  using Coord = T;
  static constexpr const char* kGridName = "grid_dense";
  using Options = DenseCellOptions;

  explicit DenseCellCore(const Options& options = Options())
      : options_(options), kernel_(ResolveDenseKernel<T>(options.kernel)) {
    options_.matrix_slots = std::min(options_.matrix_slots, kMaxMatrixSlots);
  }

  void Apply(std::span<const uint32_t> erases, std::span<const HandleBox<K, T>> updates,
             std::span<const HandleBox<K, T>> inserts) {
    tests_ = 0;
    Scratch& s = ThreadScratch();
    // The lists only grow (written by index: a push_back per changed slot was a call, out of
    // line, in GCC's build of the benchmark).
    const size_t ops = erases.size() + updates.size() + inserts.size();
    if (s.order.size() < ops) s.order.resize(ops);
    s.count = 0;
    size_t top = size_;
    for (const auto& hb : inserts) {
      top = std::max(top, (size_t{hb.handle} + kBlock) / kBlock * kBlock);
    }
    BP_ASSERT(top <= std::numeric_limits<uint32_t>::max());
    ChooseMode(top);
    if (top > size_) Resize(top);
    if (!matrix_ && s.before.size() < ops) s.before.resize(ops);
    for (uint32_t h : erases) {
      BP_ASSERT(h < size_ && Live(h));
      Mark(s, h, true);
      ClearLive(h);  // the box stays: it is the old one
    }
    for (const auto& [h, box] : updates) {
      BP_ASSERT(h < size_ && Live(h));
      Mark(s, h, true);
      Store(h, box);
    }
    for (const auto& [h, box] : inserts) {
      BP_ASSERT(h < size_ && !Live(h));
      Mark(s, h, false);
      SetLive(h);
      Store(h, box);
    }
    live_ = live_ + inserts.size() - erases.size();
    if (s.count != 0) FindChanges(s);
    if (live_ == 0) Resize(0);  // an emptied cell is recycled by the grid with fresh handles
  }

  // ---- the grid's view of the cell's pairs (a SAP cell answers these through its tracker) ----

  /// Sets the options of slot h (before its insert).
  void SetOptions(uint32_t h, const ObjectOptions& options) { options_of_.Set(h, options); }
  ObjectOptions options(uint32_t h) const { return options_of_.Get(h); }
  /// Calls f(a, b, overlapping_now) for every pair whose status the last Apply changed.
  template <class F>
  void DrainChanges(F&& f) {
    for (const Change& c : changes_) f(c.a, c.b, c.now);
    changes_.clear();
  }
  /// Calls f(a, b) for every overlapping pair of the cell (O(n^2): for validators).
  template <class F>
  void ForEachOverlap(F&& f) const {
    for (uint32_t a = 0; a < size_; ++a) {
      if (!Live(a)) continue;
      for (uint32_t b = a + 1; b < size_; ++b) {
        if (Live(b) && Accepts(a, b) && Overlaps(BoxAt(a), BoxAt(b))) f(a, b);
      }
    }
  }

  size_t live() const { return live_; }
  /// Slots held, live or free (a multiple of 16); the grid's local handles are below it.
  uint32_t slots() const { return size_; }
  /// True iff slot h holds a live object.
  bool holds(uint32_t h) const { return h < size_ && Live(h); }
  /// The box-test kernel this cell runs (DenseCellOptions::kernel, resolved for this CPU).
  DenseKernel kernel() const { return kernel_; }
  /// True iff the cell keeps its pairs as a bit matrix (see DenseCellOptions::matrix_slots).
  bool has_matrix() const { return matrix_; }

  /// Gives back trailing blocks that free slots below could absorb: when the live slots and
  /// kCompactSlack free ones fit in fewer blocks, the live slots of the blocks beyond are moved
  /// into the lowest free slots, moved(from, to) is called for each, and the arrays shrink. Without
  /// it a cell keeps the largest population it ever had (under churn its blocks per cell keep
  /// growing), and every query scans the holes. Moving a
  /// slot changes no pair. Call between queries (no change pending).
  template <class Moved>
  void Compact(Moved&& moved) {
    const auto target =
        static_cast<uint32_t>((live_ + kCompactSlack + kBlock - 1) / kBlock * kBlock);
    if (target >= size_) return;
    uint32_t to = 0;
    for (uint32_t from = target; from < size_; ++from) {
      if (!Live(from)) continue;
      while (Live(to)) ++to;  // there is one below target: live_ <= target - slack
      BP_ASSERT(to < target);
      Store(to, BoxAt(from));
      SetLive(to);
      ClearLive(from);
      if (matrix_) MoveMatrixSlot(from, to);
      if (options_of_.filtering()) {
        const ObjectOptions o = options_of_.Get(from);
        options_of_.Set(to, o);
      }
      moved(from, to);
    }
    Resize(target);
  }

  /// Starts loading the rows, live bits and change buffer a query reads (the grid calls it two
  /// cells ahead). Not the matrix: a query reads its changed slots' rows of it only, and loading
  /// all of it gains nothing.
  void Prefetch() const {
    const char* p = reinterpret_cast<const char*>(rows_.data());
    const size_t bytes = rows_.size() * sizeof(T);
    for (size_t off = 0; off < bytes; off += 64) __builtin_prefetch(p + off);
    const char* f = reinterpret_cast<const char*>(live_bits_.data());
    for (size_t off = 0; off < live_bits_.size() * sizeof(uint16_t); off += 64)
      __builtin_prefetch(f + off);
    if (changes_.capacity() != 0) __builtin_prefetch(changes_.data());
  }

  void FillStats(Stats* out) const {
    out->swaps = 0;
    out->overlap_tests = tests_;
    out->global_sort = false;
    out->rebuilt = false;
  }

  Status Validate() const;

  const Options& options() const { return options_; }

 private:
  // Slots are tested in blocks of this many; the arrays are padded to a multiple of it (padding
  // slots are dead, so they never pair).
  static constexpr uint32_t kBlock = 16;
  static constexpr size_t kRows = 2 * kAxes;  // lo and hi of each axis
  static constexpr size_t kBlockValues = kRows * kBlock;
  // Up to this many changed slots, a query tests against the current rows (no scratch copy).
  static constexpr size_t kFewChanges = 8;
  // Compact keeps this many free slots at least, so that a cell whose population wavers near a
  // multiple of kBlock does not move slots back and forth every query.
  static constexpr uint32_t kCompactSlack = 4;
  // The largest matrix a cell may keep (DenseCellOptions::matrix_slots is clamped to it): its
  // blocks bound the scan's per-query buffer of differing blocks, kept on the stack.
  static constexpr uint32_t kMaxMatrixSlots = 1024;
  static constexpr uint32_t kMaxMatrixBlocks = kMaxMatrixSlots / kBlock;

  struct Change {
    uint32_t a, b;
    bool now;
  };
  struct Before {
    Box<K, T> box;  // the box at the last query
    uint32_t live;  // live at the last query (0/1)
  };
  // A block whose bits differ between a changed slot's pairs and its tests now (the matrix scan).
  struct Hit {
    uint32_t block, diff, now;
  };
  // Per-thread scratch of one Apply: the rows as they were ("then"), which slots changed, and
  // per block the slots that did not change and are live (a block without any holds only pairs
  // that its changed slots decide).
  // The changed slots' order and old states are per thread too (not per cell): the lists are
  // needed only inside Apply, and a per-cell list is one more line to miss per touched cell.
  struct Scratch {
    std::vector<T> then_rows;
    std::vector<uint16_t> then_live;  // live bits then, per block
    std::vector<uint32_t> changed, steady;
    std::vector<uint32_t> order;  // the query's changed slots, in order: order[0, count)
    std::vector<Before> before;   // their states at the last query (rows mode): [0, count)
    size_t count = 0;
  };
  static Scratch& ThreadScratch() {
    thread_local Scratch scratch;
    return scratch;
  }

  static size_t At(uint32_t h, size_t row) {
    return size_t{h / kBlock} * kBlockValues + row * kBlock + h % kBlock;
  }
  // Live bits are read and written in uint32_t arithmetic: a uint16_t operand is promoted to
  // int, which -Wsign-conversion flags under the sanitizers' instrumentation.
  bool Live(uint32_t h) const {
    return ((uint32_t{live_bits_[h / kBlock]} >> (h % kBlock)) & 1u) != 0;
  }
  void SetLive(uint32_t h) {
    uint16_t& word = live_bits_[h / kBlock];
    word = static_cast<uint16_t>(uint32_t{word} | (1u << (h % kBlock)));
  }
  void ClearLive(uint32_t h) {
    uint16_t& word = live_bits_[h / kBlock];
    word = static_cast<uint16_t>(uint32_t{word} & ~(1u << (h % kBlock)));
  }
  Box<K, T> BoxAt(uint32_t h) const {
    Box<K, T> b;
    for (size_t a = 0; a < kAxes; ++a) {
      b.lo[a] = rows_[At(h, 2 * a)];
      b.hi[a] = rows_[At(h, 2 * a + 1)];
    }
    return b;
  }
  void Store(uint32_t h, const Box<K, T>& box) {
    for (size_t a = 0; a < kAxes; ++a) {
      rows_[At(h, 2 * a)] = box.lo[a];
      rows_[At(h, 2 * a + 1)] = box.hi[a];
    }
  }
  bool Accepts(uint32_t a, uint32_t b) const { return options_of_.Accepts(a, b); }
  // Overlaps (closed intervals) evaluated on every axis, without branches: the boxes are valid
  // (no NaN), so a.lo <= b.hi && b.lo <= a.hi is the same test as Overlaps'.
  static uint32_t OverlapsFlat(const Box<K, T>& a, const Box<K, T>& b) {
    uint32_t ok = 1;
    for (size_t i = 0; i < kAxes; ++i) {
      ok &= static_cast<uint32_t>(a.lo[i] <= b.hi[i]) & static_cast<uint32_t>(b.lo[i] <= a.hi[i]);
    }
    return ok;
  }
  void Resize(size_t n) {
    rows_.resize(n * kRows);
    live_bits_.resize(n / kBlock, 0);
    if (matrix_) {
      // Rows and columns of the slots beyond a smaller n are all clear (those slots are dead).
      const size_t from = size_ / kBlock, to = n / kBlock;
      if (from != to) {
        std::vector<uint16_t> pairs(n * to, 0);
        for (size_t h = 0; h < std::min<size_t>(n, size_); ++h) {
          std::copy_n(pairs_.begin() + static_cast<ptrdiff_t>(h * from), std::min(from, to),
                      pairs.begin() + static_cast<ptrdiff_t>(h * to));
        }
        pairs_.swap(pairs);
      }
    }
    size_ = static_cast<uint32_t>(n);
  }
  void Mark(Scratch& s, uint32_t h, bool live) {
    if (!matrix_) s.before[s.count] = Before{live ? BoxAt(h) : Box<K, T>{}, live ? 1u : 0u};
    s.order[s.count++] = h;
  }

  // ---- the bit matrix: bit j % kBlock of pairs_[h * blocks + j / kBlock] is set iff slots h and
  // j are a reported pair (both live, boxes overlapping, accepted by the filter) ----

  uint16_t* PairRow(uint32_t h) { return pairs_.data() + size_t{h} * (size_ / kBlock); }
  const uint16_t* PairRow(uint32_t h) const { return pairs_.data() + size_t{h} * (size_ / kBlock); }
  void FlipPair(uint32_t a, uint32_t b) {
    PairRow(a)[b / kBlock] ^= static_cast<uint16_t>(1u << (b % kBlock));
    PairRow(b)[a / kBlock] ^= static_cast<uint16_t>(1u << (a % kBlock));
  }

  // At the start of a query that leaves the cell with `top` slots: drops the matrix of a cell
  // growing beyond matrix_slots, or builds one, from the boxes as they are (the pairs last
  // reported), for a cell that has at most half as many, or that is empty (nothing to build)
  // and stays within the cap.
  void ChooseMode(size_t top) {
    const size_t cap = options_.matrix_slots;
    if (matrix_ && top > cap) {
      matrix_ = false;
      pairs_ = {};
    } else if (!matrix_ && cap != 0 && (top <= cap / 2 || (size_ == 0 && top <= cap))) {
      matrix_ = true;
      pairs_.assign(size_t{size_} * (size_ / kBlock), 0);
      for (uint32_t a = 0; a < size_; ++a) {
        if (!Live(a)) continue;
        const Box<K, T> box = BoxAt(a);
        for (uint32_t b = a + 1; b < size_; ++b) {
          if (Live(b) && OverlapsFlat(box, BoxAt(b)) != 0 && Accepts(a, b)) FlipPair(a, b);
        }
      }
    }
  }

  // Compact's move of live slot `from` to dead slot `to`: its row, and its bit in its partners'.
  void MoveMatrixSlot(uint32_t from, uint32_t to) {
    const uint32_t blocks = size_ / kBlock;
    uint16_t* row = PairRow(from);
    for (uint32_t b = 0; b < blocks; ++b) {
      for (uint32_t bits = row[b]; bits != 0; bits &= bits - 1) {
        const uint32_t k = b * kBlock + static_cast<uint32_t>(std::countr_zero(bits));
        PairRow(k)[from / kBlock] ^= static_cast<uint16_t>(1u << (from % kBlock));
        PairRow(k)[to / kBlock] ^= static_cast<uint16_t>(1u << (to % kBlock));
      }
    }
    std::copy_n(row, blocks, PairRow(to));
    std::fill_n(row, blocks, uint16_t{0});
  }

  // The matrix query: each changed slot c, in order, is tested now against the cell's live
  // slots, and every bit where that differs from c's row is a changed pair, reported and
  // flipped at once (in c's row and its partner's). A pair of two changed slots is thus
  // reported by the first of them and agrees from the second's side; a scan skips a block
  // whose live and paired slots are all changed slots already done.
  // The loop is spelled out once per kernel (BP_DENSE_MATRIX_LOOP), in a function with that
  // kernel's target attribute, so that the kernel's scan inlines into it: GCC does not inline an
  // AVX2 function into one without the attribute (a template instantiated from it does not take
  // it either), and the call with the scan's set-up took about 65 instructions per changed slot.
  // The scans are always_inline: at -O2 and below GCC kept them as calls even so.
#define BP_DENSE_MATRIX_LOOP(SCAN)                                                          \
  do {                                                                                      \
    const uint32_t blocks = size_ / kBlock;                                                 \
    BP_ASSERT(blocks <= kMaxMatrixBlocks); /* ChooseMode drops the matrix beyond the cap */ \
    uint32_t done[kMaxMatrixBlocks];       /* per block, the changed slots done */          \
    std::fill_n(done, blocks, 0u);                                                          \
    Hit hits[kMaxMatrixBlocks];                                                             \
    for (const uint32_t c : std::span(s.order.data(), s.count)) {                           \
      /* c is done from its own scan on: its bit keeps it from pairing with itself. */      \
      done[c / kBlock] |= 1u << (c % kBlock);                                               \
      const uint32_t n = SCAN(c, done, hits);                                               \
      const bool filter = options_of_.MayRefuse(c); /* else Accepts holds */                \
      for (uint32_t k = 0; k < n; ++k) {                                                    \
        const Hit& hit = hits[k];                                                           \
        for (uint32_t diff = hit.diff; diff != 0; diff &= diff - 1) {                       \
          const auto i = static_cast<uint32_t>(std::countr_zero(diff));                     \
          const uint32_t j = hit.block * kBlock + i;                                        \
          if (filter && !Accepts(c, j)) continue;                                           \
          changes_.push_back(Change{c, j, ((hit.now >> i) & 1u) != 0});                     \
          FlipPair(c, j);                                                                   \
        }                                                                                   \
      }                                                                                     \
    }                                                                                       \
  } while (false)

  void FindChangesMatrix(Scratch& s) {
#ifdef BP_DENSE_WIDE
    if constexpr (kHasWideRows<T>) {
      if (kernel_ == DenseKernel::kAvx512) return FindChangesMatrixWide(s);
    }
    if constexpr (kHasAvx2Rows<T>) {
      if (kernel_ == DenseKernel::kAvx2) return FindChangesMatrixAvx2(s);
    }
#endif
    BP_DENSE_MATRIX_LOOP(ScanMatrix);
  }
#ifdef BP_DENSE_WIDE
  BP_WIDE_TARGET void FindChangesMatrixWide(Scratch& s) requires kHasWideRows<T> {
    BP_DENSE_MATRIX_LOOP(ScanMatrixWide);
  }
  BP_AVX2_TARGET void FindChangesMatrixAvx2(Scratch& s) requires kHasAvx2Rows<T> {
    BP_DENSE_MATRIX_LOOP(ScanMatrixAvx2);
  }
#endif
#undef BP_DENSE_MATRIX_LOOP

  // Writes to hits the blocks where changed slot c's tests now differ from its row of the matrix
  // (the slots done, c among them, excluded); returns their number. The portable kernel
  // (PortableBlock).
  [[gnu::always_inline]] uint32_t ScanMatrix(uint32_t c, const uint32_t* done, Hit* hits) {
    T nlo[kAxes], nhi[kAxes];
    for (size_t a = 0; a < kAxes; ++a) {
      nlo[a] = rows_[At(c, 2 * a)];
      nhi[a] = rows_[At(c, 2 * a + 1)];
    }
    const uint32_t blocks = size_ / kBlock;
    const uint32_t live = Live(c) ? 0xFFFFu : 0u;
    const uint16_t* then = PairRow(c);
    const uint16_t* live_bits = live_bits_.data();
    const T* block = rows_.data();
    uint32_t n = 0, tested = 0;
    for (uint32_t b = 0; b < blocks; ++b, block += kBlockValues) {
      uint32_t now = uint32_t{live_bits[b]} & live;
      const uint32_t was = then[b], open = ~done[b];
      if (((now | was) & open) == 0) continue;
      ++tested;
      if (now != 0) now &= PortableBlock<T, kAxes>(block, nlo, nhi);
      const uint32_t diff = (now ^ was) & open;
      if (diff != 0) hits[n++] = Hit{b, diff, now};
    }
    tests_ += size_t{tested} * kBlock;
    return n;
  }

  // The pairs whose status differs between the last query and now, each reported once. With
  // few changed slots (most cells in most frames) the current rows stand for "then" too, which
  // they are for every unchanged slot, and the pairs among the changed slots are decided one by
  // one; with more, the scratch holds the rows as they were and one pass settles every pair.
  void FindChanges(Scratch& s) {
    if (matrix_) {
      FindChangesMatrix(s);
      return;
    }
    const std::span<const uint32_t> order(s.order.data(), s.count);
    const std::span<const Before> before(s.before.data(), s.count);
    if (order.size() <= kFewChanges) {
      for (uint32_t r = 0; r < order.size(); ++r) {
        const uint32_t c = order[r];
        ScanBlocks(rows_.data(), live_bits_.data(), c, before[r], nullptr,
                   [&](uint32_t j, bool now) {
                     if (std::find(order.begin(), order.end(), j) != order.end()) return;
                     if (Accepts(c, j)) changes_.push_back(Change{c, j, now});
                   });
        // The pairs among the changed slots, tested without branches: this loop's short-circuit
        // branches are unpredictable, and they held most of its time.
        const Box<K, T> c_now = BoxAt(c);
        const uint32_t c_live = Live(c) ? 1u : 0u;
        for (uint32_t q = r + 1; q < order.size(); ++q) {
          const uint32_t j = order[q];
          BP_ASSERT(j != c);  // one operation per slot and query
          const bool then =
              (before[r].live & before[q].live & OverlapsFlat(before[r].box, before[q].box)) != 0;
          const bool now = (c_live & (Live(j) ? 1u : 0u) & OverlapsFlat(c_now, BoxAt(j))) != 0;
          if (then != now && Accepts(c, j)) changes_.push_back(Change{c, j, now});
        }
      }
      return;
    }
    s.then_rows.assign(rows_.begin(), rows_.end());
    s.then_live.assign(live_bits_.begin(), live_bits_.end());
    s.changed.assign(size_, 0);
    s.steady.resize(size_ / kBlock);
    for (uint32_t b = 0; b < size_ / kBlock; ++b) {
      s.steady[b] = static_cast<uint32_t>(std::popcount(live_bits_[b]));
    }
    for (uint32_t r = 0; r < order.size(); ++r) {
      const uint32_t h = order[r];
      BP_ASSERT(s.changed[h] == 0);  // one operation per slot and query
      s.changed[h] = 1;
      s.steady[h / kBlock] -= Live(h) ? 1u : 0u;
      const uint32_t bit = 1u << (h % kBlock), word = s.then_live[h / kBlock];
      s.then_live[h / kBlock] =
          static_cast<uint16_t>(before[r].live != 0 ? word | bit : word & ~bit);
      if (before[r].live == 0) continue;
      for (size_t a = 0; a < kAxes; ++a) {
        s.then_rows[At(h, 2 * a)] = before[r].box.lo[a];
        s.then_rows[At(h, 2 * a + 1)] = before[r].box.hi[a];
      }
    }
    for (uint32_t r = 0; r < order.size(); ++r) {
      const uint32_t c = order[r];
      ScanBlocks(s.then_rows.data(), s.then_live.data(), c, before[r], s.steady.data(),
                 [&](uint32_t j, bool now) {
                   if (s.changed[j] != 0 && j < c) return;  // decided from j's side
                   if (Accepts(c, j)) changes_.push_back(Change{c, j, now});
                 });
    }
  }

  // Calls report(j, overlapping_now) for every slot j != c whose pair with changed slot c
  // differs between "then" (then_rows, then_live, and c's old state) and now. Blocks are tested
  // branch-free (vectorised), and only a block with a difference is looked at slot by slot. With
  // `steady` (live unchanged slots per block), a block below c's without any is skipped: its
  // pairs with c are decided by its own changed slots (when every object moves, that halves the
  // tests).
  template <class Report>
  void ScanBlocks(const T* then_rows, const uint16_t* then_live, uint32_t c, const Before& old,
                  const uint32_t* steady, Report&& report) {
#ifdef BP_DENSE_WIDE
    if constexpr (kHasWideRows<T>) {
      if (kernel_ == DenseKernel::kAvx512) {
        ScanBlocksWide(then_rows, then_live, c, old, steady, report);
        return;
      }
    }
    if constexpr (kHasAvx2Rows<T>) {
      if (kernel_ == DenseKernel::kAvx2) {
        ScanBlocksAvx2(then_rows, then_live, c, old, steady, report);
        return;
      }
    }
#endif
    T nlo[kAxes], nhi[kAxes];
    for (size_t a = 0; a < kAxes; ++a) {
      nlo[a] = rows_[At(c, 2 * a)];
      nhi[a] = rows_[At(c, 2 * a + 1)];
    }
    const uint32_t c_block = c / kBlock, blocks = size_ / kBlock;
    const bool was_live = old.live != 0, is_live = Live(c);
    for (uint32_t b = 0; b < blocks; ++b) {
      if (steady != nullptr && b < c_block && steady[b] == 0) continue;
      tests_ += 2 * kBlock;
      uint32_t then_bits = was_live ? uint32_t{then_live[b]} : 0;
      uint32_t now_bits = is_live ? uint32_t{live_bits_[b]} : 0;
      if (then_bits != 0) {
        then_bits &= PortableBlock<T, kAxes>(then_rows + size_t{b} * kBlockValues,
                                             old.box.lo.data(), old.box.hi.data());
      }
      if (now_bits != 0) {
        now_bits &= PortableBlock<T, kAxes>(rows_.data() + size_t{b} * kBlockValues, nlo, nhi);
      }
      uint32_t diff = then_bits ^ now_bits;
      if (b == c_block) diff &= ~(1u << (c % kBlock));
      while (diff != 0) {
        const auto i = static_cast<uint32_t>(std::countr_zero(diff));
        diff &= diff - 1;
        report(b * kBlock + i, ((now_bits >> i) & 1u) != 0);
      }
    }
  }

#ifdef BP_DENSE_WIDE
  // ScanBlocks with AVX-512: one register per row of a block (two for double), the then and now
  // tests as bit masks, and only the differing bits visited. A loop of its own, not a kernel
  // plugged into ScanBlocks: the intrinsics inline only into a function compiled for AVX-512.
  template <class Report>
  BP_WIDE_TARGET void ScanBlocksWide(const T* then_rows, const uint16_t* then_live, uint32_t c,
                                     const Before& old, const uint32_t* steady,
                                     Report& report) requires kHasWideRows<T> {
    T nlo[kAxes], nhi[kAxes];
    for (size_t a = 0; a < kAxes; ++a) {
      nlo[a] = rows_[At(c, 2 * a)];
      nhi[a] = rows_[At(c, 2 * a + 1)];
    }
    const uint32_t c_block = c / kBlock, blocks = size_ / kBlock;
    const bool was_live = old.live != 0, is_live = Live(c);
    for (uint32_t b = 0; b < blocks; ++b) {
      if (steady != nullptr && b < c_block && steady[b] == 0) continue;
      tests_ += 2 * kBlock;
      const T* then_block = then_rows + size_t{b} * kBlockValues;
      const T* now_block = rows_.data() + size_t{b} * kBlockValues;
      uint32_t then_bits = was_live ? uint32_t{then_live[b]} : 0;
      uint32_t now_bits = is_live ? uint32_t{live_bits_[b]} : 0;
      for (size_t a = 0; a < kAxes; ++a) {
        const size_t lo = 2 * a * kBlock, hi = lo + kBlock;
        then_bits = WideRows<T>::Overlap(then_bits, then_block + lo, then_block + hi, old.box.lo[a],
                                         old.box.hi[a]);
        now_bits = WideRows<T>::Overlap(now_bits, now_block + lo, now_block + hi, nlo[a], nhi[a]);
      }
      uint32_t diff = then_bits ^ now_bits;
      if (b == c_block) diff &= ~(1u << (c % kBlock));
      while (diff != 0) {
        const auto i = static_cast<uint32_t>(std::countr_zero(diff));
        diff &= diff - 1;
        report(b * kBlock + i, ((now_bits >> i) & 1u) != 0);
      }
    }
  }

  // ScanMatrix with AVX-512: a block whose live and paired slots are all done is skipped.
  [[gnu::always_inline]] BP_WIDE_TARGET uint32_t
  ScanMatrixWide(uint32_t c, const uint32_t* done, Hit* hits) requires kHasWideRows<T> {
    T nlo[kAxes], nhi[kAxes];
    for (size_t a = 0; a < kAxes; ++a) {
      nlo[a] = rows_[At(c, 2 * a)];
      nhi[a] = rows_[At(c, 2 * a + 1)];
    }
    const uint32_t blocks = size_ / kBlock;
    const uint32_t live = Live(c) ? 0xFFFFu : 0u;
    const uint16_t* then = PairRow(c);
    const uint16_t* live_bits = live_bits_.data();
    const T* block = rows_.data();
    uint32_t n = 0, tested = 0;
    for (uint32_t b = 0; b < blocks; ++b, block += kBlockValues) {
      uint32_t now = uint32_t{live_bits[b]} & live;
      const uint32_t was = then[b], open = ~done[b];
      if (((now | was) & open) == 0) continue;
      ++tested;
      for (size_t a = 0; a < kAxes; ++a) {
        const size_t lo = 2 * a * kBlock, hi = lo + kBlock;
        now = WideRows<T>::Overlap(now, block + lo, block + hi, nlo[a], nhi[a]);
      }
      const uint32_t diff = (now ^ was) & open;
      if (diff != 0) hits[n++] = Hit{b, diff, now};
    }
    tests_ += size_t{tested} * kBlock;
    return n;
  }

  // ScanBlocks under AVX2: each block's tests, then and now, as 16-bit masks (Avx2Rows). The
  // same loop as the portable ScanBlocks with Avx2Rows for PortableBlock, written out again rather
  // than shared as a template over the kernel: the intrinsics inline only into a function compiled
  // for AVX2, and the portable loop must not be.
  template <class Report>
  BP_AVX2_TARGET void ScanBlocksAvx2(const T* then_rows, const uint16_t* then_live, uint32_t c,
                                     const Before& old, const uint32_t* steady,
                                     Report& report) requires kHasAvx2Rows<T> {
    T nlo[kAxes], nhi[kAxes];
    for (size_t a = 0; a < kAxes; ++a) {
      nlo[a] = rows_[At(c, 2 * a)];
      nhi[a] = rows_[At(c, 2 * a + 1)];
    }
    const uint32_t c_block = c / kBlock, blocks = size_ / kBlock;
    const bool was_live = old.live != 0, is_live = Live(c);
    for (uint32_t b = 0; b < blocks; ++b) {
      if (steady != nullptr && b < c_block && steady[b] == 0) continue;
      tests_ += 2 * kBlock;
      uint32_t then_bits = was_live ? uint32_t{then_live[b]} : 0;
      uint32_t now_bits = is_live ? uint32_t{live_bits_[b]} : 0;
      if (then_bits != 0) {
        then_bits &= Avx2Rows<T>::template Block<kAxes>(then_rows + size_t{b} * kBlockValues,
                                                        old.box.lo.data(), old.box.hi.data());
      }
      if (now_bits != 0) {
        now_bits &=
            Avx2Rows<T>::template Block<kAxes>(rows_.data() + size_t{b} * kBlockValues, nlo, nhi);
      }
      uint32_t diff = then_bits ^ now_bits;
      if (b == c_block) diff &= ~(1u << (c % kBlock));
      while (diff != 0) {
        const auto i = static_cast<uint32_t>(std::countr_zero(diff));
        diff &= diff - 1;
        report(b * kBlock + i, ((now_bits >> i) & 1u) != 0);
      }
    }
  }

  // ScanMatrix under AVX2 (a copy of its loop, for the reason given at ScanBlocksAvx2): a block
  // whose live and paired slots are all done is skipped.
  [[gnu::always_inline]] BP_AVX2_TARGET uint32_t
  ScanMatrixAvx2(uint32_t c, const uint32_t* done, Hit* hits) requires kHasAvx2Rows<T> {
    T nlo[kAxes], nhi[kAxes];
    for (size_t a = 0; a < kAxes; ++a) {
      nlo[a] = rows_[At(c, 2 * a)];
      nhi[a] = rows_[At(c, 2 * a + 1)];
    }
    const uint32_t blocks = size_ / kBlock;
    const uint32_t live = Live(c) ? 0xFFFFu : 0u;
    const uint16_t* then = PairRow(c);
    const uint16_t* live_bits = live_bits_.data();
    const T* block = rows_.data();
    uint32_t n = 0, tested = 0;
    for (uint32_t b = 0; b < blocks; ++b, block += kBlockValues) {
      uint32_t now = uint32_t{live_bits[b]} & live;
      const uint32_t was = then[b], open = ~done[b];
      if (((now | was) & open) == 0) continue;
      ++tested;
      if (now != 0) now &= Avx2Rows<T>::template Block<kAxes>(block, nlo, nhi);
      const uint32_t diff = (now ^ was) & open;
      if (diff != 0) hits[n++] = Hit{b, diff, now};
    }
    tests_ += size_t{tested} * kBlock;
    return n;
  }
#endif

  Options options_;
  DenseKernel kernel_;               // the box-test kernel that runs (never kAuto)
  bool matrix_ = false;              // the cell's pairs are kept in pairs_
  std::vector<T> rows_;              // per block: lo[0], hi[0], lo[1], ... (kBlock values each)
  std::vector<uint16_t> live_bits_;  // per block: bit i set iff slot b * kBlock + i is live
  uint32_t size_ = 0;                // slots (the grid's local handles), a multiple of kBlock
  size_t live_ = 0;
  OptionsTable options_of_;      // by slot
  std::vector<uint16_t> pairs_;  // with matrix_: size_ rows of size_ / kBlock words (see PairRow)
  std::vector<Change> changes_;
  size_t tests_ = 0;
};

template <int K, Coordinate T>
Status DenseCellCore<K, T>::Validate() const {
  auto fail = [](const std::string& what) {
    return Status(StatusCode::kInternal, "dense cell: " + what);
  };
  if (!changes_.empty()) return fail("changes left after a query");
  if (size_ % kBlock != 0 || rows_.size() != size_t{size_} * kRows ||
      live_bits_.size() != size_ / kBlock) {
    return fail("arrays of the wrong size");
  }
  size_t live = 0;
  for (uint32_t h = 0; h < size_; ++h) {
    if (!Live(h)) continue;
    ++live;
    Box<K, T> b = BoxAt(h);
    for (size_t a = 0; a < kAxes; ++a) {
      if (b.hi[a] < b.lo[a]) return fail("slot " + std::to_string(h) + ": bad box");
    }
  }
  if (live != live_) return fail("live count differs");
  if (!matrix_) return pairs_.empty() ? Status::Ok() : fail("a matrix kept in the rows mode");
  if (pairs_.size() != size_t{size_} * (size_ / kBlock)) return fail("matrix of the wrong size");
  for (uint32_t a = 0; a < size_; ++a) {
    for (uint32_t b = 0; b < size_; ++b) {
      const bool bit = ((unsigned{PairRow(a)[b / kBlock]} >> (b % kBlock)) & 1u) != 0;
      const bool pair =
          a != b && Live(a) && Live(b) && Accepts(a, b) && OverlapsFlat(BoxAt(a), BoxAt(b)) != 0;
      if (bit != pair) {
        return fail("matrix bit of slots " + std::to_string(a) + " and " + std::to_string(b) +
                    (bit ? " set for no pair" : " clear for a pair"));
      }
    }
  }
  return Status::Ok();
}

}  // namespace detail
}  // namespace bp
