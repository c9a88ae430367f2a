// bp::util::Percentile: the exact p-quantile of a small sample (frame times of a summary
// interval, latencies of a watch window), shared by the daemon's summary and bpctl watch.
//
// Thread safety: a free function on caller-owned data; it reorders the values.
#pragma once

#include <algorithm>
#include <cstddef>
#include <vector>

namespace bp::util {

/// The value at rank floor(p * n) (clamped) of values, reordering them (nth_element); 0 if empty.
inline double Percentile(std::vector<double>& values, double p) {
  if (values.empty()) return 0.0;
  const size_t k =
      std::min(values.size() - 1, static_cast<size_t>(p * static_cast<double>(values.size())));
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(k), values.end());
  return values[k];
}

}  // namespace bp::util
