// bp::detail::Stopwatch: times the phases of a query for Stats (prepare, core, route, cells,
// fold, events), so that a benchmark or an operator sees where a frame goes without a profiler.
// A lap is one read of the monotonic clock (tens of nanoseconds; a query takes a few of them).
//
// Thread safety: none; owned by one engine.
#pragma once

#include <chrono>

namespace bp::detail {

class Stopwatch {
 public:
  Stopwatch() : start_(Clock::now()) {}
  /// Milliseconds since construction or the last Lap; starts the next lap.
  double Lap() {
    const Clock::time_point now = Clock::now();
    const double ms = std::chrono::duration<double, std::milli>(now - start_).count();
    start_ = now;
    return ms;
  }

 private:
  using Clock = std::chrono::steady_clock;
  Clock::time_point start_;
};

}  // namespace bp::detail
