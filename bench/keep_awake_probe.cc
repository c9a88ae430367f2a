// bpawake: what broadphased's frames.keep_cpus_awake_ms (service/keep_awake.h) costs the threads
// it runs beside, apart from DDS and the engine. On each CPU of the process a "frame" thread
// works in 2 ms bursts with 1 ms sleeps, and an "other" thread (another process's receive thread,
// say) works 0.3 ms in every 1 ms; the frame thread reads the clock in a tight loop and counts
// the gaps: the time it was runnable or preempted but off its CPU. Rounds alternate the keeper
// off and on (touched every 10 ms, as batches would). One JSON line per run.
// A keeper whose spinners do not yield shows as hundreds of gaps over 1 ms per run where no
// keeper shows a few: under EEVDF a thread that has just run past its share is not eligible, so
// the spinner's low weight alone does not keep it behind a runnable frame thread.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "keep_awake.h"
#include <CLI/CLI.hpp>
#include <pthread.h>
#include <sched.h>

namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::microseconds;

void Pin(int cpu) {
  cpu_set_t one;
  CPU_ZERO(&one);
  CPU_SET(static_cast<size_t>(cpu), &one);
  (void)pthread_setaffinity_np(pthread_self(), sizeof(one), &one);
}

struct Gaps {
  std::vector<double> us;  // gaps over the threshold
  double worked_ms = 0;
};

// Works in 2 ms bursts with 1 ms sleeps between them; records gaps over `threshold` (us) between
// two consecutive clock reads within a burst.
void FrameThread(int cpu, const std::atomic<bool>& stop, double threshold, Gaps* out) {
  Pin(cpu);
  while (!stop.load(std::memory_order_relaxed)) {
    const auto start = Clock::now();
    auto last = start;
    for (auto now = start; now - start < microseconds(2000); now = Clock::now()) {
      const double gap = std::chrono::duration<double, std::micro>(now - last).count();
      if (gap > threshold) out->us.push_back(gap);
      last = now;
    }
    out->worked_ms += std::chrono::duration<double, std::milli>(Clock::now() - start).count();
    std::this_thread::sleep_for(microseconds(1000));
  }
}

void OtherThread(int cpu, const std::atomic<bool>& stop) {
  Pin(cpu);
  while (!stop.load(std::memory_order_relaxed)) {
    const auto start = Clock::now();
    while (Clock::now() - start < microseconds(300)) {
    }
    std::this_thread::sleep_for(microseconds(700));
  }
}

std::vector<int> AllowedCpus() {
  cpu_set_t set;
  CPU_ZERO(&set);
  std::vector<int> cpus;
  if (sched_getaffinity(0, sizeof(set), &set) == 0) {
    for (size_t cpu = 0; cpu < CPU_SETSIZE; ++cpu) {
      if (CPU_ISSET(cpu, &set)) cpus.push_back(static_cast<int>(cpu));
    }
  }
  return cpus;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"bpawake: gaps that broadphased's keep-awake spinners leave beside other threads"};
  double seconds = 8;
  int rounds = 2;
  double threshold = 200;
  app.add_option("-s,--seconds", seconds, "length of each run")->check(CLI::PositiveNumber);
  app.add_option("-r,--rounds", rounds, "rounds of (off, on)")->check(CLI::PositiveNumber);
  app.add_option("--gap-us", threshold, "smallest gap recorded, in microseconds")
      ->check(CLI::PositiveNumber);
  CLI11_PARSE(app, argc, argv);
  const std::vector<int> cpus = AllowedCpus();
  if (cpus.empty()) {
    std::fprintf(stderr, "bpawake: cannot read this process's CPUs\n");
    return 1;
  }
  for (int round = 1; round <= rounds; ++round) {
    for (const bool on : {false, true}) {
      std::unique_ptr<bp::service::KeepAwake> keeper;
      if (on) {
        if (bp::Status s = bp::service::KeepAwake::Start(std::chrono::milliseconds(100), &keeper);
            !s.ok()) {
          std::fprintf(stderr, "bpawake: %s\n", s.ToString().c_str());
          return 1;
        }
      }
      std::atomic<bool> stop{false};
      std::vector<Gaps> gaps(cpus.size());
      std::vector<std::thread> threads;
      for (size_t i = 0; i < cpus.size(); ++i) {
        threads.emplace_back(OtherThread, cpus[i], std::cref(stop));
        threads.emplace_back(FrameThread, cpus[i], std::cref(stop), threshold, &gaps[i]);
      }
      const auto until = Clock::now() + std::chrono::duration<double>(seconds);
      while (Clock::now() < until) {
        if (keeper) keeper->Touch();
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
      }
      stop.store(true);
      for (std::thread& t : threads) t.join();
      std::vector<double> all;
      double worked = 0;
      for (const Gaps& g : gaps) {
        all.insert(all.end(), g.us.begin(), g.us.end());
        worked += g.worked_ms;
      }
      std::sort(all.begin(), all.end());
      auto over = [&](double us) {
        return all.end() - std::upper_bound(all.begin(), all.end(), us);
      };
      std::printf(
          "{\"probe\": \"keep_awake\", \"round\": %d, \"keep_awake\": %s, \"cpus\": %zu, "
          "\"seconds\": %.1f, \"frame_work_ms\": %.0f, \"gaps_over_%.0fus\": %zu, "
          "\"gaps_over_1ms\": %td, \"gaps_over_3ms\": %td, \"max_gap_us\": %.0f}\n",
          round, on ? "true" : "false", cpus.size(), seconds, worked, threshold, all.size(),
          over(1000), over(3000), all.empty() ? 0.0 : all.back());
      std::fflush(stdout);
    }
  }
  return 0;
}
