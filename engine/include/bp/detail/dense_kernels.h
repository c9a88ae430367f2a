// The dense cell's box-test kernels (bp/dense_cell.h): one block of 16 slots' boxes against one
// box, as a 16-bit mask of the slots whose boxes overlap it, in three forms that give the same
// bits: AVX-512F (WideRows), AVX2 (Avx2Rows) and portable C++ (PortableBlock, GCC/Clang vector
// extensions where the type has them). Each is compiled with its own target attribute, so the
// library runs on any x86-64 and uses the widest kernel the CPU has (CpuHasAvx512, CpuHasAvx2;
// the choice is the cell's: ResolveDenseKernel). They stay inline templates: each is called in
// the innermost loop of a cell's scan, where a call would cost more than the test.
//
// A block is laid out as the cell keeps it: 2 K rows of 16 coordinates, lo and hi of each axis.
//
// Thread safety: pure functions (CPU detection runs once, thread-safely, as a static local).
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "bp/box.h"

namespace bp::detail {

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define BP_DENSE_WIDE 1
#define BP_WIDE_TARGET __attribute__((target("avx512f")))

/// True iff this CPU (and its OS) runs AVX-512F code: the dense cell's wide kernel.
inline bool CpuHasAvx512() {
  static const bool has = [] {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx512f") != 0;
  }();
  return has;
}

/// One row pair of a block of 16 slots under AVX-512: bit i of the result is bit i of `in` and
/// [rlo[i] <= hi && lo <= rhi[i]] (closed overlap on one axis, the scalar <= exactly).
template <class T>
struct WideRows {};  // no wide kernel for T
template <>
struct WideRows<float> {
  BP_WIDE_TARGET static uint32_t Overlap(uint32_t in, const float* rlo, const float* rhi, float lo,
                                         float hi) {
    __mmask16 m = _mm512_mask_cmp_ps_mask(static_cast<__mmask16>(in), _mm512_loadu_ps(rlo),
                                          _mm512_set1_ps(hi), _CMP_LE_OQ);
    return _mm512_mask_cmp_ps_mask(m, _mm512_set1_ps(lo), _mm512_loadu_ps(rhi), _CMP_LE_OQ);
  }
};
template <>
struct WideRows<double> {
  BP_WIDE_TARGET static uint32_t Overlap(uint32_t in, const double* rlo, const double* rhi,
                                         double lo, double hi) {
    const __m512d vlo = _mm512_set1_pd(lo), vhi = _mm512_set1_pd(hi);
    uint32_t out = 0;
    for (int half = 0; half < 2; ++half) {
      auto m = static_cast<__mmask8>(in >> (8 * half));
      m = _mm512_mask_cmp_pd_mask(m, _mm512_loadu_pd(rlo + 8 * half), vhi, _CMP_LE_OQ);
      m = _mm512_mask_cmp_pd_mask(m, vlo, _mm512_loadu_pd(rhi + 8 * half), _CMP_LE_OQ);
      out |= uint32_t{m} << (8 * half);
    }
    return out;
  }
};
template <>
struct WideRows<int32_t> {
  BP_WIDE_TARGET static uint32_t Overlap(uint32_t in, const int32_t* rlo, const int32_t* rhi,
                                         int32_t lo, int32_t hi) {
    __mmask16 m = _mm512_mask_cmp_epi32_mask(static_cast<__mmask16>(in), _mm512_loadu_si512(rlo),
                                             _mm512_set1_epi32(hi), _MM_CMPINT_LE);
    return _mm512_mask_cmp_epi32_mask(m, _mm512_set1_epi32(lo), _mm512_loadu_si512(rhi),
                                      _MM_CMPINT_LE);
  }
};
template <class T>
inline constexpr bool kHasWideRows = requires {
  WideRows<T>::Overlap;
};

#define BP_AVX2_TARGET __attribute__((target("avx2")))

/// True iff this CPU (and its OS) runs AVX2 code.
inline bool CpuHasAvx2() {
  static const bool has = [] {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") != 0;
  }();
  return has;
}

/// A block of 16 slots under AVX2: bit i of Block's result is set iff slot i's box overlaps
/// [lo, hi] on every axis (closed, the scalar <= exactly; live bits not applied). The rows of
/// all axes are tested in registers and turned into bits once (the AVX-512 kernel, with mask
/// registers, does it per axis). One struct per type, since each compares its own way.
template <class T>
struct Avx2Rows {};  // no AVX2 kernel for T
template <>
struct Avx2Rows<float> {
  template <size_t kAxes>
  BP_AVX2_TARGET static uint32_t Block(const float* block, const float* lo, const float* hi) {
    __m256 m[2];
    for (size_t a = 0; a < kAxes; ++a) {
      const __m256 vlo = _mm256_set1_ps(lo[a]), vhi = _mm256_set1_ps(hi[a]);
      const float* rlo = block + 2 * a * 16;
      for (int half = 0; half < 2; ++half) {
        const __m256 t =
            _mm256_and_ps(_mm256_cmp_ps(_mm256_loadu_ps(rlo + 8 * half), vhi, _CMP_LE_OQ),
                          _mm256_cmp_ps(vlo, _mm256_loadu_ps(rlo + 16 + 8 * half), _CMP_LE_OQ));
        m[half] = a == 0 ? t : _mm256_and_ps(m[half], t);
      }
    }
    return static_cast<uint32_t>(_mm256_movemask_ps(m[0])) |
           static_cast<uint32_t>(_mm256_movemask_ps(m[1])) << 8;
  }
};
template <>
struct Avx2Rows<double> {
  template <size_t kAxes>
  BP_AVX2_TARGET static uint32_t Block(const double* block, const double* lo, const double* hi) {
    __m256d m[4];
    for (size_t a = 0; a < kAxes; ++a) {
      const __m256d vlo = _mm256_set1_pd(lo[a]), vhi = _mm256_set1_pd(hi[a]);
      const double* rlo = block + 2 * a * 16;
      for (int q = 0; q < 4; ++q) {
        const __m256d t =
            _mm256_and_pd(_mm256_cmp_pd(_mm256_loadu_pd(rlo + 4 * q), vhi, _CMP_LE_OQ),
                          _mm256_cmp_pd(vlo, _mm256_loadu_pd(rlo + 16 + 4 * q), _CMP_LE_OQ));
        m[q] = a == 0 ? t : _mm256_and_pd(m[q], t);
      }
    }
    uint32_t bits = 0;
    for (int q = 0; q < 4; ++q) bits |= static_cast<uint32_t>(_mm256_movemask_pd(m[q])) << (4 * q);
    return bits;
  }
};
template <>
struct Avx2Rows<int32_t> {
  // AVX2 compares integers by > only: a slot fails where rlo > hi or lo > rhi on some axis.
  template <size_t kAxes>
  BP_AVX2_TARGET static uint32_t Block(const int32_t* block, const int32_t* lo, const int32_t* hi) {
    __m256i bad[2] = {_mm256_setzero_si256(), _mm256_setzero_si256()};
    for (size_t a = 0; a < kAxes; ++a) {
      const __m256i vlo = _mm256_set1_epi32(lo[a]), vhi = _mm256_set1_epi32(hi[a]);
      const int32_t* rlo = block + 2 * a * 16;
      for (int half = 0; half < 2; ++half) {
        const auto* l = reinterpret_cast<const __m256i*>(rlo + 8 * half);
        const auto* h = reinterpret_cast<const __m256i*>(rlo + 16 + 8 * half);
        bad[half] = _mm256_or_si256(
            bad[half], _mm256_or_si256(_mm256_cmpgt_epi32(_mm256_loadu_si256(l), vhi),
                                       _mm256_cmpgt_epi32(vlo, _mm256_loadu_si256(h))));
      }
    }
    const auto fail = static_cast<uint32_t>(_mm256_movemask_ps(_mm256_castsi256_ps(bad[0]))) |
                      static_cast<uint32_t>(_mm256_movemask_ps(_mm256_castsi256_ps(bad[1]))) << 8;
    return ~fail & 0xFFFFu;
  }
};
template <class T>
inline constexpr bool kHasAvx2Rows =
    std::is_same_v<T, float> || std::is_same_v<T, double> || std::is_same_v<T, int32_t>;
#else
inline bool CpuHasAvx512() { return false; }
inline bool CpuHasAvx2() { return false; }
template <class T>
inline constexpr bool kHasWideRows = false;
template <class T>
inline constexpr bool kHasAvx2Rows = false;
#endif

/// The portable block test, in GCC/Clang vector extensions (16-byte vectors, which every target
/// of these compilers lowers to its own SIMD, or to scalars): bit i of Block's result is set iff
/// slot i's box overlaps [lo, hi] on every axis (live bits not applied). GCC 12 does not
/// vectorise the plain loop (one scalar compare per slot and bound); in this form it takes
/// about half as long. For float, double and int32
/// (the types the differential suite runs); other types take the plain loop.
template <class T>
inline constexpr bool kHasVectorRows =
    std::is_same_v<T, float> || std::is_same_v<T, double> || std::is_same_v<T, int32_t>;
template <class T, size_t kAxes>
inline uint32_t PortableBlock(const T* block, const T* lo, const T* hi) {
  constexpr size_t kBlockSlots = 16;
  if constexpr (kHasVectorRows<T>) {
    using V [[gnu::vector_size(16)]] = T;
    using M = decltype(V{} <= V{});  // lanes of 0 or -1, a signed integer as wide as T
    using Lane = std::conditional_t<sizeof(T) == 8, int64_t, int32_t>;  // M's lane type
    constexpr size_t kLanes = 16 / sizeof(T), kVectors = kBlockSlots / kLanes;
    M m[kVectors] = {};
    for (size_t a = 0; a < kAxes; ++a) {
      V vlo{}, vhi{};
      for (size_t i = 0; i < kLanes; ++i) {
        vlo[i] = lo[a];
        vhi[i] = hi[a];
      }
      const T* rlo = block + 2 * a * kBlockSlots;
      for (size_t q = 0; q < kVectors; ++q) {
        V l, h;
        std::memcpy(&l, rlo + q * kLanes, sizeof(V));
        std::memcpy(&h, rlo + kBlockSlots + q * kLanes, sizeof(V));
        const M t = (l <= vhi) & (vlo <= h);
        m[q] = a == 0 ? t : (m[q] & t);
      }
    }
    // Each lane keeps its slot's bit, then the lanes are ORed.
    M bits{};
    for (size_t q = 0; q < kVectors; ++q) {
      M weight{};
      for (size_t i = 0; i < kLanes; ++i)
        weight[i] = static_cast<Lane>(Lane{1} << (q * kLanes + i));
      bits |= m[q] & weight;
    }
    uint32_t out = 0;
    for (size_t i = 0; i < kLanes; ++i) out |= static_cast<uint32_t>(bits[i]);
    return out;
  } else {
    uint32_t mask[kBlockSlots];
    for (size_t i = 0; i < kBlockSlots; ++i) mask[i] = 1;
    for (size_t a = 0; a < kAxes; ++a) {
      const T* rlo = block + 2 * a * kBlockSlots;
      const T* rhi = rlo + kBlockSlots;
      for (size_t i = 0; i < kBlockSlots; ++i) {
        mask[i] &= static_cast<uint32_t>(rlo[i] <= hi[a]) & static_cast<uint32_t>(lo[a] <= rhi[i]);
      }
    }
    uint32_t out = 0;
    for (size_t i = 0; i < kBlockSlots; ++i) out |= mask[i] << i;
    return out;
  }
}

/// The kernel a block test outside the dense cell runs (BlockOverlaps): the widest this CPU has
/// for T.
enum class BlockKernel : uint8_t { kWide, kAvx2, kPortable };
template <class T>
BlockKernel ResolveBlockKernel() {
  if (kHasWideRows<T> && CpuHasAvx512()) return BlockKernel::kWide;
  if (kHasAvx2Rows<T> && CpuHasAvx2()) return BlockKernel::kAvx2;
  return BlockKernel::kPortable;
}

/// Two boxes against one block: bit i of (*a)[0] is set iff bit i of in[0] is and slot i of the
/// block (laid out as above) overlaps box 0 ([lo[0], hi[0]]) on every axis; likewise for box 1.
/// The same bits for every kernel k.
/// The boxes are held by value: a caller testing many blocks in a loop keeps them in registers
/// (through pointers, every store in the loop could change them, and each block reloaded them).
template <class T, size_t kAxes>
struct BlockBoxes {
  T lo[2][kAxes];
  T hi[2][kAxes];
  uint32_t in[2];
};
#ifdef BP_DENSE_WIDE
/// BlockOverlaps under AVX-512, in one call (a call into a function of another target is not
/// inlined): the block's rows are loaded once for both boxes.
template <class T, size_t kAxes>
BP_WIDE_TARGET void WideBlockBoxes(const T* block, const BlockBoxes<T, kAxes>& boxes,
                                   uint32_t* out) {
  uint32_t m0 = boxes.in[0], m1 = boxes.in[1];  // two chains, interleaved, without branches
  for (size_t a = 0; a < kAxes; ++a) {
    const T* rlo = block + 2 * a * 16;
    m0 = WideRows<T>::Overlap(m0, rlo, rlo + 16, boxes.lo[0][a], boxes.hi[0][a]);
    m1 = WideRows<T>::Overlap(m1, rlo, rlo + 16, boxes.lo[1][a], boxes.hi[1][a]);
  }
  out[0] = m0;
  out[1] = m1;
}
#endif
template <class T, size_t kAxes>
inline void BlockOverlaps(BlockKernel k, const T* block, const BlockBoxes<T, kAxes>& boxes,
                          uint32_t* out) {
#ifdef BP_DENSE_WIDE
  if constexpr (kHasWideRows<T>) {
    if (k == BlockKernel::kWide) {
      WideBlockBoxes<T, kAxes>(block, boxes, out);
      return;
    }
  }
#endif
  for (int b = 0; b < 2; ++b) {
    if (boxes.in[b] == 0) {
      out[b] = 0;
      continue;
    }
#ifdef BP_DENSE_WIDE
    if constexpr (kHasAvx2Rows<T>) {
      if (k == BlockKernel::kAvx2) {
        out[b] = boxes.in[b] & Avx2Rows<T>::template Block<kAxes>(block, boxes.lo[b], boxes.hi[b]);
        continue;
      }
    }
#endif
    out[b] = boxes.in[b] & PortableBlock<T, kAxes>(block, boxes.lo[b], boxes.hi[b]);
  }
  (void)k;
}

}  // namespace bp::detail
