// A model of the dense cells' memory traffic in one S1-200k frame, apart from the engine (README
// "2026-11-25, evening"): 6859 cells, each a record of 320 bytes and four arrays (rows 1152,
// flags 192, pairs 288, local-to-global 192) wherever an allocator put them, read as the grid
// reads them (record 4 cells ahead, rows, flags and the first line of the table 2 ahead, 5 pair
// rows and 3 table entries on demand), against the same bytes in one block per cell, contiguous
// in cell order. 96 MB of other traffic before each pass. Not built by CMake:
//   g++ -O2 -o layout-model 2026-11-25-layout-model.cc && ./layout-model
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <numeric>
#include <random>
#include <vector>

#include <immintrin.h>

static constexpr size_t kCells = 6859;
static double Now() {
  return std::chrono::duration<double, std::milli>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}
struct Rec {
  const char* rows;
  const char* flags;
  const char* pairs;
  const char* global;
  char pad[320 - 32];
};
__attribute__((target("avx512f"))) static uint64_t Work(const char* p, size_t bytes) {
  __m512i acc = _mm512_setzero_si512();
  for (size_t off = 0; off + 64 <= bytes; off += 64)
    acc = _mm512_xor_si512(acc, _mm512_loadu_si512(p + off));
  alignas(64) uint64_t lanes[8];
  _mm512_store_si512(lanes, acc);
  uint64_t s = 0;
  for (uint64_t v : lanes) s += v;
  return s;
}
int main() {
  std::mt19937_64 rng(1);
  const size_t region = 128u << 20, slots = region / 2048;
  std::vector<char> heap(region + 4096, 1), flat(kCells * 2176 + 4096, 1), evict(96u << 20, 1);
  std::vector<size_t> slot(slots);
  std::iota(slot.begin(), slot.end(), 0);
  std::shuffle(slot.begin(), slot.end(), rng);
  size_t next = 0;
  auto alloc = [&] { return heap.data() + slot[next++] * 2048; };
  std::vector<Rec*> recs(kCells);
  for (size_t i = 0; i < kCells; ++i) {
    Rec* r = reinterpret_cast<Rec*>(alloc());
    r->rows = alloc();
    r->flags = alloc();
    r->pairs = alloc();
    r->global = alloc();
    recs[i] = r;
  }
  std::vector<uint32_t> rnd(kCells * 8);
  for (auto& x : rnd) x = rng() % 48;
  auto cur = [&] {
    uint64_t s = 0;
    for (size_t i = 0; i < kCells; ++i) {
      if (i + 4 < kCells)
        for (int l = 0; l < 320; l += 64)
          __builtin_prefetch(reinterpret_cast<char*>(recs[i + 4]) + l);
      if (i + 2 < kCells) {
        const Rec* r = recs[i + 2];
        for (int l = 0; l < 1152; l += 64) __builtin_prefetch(r->rows + l);
        for (int l = 0; l < 192; l += 64) __builtin_prefetch(r->flags + l);
        __builtin_prefetch(r->global);
      }
      const Rec* r = recs[i];
      s += Work(r->rows, 1152) + Work(r->flags, 192);
      for (int k = 0; k < 5; ++k)
        s += *reinterpret_cast<const uint32_t*>(r->pairs + rnd[i * 8 + k] * 6);
      for (int k = 5; k < 8; ++k)
        s += *reinterpret_cast<const uint32_t*>(r->global + rnd[i * 8 + k] * 4);
    }
    return s;
  };
  auto cont = [&](bool pf) {
    uint64_t s = 0;
    const size_t chunk = 320 + 1152 + 192 + 288 + 192;  // 2144
    for (size_t i = 0; i < kCells; ++i) {
      const char* c = flat.data() + i * chunk;
      if (pf && i + 2 < kCells)
        for (size_t l = 0; l < chunk; l += 64) __builtin_prefetch(c + 2 * chunk + l);
      s += Work(c + 320, 1152) + Work(c + 320 + 1152, 192) + *reinterpret_cast<const uint64_t*>(c);
      for (int k = 0; k < 5; ++k)
        s += *reinterpret_cast<const uint32_t*>(c + 1664 + rnd[i * 8 + k] * 6);
      for (int k = 5; k < 8; ++k)
        s += *reinterpret_cast<const uint32_t*>(c + 1952 + rnd[i * 8 + k] * 4);
    }
    return s;
  };
  uint64_t sink = 0;
  for (int round = 0; round < 8; ++round) {
    double t[3];
    for (int k = 0; k < 3; ++k) {
      for (size_t o = 0; o < evict.size(); o += 64) evict[o]++;
      double t0 = Now();
      sink += k == 0 ? cur() : cont(k == 2);
      t[k] = Now() - t0;
    }
    printf("current %.3f contiguous %.3f contiguous+pf %.3f ms\n", t[0], t[1], t[2]);
  }
  return sink == 42;
}
