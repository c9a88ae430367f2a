// bp::service::KeepAwake: threads of the lowest scheduling class (SCHED_IDLE), one pinned to each
// CPU the daemon may run on, that spin for a window after each update batch so that no CPU halts
// while frames flow (frames.keep_cpus_awake_ms).
//
// Why: on a virtual machine an idle CPU halts, and waking it (a packet for the DDS receive
// thread, the engine's worker for the query) exits to the hypervisor, and the frame waits for
// it; on such guests the query's tail is then several times its median. What it buys is
// measured end to end in docs/RESULTS.md.
//
// A SCHED_IDLE thread has the lowest weight the scheduler knows (3, against 1024 for a normal
// thread), so within the guest it takes almost no time from the daemon or any other process
// (the kernel preempts it at once for a woken thread); it keeps the CPU from halting. Touch
// takes no lock, so a spinner preempted anywhere never holds the daemon up.
//
// Each spin round calls sched_yield. Weight alone does not keep a spinner behind the daemon: the
// EEVDF scheduler (Linux 6.6 on) picks among the eligible threads of a CPU, and a runnable thread
// that has just run ahead of its share (a daemon thread preempted by another process's thread) may
// be ineligible, so the spinner would be picked and keep the CPU until the next tick. The yield
// hands the CPU back at once whenever another thread is runnable. bench/keep_awake_probe.cc
// (bpawake) measures this apart from the daemon: a thread that shares its CPU with another
// normal thread, beside spinners and without.
// Outside the guest it is not free: every CPU reads busy while batches keep arriving, plus the
// window (power, and the host's cycles), and where two virtual CPUs share a physical core the
// spin takes issue slots from the other. After the window the threads block until the next
// batch.
//
// The spin loop does not use PAUSE: a hypervisor's pause-loop exiting would deschedule the CPU
// just as halting does.
//
// Stopping waits for each thread to see the stop, which takes a moment of its CPU: on a loaded
// machine, where SCHED_IDLE threads run least, over a second.
//
// Thread safety: Touch may be called from any thread; the rest from the owner.
// Invariants:
//  1. The threads spin only while now < deadline (the last Touch plus the window), else wait on
//     generation_ (a futex): a thread counts itself in waiting_ before it checks the deadline,
//     and Touch stores the deadline before it reads waiting_ (both sequentially consistent), so
//     either the thread sees the new deadline or Touch sees it waiting and bumps generation_,
//     which ends or prevents its wait.
//  2. The destructor returns after every thread has stopped.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <future>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "bp/status.h"

namespace bp::service {

class KeepAwake {
 public:
  /// Starts one thread per CPU in this process's affinity mask (at most 256), each pinned to its
  /// CPU and switched to SCHED_IDLE, waiting for the first Touch. Fails (and starts nothing)
  /// when a thread cannot take the SCHED_IDLE class, so that no thread ever spins at a normal
  /// priority. window must be positive.
  static Status Start(std::chrono::nanoseconds window, std::unique_ptr<KeepAwake>* out);
  ~KeepAwake();
  KeepAwake(const KeepAwake&) = delete;
  KeepAwake& operator=(const KeepAwake&) = delete;

  /// Keeps the CPUs awake until now + window (an update batch arrived).
  void Touch();

  /// The threads started (one per CPU).
  unsigned threads() const { return static_cast<unsigned>(threads_.size()); }
  /// Threads counted as waiting for a Touch (for tests).
  unsigned waiting() const { return waiting_.load(std::memory_order_relaxed); }
  /// Spin rounds so far, all threads together (each round reads the clock once).
  uint64_t rounds() const { return rounds_.load(std::memory_order_relaxed); }

 private:
  explicit KeepAwake(std::chrono::nanoseconds window) : window_(window) {}
  void Run(int cpu, std::promise<Status>* started);
  static int64_t NowNs();

  const std::chrono::nanoseconds window_;
  std::vector<std::thread> threads_;
  std::atomic<uint32_t> generation_{0};  // bumped to wake waiting threads (Touch, the destructor)
  std::atomic<int64_t> deadline_ns_{0};  // steady clock; spin while now is before it
  std::atomic<unsigned> waiting_{0};
  std::atomic<uint64_t> rounds_{0};
  std::atomic<bool> stop_{false};
};

}  // namespace bp::service
