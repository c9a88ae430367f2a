// bp::detail::WorkerPool: a fixed set of threads that run one index-parallel loop at a time
// (fork/join). The grid applies its touched cells through it; the caller's thread takes part, so
// a pool of t threads starts t - 1 workers.
//
// Why not oneTBB: the engine depends on the standard library only, and the grid needs one
// operation, a parallel loop over a few hundred independent cells per query, where dynamic
// claiming of indices through one atomic counter balances uneven cells well enough.
//
// Thread safety: ParallelFor is called by one thread at a time (the engine's owner); the body
// runs concurrently on distinct indices and must not throw.
// A loop does not wait for a worker that has not joined it: the caller runs runs itself until
// none is left, closes the loop, and waits only for the workers counted in it (a worker that
// counted itself in just before the close leaves at once, having found no run). A worker woken late
// (a virtual CPU's wake-up can take milliseconds, many times a small frame) finds the loop
// closed and goes back to waiting.
// Invariants:
//  1. Outside ParallelFor open_ is false, no worker runs a body and none is referenced (a late
//     worker may still count itself in and out of active_, touching nothing else).
//  2. ParallelFor returns only after every index in [0, n) has been run exactly once.
//  3. A worker runs a loop's body only after counting itself in active_ and then seeing that
//     loop open (open_ and its generation); the caller closes the loop before it waits for
//     active_ to drop to zero, so no worker enters a closed loop or outlives the body.
#pragma once

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace bp::detail {

class WorkerPool {
 public:
  /// A pool running loops on `threads` threads in all (the caller's included); at least 1.
  explicit WorkerPool(unsigned threads) {
    for (unsigned i = 1; i < std::max(threads, 1u); ++i) {
      workers_.emplace_back([this, i] { Work(i); });
    }
  }
  ~WorkerPool() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_.store(true, std::memory_order_relaxed);
    }
    wake_.notify_all();
    for (std::thread& t : workers_) t.join();
  }
  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  /// Threads in all, the caller's included.
  unsigned threads() const { return static_cast<unsigned>(workers_.size()) + 1; }
  /// Indices the last ParallelFor ran on the workers (not the caller): how much was shared.
  size_t last_on_workers() const { return on_workers_.load(std::memory_order_relaxed); }

  /// Runs body(begin, end, thread) over [0, n) cut into runs of at most `grain` consecutive
  /// indices, spread over the pool's threads (each claims the next run when it is done with
  /// one); returns when all ran. Without workers, or for n < 2, the caller runs [0, n) as one.
  /// thread is the ordinal of the thread running the run: 0 for the caller, 1.. for the workers
  /// (below threads()), so a body can write to per-thread buffers without locks, and a run lets it
  /// prefetch its own next index.
  using Body = std::function<void(size_t, size_t, unsigned)>;
  void ParallelFor(size_t n, size_t grain, const Body& body) {
    on_workers_.store(0, std::memory_order_relaxed);
    if (workers_.empty() || n < 2) {
      if (n != 0) body(0, n, 0);
      return;
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      body_ = &body;
      n_ = n;
      grain_ = std::max<size_t>(grain, 1);
      next_.store(0, std::memory_order_relaxed);
      generation_.fetch_add(1, std::memory_order_seq_cst);
      open_.store(true, std::memory_order_seq_cst);
    }
    wake_.notify_all();
    Run(body, n, 0);
    // Every run is claimed: close the loop, then wait for the workers that joined it.
    open_.store(false, std::memory_order_seq_cst);
    SpinWhile([this] { return active_.load(std::memory_order_seq_cst) != 0; });
    std::unique_lock<std::mutex> lock(mutex_);
    done_.wait(lock, [this] { return active_.load(std::memory_order_seq_cst) == 0; });
    body_ = nullptr;
  }

 private:
  // How long a thread polls before it blocks: a worker between two loops of a frame, the caller
  // for the workers' last runs. Waking a blocked thread takes tens of microseconds on a virtual
  // machine (a futex and an interrupt to the other CPU), which a late worker costs the caller
  // when the loop's runs are few; polling costs the other CPU at most this long per loop.
  static constexpr std::chrono::microseconds kSpin{1000};
  template <class Busy>
  static void SpinWhile(Busy&& busy) {
    const auto until = std::chrono::steady_clock::now() + kSpin;
    for (unsigned i = 1; busy(); ++i) {
#if defined(__x86_64__) || defined(__i386__)
      __builtin_ia32_pause();
#endif
      if (i % 64 == 0 && std::chrono::steady_clock::now() > until) return;
    }
  }

  // Runs indices until none is left; returns how many this thread ran.
  size_t Run(const Body& body, size_t n, unsigned thread) {
    size_t ran = 0;
    for (size_t i = next_.fetch_add(grain_, std::memory_order_relaxed); i < n;
         i = next_.fetch_add(grain_, std::memory_order_relaxed)) {
      const size_t end = std::min(n, i + grain_);
      body(i, end, thread);
      ran += end - i;
    }
    return ran;
  }

  void Work(unsigned thread) {
    uint64_t seen = 0;
    for (;;) {
      SpinWhile([&] {
        return generation_.load(std::memory_order_acquire) == seen &&
               !stop_.load(std::memory_order_relaxed);
      });
      {
        std::unique_lock<std::mutex> lock(mutex_);
        wake_.wait(lock, [&] {
          return stop_.load(std::memory_order_relaxed) ||
                 generation_.load(std::memory_order_relaxed) != seen;
        });
        if (stop_.load(std::memory_order_relaxed)) return;
        seen = generation_.load(std::memory_order_relaxed);
      }
      // Join the loop if it is still open (invariant 3): counted first, then checked, against
      // the caller's close-then-wait, both sequentially consistent.
      active_.fetch_add(1, std::memory_order_seq_cst);
      if (open_.load(std::memory_order_seq_cst) &&
          generation_.load(std::memory_order_seq_cst) == seen) {
        on_workers_.fetch_add(
            Run(*body_.load(std::memory_order_acquire), n_.load(std::memory_order_acquire), thread),
            std::memory_order_relaxed);
      }
      {
        std::lock_guard<std::mutex> lock(mutex_);
        active_.fetch_sub(1, std::memory_order_seq_cst);
      }
      done_.notify_one();
    }
  }

  std::vector<std::thread> workers_;
  std::mutex mutex_;
  std::condition_variable wake_;
  std::condition_variable done_;
  // The open loop's body and size, written by the caller before it opens the loop; read by a
  // worker that joined it, without the mutex.
  std::atomic<const Body*> body_{nullptr};
  std::atomic<size_t> n_{0};
  size_t grain_ = 1;  // read by Run after the same ordering as body_
  std::atomic<size_t> next_{0};
  std::atomic<size_t> on_workers_{0};
  std::atomic<size_t> active_{0};  // workers inside the current loop (joined, not yet out)
  std::atomic<bool> open_{false};  // the current loop takes workers
  // Written under mutex_ (so that a blocked waiter misses no change); atomic so that a spinning
  // thread may read them without it.
  std::atomic<uint64_t> generation_{0};
  std::atomic<bool> stop_{false};
};

/// Cuts [0, n) into runs for a ParallelFor over run indices (grain 1) whose runs start cold: a
/// run's look-ahead or prefetches have nothing in flight when it begins, so runs of a fixed
/// small size pay that often (the grid's cells in runs of 32 would start cold about a thousand
/// times in a million-object frame). Guided: each run a quarter of what is
/// left per thread, in whole units of `unit`, between `least` and `most` (multiples of unit), the
/// last run the rest; long runs first, short ones at the end, so that the threads finish
/// together. Run r is [(*runs)[r], (*runs)[r + 1]); runs->size() - 1 runs.
template <class Index>
void GuidedRuns(size_t n, unsigned threads, size_t unit, size_t least, size_t most,
                std::vector<Index>* runs) {
  const size_t per = size_t{4} * std::max(threads, 1u);
  runs->clear();
  runs->push_back(0);
  for (size_t at = 0; at < n;) {
    at = std::min(n, at + std::clamp((n - at) / per / unit * unit, least, most));
    runs->push_back(static_cast<Index>(at));
  }
}

}  // namespace bp::detail
