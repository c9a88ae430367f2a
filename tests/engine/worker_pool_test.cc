// bp::detail::WorkerPool: every index runs exactly once per loop, on a thread ordinal below
// threads(), whether the workers are still polling from the last loop (loops back to back) or
// have blocked (a pause longer than the poll between loops); a worker waking after its loop
// closed stays out of it; and the pool stops cleanly in either state.
#include "bp/detail/worker_pool.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstddef>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

namespace bp::test {
namespace {

// Runs `loops` loops of n indices with the given grain, pausing `pause` between loops; checks
// each index ran once and every thread ordinal is valid. Returns the indices the workers ran.
size_t RunLoops(detail::WorkerPool& pool, int loops, size_t n, size_t grain,
                std::chrono::microseconds pause) {
  size_t on_workers = 0;
  std::vector<std::atomic<int>> hits(n);
  for (int loop = 0; loop < loops; ++loop) {
    for (auto& h : hits) h.store(0, std::memory_order_relaxed);
    std::atomic<bool> bad_thread{false};
    pool.ParallelFor(n, grain, [&](size_t begin, size_t end, unsigned thread) {
      if (thread >= pool.threads() || begin >= end || end > n) bad_thread = true;
      for (size_t i = begin; i < end; ++i) hits[i].fetch_add(1, std::memory_order_relaxed);
    });
    EXPECT_FALSE(bad_thread.load());
    size_t wrong = 0;
    for (size_t i = 0; i < n; ++i) wrong += hits[i].load() == 1 ? 0u : 1u;
    EXPECT_EQ(wrong, 0u) << "loop " << loop << ": indices not run exactly once";
    on_workers += pool.last_on_workers();
    if (pause.count() > 0) std::this_thread::sleep_for(pause);
  }
  return on_workers;
}

TEST(WorkerPool, EveryIndexOnceWhetherWorkersPollOrSleep) {
  for (unsigned threads : {1u, 2u, 4u}) {
    detail::WorkerPool pool(threads);
    EXPECT_EQ(pool.threads(), threads);
    // Back to back: the workers are still polling when the next loop starts.
    size_t on_workers = RunLoops(pool, 200, 1000, 7, std::chrono::microseconds(0));
    // Paused longer than the poll: the workers have blocked and are woken.
    on_workers += RunLoops(pool, 5, 1000, 7, std::chrono::microseconds(5000));
    if (threads == 1) {
      EXPECT_EQ(on_workers, 0u);
    }
    // Small loops (n < 2 and one run) stay on the caller.
    RunLoops(pool, 3, 1, 4, std::chrono::microseconds(0));
    RunLoops(pool, 3, 0, 4, std::chrono::microseconds(0));
  }
}

// A loop's body runs only inside its ParallelFor: a worker that wakes after the caller closed
// the loop (it ran every run itself) must not enter it. Loops with pauses of 0 to 2 ms between
// them catch the workers polling, blocking and waking at every point; each body call checks that
// its loop is still in progress, and each index still runs exactly once.
TEST(WorkerPool, LateWorkersNeverRunAClosedLoop) {
  detail::WorkerPool pool(3);
  std::atomic<int> in_loop{-1};
  std::atomic<int> strays{0};
  uint64_t x = 12345;
  for (int loop = 0; loop < 300; ++loop) {
    x = x * 6364136223846793005ull + 1442695040888963407ull;
    const size_t n = 1 + (x >> 33) % 40;
    std::vector<std::atomic<int>> hits(n);
    in_loop.store(loop);
    pool.ParallelFor(n, 1 + (x >> 20) % 4, [&](size_t begin, size_t end, unsigned) {
      if (in_loop.load() != loop) strays.fetch_add(1);
      for (size_t i = begin; i < end; ++i) hits[i].fetch_add(1);
    });
    in_loop.store(-1);
    for (size_t i = 0; i < n; ++i) ASSERT_EQ(hits[i].load(), 1) << "loop " << loop;
    std::this_thread::sleep_for(std::chrono::microseconds((x >> 40) % 2000));
  }
  EXPECT_EQ(strays.load(), 0);
}

TEST(WorkerPool, StopsWhilePollingAndWhileBlocked) {
  {
    detail::WorkerPool pool(3);
    RunLoops(pool, 2, 100, 1, std::chrono::microseconds(0));
  }  // destroyed right after a loop: the workers are polling
  {
    detail::WorkerPool pool(3);
    RunLoops(pool, 2, 100, 1, std::chrono::microseconds(0));
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }                                // destroyed with the workers blocked
  { detail::WorkerPool pool(2); }  // never used
}

// Guided runs cover [0, n) in order, long first: whole units between least and most but the
// last, never growing, and within a quarter of what is left per thread.
TEST(WorkerPool, GuidedRunsCoverInWholeUnitsLongFirst) {
  for (const size_t n :
       {size_t{0}, size_t{1}, size_t{31}, size_t{5000}, size_t{32768}, size_t{100000}}) {
    for (const unsigned threads : {1u, 2u, 4u}) {
      for (const size_t unit : {size_t{1}, size_t{64}, size_t{2048}}) {
        const size_t least = unit == 1 ? 32 : unit, most = unit == 1 ? 512 : unit * 8;
        std::vector<size_t> runs;
        detail::GuidedRuns(n, threads, unit, least, most, &runs);
        ASSERT_FALSE(runs.empty());
        EXPECT_EQ(runs.front(), 0u);
        EXPECT_EQ(runs.back(), n);
        for (size_t r = 0; r + 1 < runs.size(); ++r) {
          const size_t len = runs[r + 1] - runs[r];
          ASSERT_GT(len, 0u) << n << " " << threads << " " << unit;
          if (r + 2 == runs.size()) continue;  // the last: the rest
          EXPECT_EQ(len % unit, 0u);
          EXPECT_GE(len, least);
          EXPECT_LE(len, most);
          EXPECT_LE(len, std::max(least, (n - runs[r]) / (4 * threads)));
          if (r > 0) {
            EXPECT_LE(len, runs[r] - runs[r - 1]);
          }
        }
      }
    }
  }
}

}  // namespace
}  // namespace bp::test
