#include "keep_awake.h"

#include <algorithm>
#include <cstring>
#include <system_error>

#include <pthread.h>
#include <sched.h>

namespace bp::service {

int64_t KeepAwake::NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

Status KeepAwake::Start(std::chrono::nanoseconds window, std::unique_ptr<KeepAwake>* out) {
  if (window.count() <= 0) {
    return Status(StatusCode::kInvalidArgument, "KeepAwake: the window must be positive");
  }
  cpu_set_t set;
  CPU_ZERO(&set);
  std::vector<int> cpus;
  if (sched_getaffinity(0, sizeof(set), &set) == 0) {
    for (size_t cpu = 0; cpu < CPU_SETSIZE && cpus.size() < 256; ++cpu) {
      if (CPU_ISSET(cpu, &set)) cpus.push_back(static_cast<int>(cpu));
    }
  }
  if (cpus.empty()) cpus.push_back(-1);  // no mask: one unpinned thread
  // Declared before the keeper, so that the promises outlive the threads if Start fails (a
  // thread touches its promise only before Start reads it).
  std::vector<std::promise<Status>> started(cpus.size());
  std::unique_ptr<KeepAwake> keeper(new KeepAwake(window));
  keeper->threads_.reserve(cpus.size());
  Status result = Status::Ok();
  size_t running = 0;
  try {
    for (; running < cpus.size(); ++running) {
      keeper->threads_.emplace_back(
          [k = keeper.get(), cpu = cpus[running], p = &started[running]] { k->Run(cpu, p); });
    }
  } catch (const std::system_error& e) {
    result = Status(StatusCode::kUnavailable, std::string("cannot start a thread: ") + e.what());
  }
  for (size_t i = 0; i < running; ++i) {
    Status s = started[i].get_future().get();
    if (!s.ok() && result.ok()) result = s;
  }
  if (!result.ok()) return result;  // the destructor stops the threads that did start
  *out = std::move(keeper);
  return Status::Ok();
}

KeepAwake::~KeepAwake() {
  stop_.store(true, std::memory_order_seq_cst);
  generation_.fetch_add(1, std::memory_order_seq_cst);
  generation_.notify_all();
  for (std::thread& t : threads_) t.join();
}

void KeepAwake::Touch() {
  // Invariant 1: either this sees the thread counted as waiting and bumps the generation it
  // waits on, or the thread sees the new deadline and does not wait. No lock: a spinner
  // preempted anywhere cannot hold this up.
  deadline_ns_.store(NowNs() + window_.count(), std::memory_order_seq_cst);
  if (waiting_.load(std::memory_order_seq_cst) == 0) return;
  generation_.fetch_add(1, std::memory_order_seq_cst);
  generation_.notify_all();
}

void KeepAwake::Run(int cpu, std::promise<Status>* started) {
  if (cpu >= 0) {
    cpu_set_t one;
    CPU_ZERO(&one);
    CPU_SET(static_cast<size_t>(cpu), &one);
    // A CPU the thread may not use (a cpuset changed meanwhile) leaves it unpinned: it still
    // keeps some CPU awake.
    (void)pthread_setaffinity_np(pthread_self(), sizeof(one), &one);
  }
  sched_param param{};
  param.sched_priority = 0;
  if (int e = pthread_setschedparam(pthread_self(), SCHED_IDLE, &param); e != 0) {
    started->set_value(
        Status(StatusCode::kUnavailable,
               std::string("a thread cannot take the SCHED_IDLE class: ") + std::strerror(e)));
    return;
  }
  started->set_value(Status::Ok());
  uint64_t rounds = 0;
  while (!stop_.load(std::memory_order_relaxed)) {
    if (NowNs() < deadline_ns_.load(std::memory_order_relaxed)) {
      // Each round offers the CPU to any other runnable thread (see the header: without it a
      // spinner may keep a CPU for a whole scheduler tick from a runnable daemon thread); with
      // none, the call returns at once and the CPU stays busy. No PAUSE (see the header).
      sched_yield();
      ++rounds;
      continue;
    }
    rounds_.fetch_add(rounds, std::memory_order_relaxed);
    rounds = 0;
    // Invariant 1: the generation first, then counted, then the deadline checked again.
    const uint32_t generation = generation_.load(std::memory_order_seq_cst);
    waiting_.fetch_add(1, std::memory_order_seq_cst);
    if (!stop_.load(std::memory_order_seq_cst) &&
        NowNs() >= deadline_ns_.load(std::memory_order_seq_cst)) {
      generation_.wait(generation, std::memory_order_seq_cst);
    }
    waiting_.fetch_sub(1, std::memory_order_seq_cst);
  }
  rounds_.fetch_add(rounds, std::memory_order_relaxed);
}

}  // namespace bp::service
