// bp::detail::PrefetchForWrite: starts loading a line the caller is about to write, asking for
// it exclusive (x86 PREFETCHW) where the CPU has the instruction.
//
// Why: GCC and clang turn __builtin_prefetch(p, 1) into a plain read prefetch unless the build
// targets a CPU with PREFETCHW (this project builds for baseline x86-64). A line read-prefetched
// from another core's cache arrives shared, and the write then waits again while that core's
// copy is invalidated. The grid's cells phase writes such lines (cell records, work entries)
// that the other thread wrote while routing.
//
// Thread safety: stateless after the first call's CPU check (a function-local static).
#pragma once

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <cpuid.h>
#endif

namespace bp::detail {

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
/// True iff the CPU reports PREFETCHW (CPUID 0x80000001, ECX bit 8: AMD's CPUs since family
/// 10h, Intel's since Broadwell; a CPU that does not, such as AMD's K8, gets the read prefetch).
inline bool CpuHasPrefetchW() {
  static const bool has = [] {
    unsigned a = 0, b = 0, c = 0, d = 0;
    return __get_cpuid(0x80000001u, &a, &b, &c, &d) != 0 && (c & (1u << 8)) != 0;
  }();
  return has;
}

inline void PrefetchForWrite(const void* p) {
  if (CpuHasPrefetchW()) {
    asm volatile("prefetchw %0" : : "m"(*static_cast<const char*>(p)));
  } else {
    __builtin_prefetch(p, 1);
  }
}
#else
inline void PrefetchForWrite(const void* p) { __builtin_prefetch(p, 1); }
#endif

}  // namespace bp::detail
