// bp::detail::HugeAllocator: the allocator of the engine's large flat arrays (objects, cell
// references, key slots, the pair and key tables, a query's routed and grouped buffers). An
// array of at least kHugeFrom bytes gets a mapping of its own, aligned to 2 MiB and advised as
// transparent huge pages (Linux madvise, honoured when THP is "madvise" or "always"); smaller
// arrays come from std::allocator.
//
// Why: these arrays are read at random (a frame's updates name objects all over them), and with
// 4 KiB pages nearly every such read also misses the TLB, whose refill in a virtual machine walks
// two page tables. glibc's malloc on huge pages (GLIBC_TUNABLES=glibc.malloc.hugetlb=1) would do
// the same, but only for a process started with that setting; this allocator gives the engine
// huge pages for its own large arrays in any program, with no setting.
//
// Cost: a mapped array's length is rounded up to 2 MiB, and a huge page is backed whole once
// touched, so each mapped array may hold up to 2 MiB more than it uses.
// Builds with a sanitizer (address, memory, thread) keep std::allocator throughout, so its heap
// checks still see every array. So a program must not mix translation units built with and
// without a sanitizer around one engine (an array mapped by one would be freed by the other).
//
// Thread safety: stateless; allocate and deallocate may be called from any thread.
#pragma once

#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <new>
#include <vector>

#if defined(__linux__)
#include <sys/mman.h>
#endif

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define BP_HUGE_ALLOC_OFF 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(memory_sanitizer) || \
    __has_feature(thread_sanitizer)
#define BP_HUGE_ALLOC_OFF 1
#endif
#endif

namespace bp::detail {

/// Arrays of at least this many bytes are mapped on huge pages (one huge page).
inline constexpr size_t kHugeFrom = size_t{2} << 20;
inline constexpr size_t kHugePage = size_t{2} << 20;

/// True iff an array of `bytes` bytes gets its own huge-page mapping in this build.
constexpr bool HugeMapped(size_t bytes) {
#if defined(__linux__) && !defined(BP_HUGE_ALLOC_OFF)
  return bytes >= kHugeFrom;
#else
  (void)bytes;
  return false;
#endif
}

#if defined(__linux__) && !defined(BP_HUGE_ALLOC_OFF)
/// A zeroed mapping of `bytes` (a multiple of kHugePage) aligned to kHugePage, advised as huge
/// pages; throws std::bad_alloc when the system refuses.
inline void* MapHuge(size_t bytes) {
  const size_t span = bytes + kHugePage;  // room to align
  void* raw = mmap(nullptr, span, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (raw == MAP_FAILED) throw std::bad_alloc();
  const auto begin = reinterpret_cast<uintptr_t>(raw);
  const uintptr_t aligned = (begin + kHugePage - 1) & ~(uintptr_t{kHugePage} - 1);
  if (aligned != begin) munmap(raw, aligned - begin);
  const uintptr_t end = begin + span, used_end = aligned + bytes;
  if (end != used_end) munmap(reinterpret_cast<void*>(used_end), end - used_end);
  void* p = reinterpret_cast<void*>(aligned);
  (void)madvise(p, bytes, MADV_HUGEPAGE);  // advice only: without THP the pages stay small
  return p;
}
inline void UnmapHuge(void* p, size_t bytes) { munmap(p, bytes); }
#endif

template <class T>
class HugeAllocator {
 public:
  using value_type = T;
  HugeAllocator() noexcept = default;
  template <class U>
  HugeAllocator(const HugeAllocator<U>&) noexcept {}  // NOLINT(google-explicit-constructor)

  T* allocate(size_t n) {
    if (n > static_cast<size_t>(std::numeric_limits<std::ptrdiff_t>::max()) / sizeof(T)) {
      throw std::bad_array_new_length();
    }
#if defined(__linux__) && !defined(BP_HUGE_ALLOC_OFF)
    static_assert(alignof(T) <= kHugePage);
    if (HugeMapped(n * sizeof(T))) return static_cast<T*>(MapHuge(Rounded(n * sizeof(T))));
#endif
    return std::allocator<T>().allocate(n);
  }
  void deallocate(T* p, size_t n) noexcept {
#if defined(__linux__) && !defined(BP_HUGE_ALLOC_OFF)
    if (HugeMapped(n * sizeof(T))) {
      UnmapHuge(p, Rounded(n * sizeof(T)));
      return;
    }
#endif
    std::allocator<T>().deallocate(p, n);
  }

  template <class U>
  bool operator==(const HugeAllocator<U>&) const noexcept {
    return true;
  }

 private:
  static constexpr size_t Rounded(size_t bytes) {
    return (bytes + kHugePage - 1) / kHugePage * kHugePage;
  }
};

/// A vector whose storage, once large, lies on huge pages (see above).
template <class T>
using HugeVector = std::vector<T, HugeAllocator<T>>;

}  // namespace bp::detail
