// The dense cell (bp/dense_cell.h) and its kernels (detail/dense_kernels.h), directly on cells:
// the pair matrix and the rows with every kernel report the same changes, and a requested
// kernel resolves to what the CPU runs.
#include <cstdint>
#include <string>
#include <vector>

#include "grid_test_support.h"

namespace bp::test {
namespace {

// The dense cell's modes against each other, directly on cells: the pair matrix with each
// kernel (AVX-512, AVX2 and portable; one the CPU lacks runs the next narrower), the rows (no
// matrix, then and now tested: few and many changes per query, both paths of FindChanges) with
// each kernel, and a matrix capped at 64 slots. Random boxes on a small lattice (many exact
// touches and equal coordinates), random erases, updates and inserts; phases alternate between
// handles below 24 and below 70, and a low phase starts by erasing the high handles and
// compacting, so that the capped cell drops its matrix and builds it again. Every change list is
// compared, and every cell validated (matrix against boxes).
template <class T>
void ExpectCellModesAgree(uint64_t seed) {
  using Core = detail::DenseCellCore<3, T>;
  using HB = detail::HandleBox<3, T>;
  // Core 0: the matrix and the widest kernel; 1: capped matrix; then matrix and rows per kernel.
  std::vector<Core> cores;
  cores.emplace_back(DenseCellOptions{});
  DenseCellOptions capped;
  capped.matrix_slots = 64;
  cores.emplace_back(capped);
  for (DenseKernel k : {DenseKernel::kAvx512, DenseKernel::kAvx2, DenseKernel::kPortable}) {
    DenseCellOptions matrix, rows;
    matrix.kernel = rows.kernel = k;
    rows.matrix_slots = 0;
    cores.emplace_back(matrix);
    cores.emplace_back(rows);
  }
  std::mt19937_64 rng(seed);
  auto coord = [&] { return static_cast<T>(static_cast<int>(rng() % 12)); };
  auto box = [&] {
    Box<3, T> b;
    for (size_t a = 0; a < 3; ++a) {
      b.lo[a] = coord();
      b.hi[a] = static_cast<T>(b.lo[a] + static_cast<T>(rng() % 4));
    }
    return b;
  };
  std::vector<bool> live(70, false);
  size_t changes = 0, switches = 0;
  bool had_matrix = false;
  for (int query = 0; query < 480; ++query) {
    const bool low = (query / 60) % 2 == 0;
    const uint32_t range = low ? 24 : 70;
    std::vector<uint32_t> erases;
    std::vector<HB> updates, inserts;
    const bool phase_start = query % 60 == 0 && query > 0;
    const uint64_t ops = query % 3 == 0 ? 40 : 1 + rng() % 8;
    std::vector<bool> used(live.size(), false);
    if (phase_start && low) {
      for (uint32_t h = range; h < live.size(); ++h) {
        if (live[h]) erases.push_back(h);
      }
    } else {
      for (uint64_t i = 0; i < ops; ++i) {
        const auto h = static_cast<uint32_t>(rng() % range);
        if (used[h]) continue;
        used[h] = true;
        if (!live[h]) {
          inserts.push_back({h, box()});
        } else if (rng() % 4 == 0) {
          erases.push_back(h);
        } else {
          updates.push_back({h, box()});
        }
      }
    }
    for (uint32_t h : erases) live[h] = false;
    for (const HB& hb : inserts) live[hb.handle] = true;
    std::vector<std::vector<std::tuple<uint32_t, uint32_t, bool>>> got(cores.size());
    for (size_t c = 0; c < cores.size(); ++c) {
      cores[c].Apply(erases, updates, inserts);
      cores[c].DrainChanges([&](uint32_t x, uint32_t y, bool now) {
        got[c].emplace_back(std::min(x, y), std::max(x, y), now);
      });
      std::sort(got[c].begin(), got[c].end());
      ASSERT_TRUE(cores[c].Validate().ok())
          << "core " << c << ", query " << query << ": " << cores[c].Validate().message();
      if (c > 0) {
        ASSERT_EQ(got[c], got[0]) << "core " << c << ", query " << query;
      }
    }
    changes += got[0].size();
    if (phase_start && low) {
      // The survivors sit below 24 but the cells keep 80 slots: give the blocks back (every core
      // moves the same slots: they hold the same live slots).
      std::vector<std::vector<std::pair<uint32_t, uint32_t>>> moves(cores.size());
      for (size_t c = 0; c < cores.size(); ++c) {
        cores[c].Compact([&](uint32_t from, uint32_t to) { moves[c].emplace_back(from, to); });
        ASSERT_TRUE(cores[c].Validate().ok()) << cores[c].Validate().message();
        ASSERT_EQ(moves[c], moves[0]);
      }
      for (const auto& [from, to] : moves[0]) {
        live[to] = true;
        live[from] = false;
      }
    }
    for (size_t c = 2; c < cores.size(); ++c) EXPECT_EQ(cores[c].has_matrix(), c % 2 == 0);
    EXPECT_TRUE(cores[0].has_matrix());
    switches += cores[1].has_matrix() != had_matrix;
    had_matrix = cores[1].has_matrix();
  }
  EXPECT_GT(changes, 1000u);  // the scene is not idle
  EXPECT_GE(switches, 4u);    // the capped cell dropped its matrix and built it again
}

TEST(DenseCell, MatrixRowsAndKernelsReportTheSameChanges) {
  for (uint64_t seed : {uint64_t{1}, uint64_t{2}, uint64_t{3}}) {
    ExpectCellModesAgree<float>(seed);
    ExpectCellModesAgree<double>(seed);
    ExpectCellModesAgree<int32_t>(seed);
  }
  // Which kernels ran (a kernel the CPU lacks ran as the next narrower one).
  std::string kernels;
  for (DenseKernel k : {DenseKernel::kAvx512, DenseKernel::kAvx2, DenseKernel::kPortable}) {
    if (detail::ResolveDenseKernel<float>(k) == k) {
      kernels += std::string(kernels.empty() ? "" : " ") + DenseKernelName(k);
    }
  }
  RecordProperty("kernels", kernels);
}

// A requested kernel resolves to itself when the CPU has it, else to the next narrower one, and
// a cell reports the one it runs; coordinate types without wide kernels run the portable one.
TEST(DenseCell, KernelResolvesToWhatTheCpuRuns) {
  using detail::ResolveDenseKernel;
  const bool avx512 = detail::CpuHasAvx512(), avx2 = detail::CpuHasAvx2();
  const DenseKernel widest = avx512 ? DenseKernel::kAvx512
                             : avx2 ? DenseKernel::kAvx2
                                    : DenseKernel::kPortable;
  EXPECT_EQ(ResolveDenseKernel<float>(DenseKernel::kAuto), widest);
  EXPECT_EQ(ResolveDenseKernel<double>(DenseKernel::kAuto), widest);
  EXPECT_EQ(ResolveDenseKernel<int32_t>(DenseKernel::kAuto), widest);
  EXPECT_EQ(ResolveDenseKernel<float>(DenseKernel::kAvx512), widest);
  EXPECT_EQ(ResolveDenseKernel<float>(DenseKernel::kAvx2),
            avx2 ? DenseKernel::kAvx2 : DenseKernel::kPortable);
  EXPECT_EQ(ResolveDenseKernel<float>(DenseKernel::kPortable), DenseKernel::kPortable);
  EXPECT_EQ(ResolveDenseKernel<int64_t>(DenseKernel::kAuto), DenseKernel::kPortable);
  DenseCellOptions o;
  o.kernel = DenseKernel::kAvx2;
  const detail::DenseCellCore<2, double> cell(o);
  EXPECT_EQ(cell.kernel(), ResolveDenseKernel<double>(o.kernel));
  EXPECT_STREQ(DenseKernelName(DenseKernel::kAvx2), "avx2");
  RecordProperty("widest", DenseKernelName(widest));
}

}  // namespace
}  // namespace bp::test
