// bpprobe: how much two threads can gain on this machine, apart from any engine. Runs the same
// kernel on 1 thread, then on N threads at once, and prints the throughput ratio as JSON lines:
//  - "alu": eight independent integer multiply-add chains (bound by the core's execution units:
//    two vCPUs that are hyper-threads of one core give about 1x, two cores about 2x);
//  - "chase": eight independent random walks over a 256 MB table (bound by memory latency and
//    the misses a core keeps in flight: what a broadphase frame mostly waits on);
//  - "gather": random 64-byte lines of the table read with a prefetch --ahead reads ahead (16 by
//    default), as the grid routes its updates (bound by the misses the memory system serves at
//    once: with a distance long enough, one thread alone may take most of them);
//  - "scatter": the same lines read, changed and written back, as routing stores each moved
//    object's box (each line also costs a write-back);
//  - "stream": the table read front to back (bound by the memory system's bandwidth);
//  - "chunks": random 2 KiB chunks of the table read whole, 4 chunks prefetched ahead, and half
//    of their lines written, as the dense cells' apply reads a cell's rows and writes its changed
//    slots' rows and pair bits (S1-1M: about 51 slots, 1.2 KiB of rows and 0.3 of pair bits a
//    cell, most of them written): bound by the lines the memory system reads and writes back
//    at once.
// Read it beside the grid's two-thread ratios: if the machine scales and the engine does not,
// the engine's serial part is the bound.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <iterator>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>

namespace {

uint64_t Alu(uint64_t rounds) {
  uint64_t x[8];
  for (uint64_t i = 0; i < 8; ++i) x[i] = i + 1;
  for (uint64_t k = 0; k < rounds; ++k) {
    for (uint64_t& v : x) v = v * 6364136223846793005ull + 1442695040888963407ull;
  }
  uint64_t s = 0;
  for (uint64_t v : x) s ^= v;
  return s;
}

uint64_t Chase(const std::vector<uint32_t>& next, uint64_t rounds) {
  uint32_t p[8];
  for (uint32_t i = 0; i < 8; ++i) p[i] = static_cast<uint32_t>((i * 1000003ull) % next.size());
  for (uint64_t k = 0; k < rounds; ++k) {
    for (uint32_t& v : p) v = next[v];
  }
  uint64_t s = 0;
  for (uint32_t v : p) s += v;
  return s;
}

// Adds one to a word other threads may change at the same time: a relaxed load and store (plain
// moves on x86), which may lose a concurrent change but is no data race.
inline void Bump(uint32_t& word) {
  std::atomic_ref<uint32_t> w(word);
  w.store(w.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);
}

// Reads (and with write, changes) `count` random lines of `table` from a stream of hashed
// indices, each prefetched `ahead` accesses ahead.
uint64_t Lines(std::vector<uint32_t>& table, uint64_t count, uint64_t seed, bool write,
               uint64_t ahead) {
  const uint64_t lines = table.size() / 16;
  auto line = [&](uint64_t i) {
    uint64_t z = (seed + i) * 0x9E3779B97F4A7C15ull;
    z = (z ^ (z >> 31)) * 0xBF58476D1CE4E5B9ull;
    return (z ^ (z >> 29)) % lines * 16;
  };
  uint64_t s = 0;
  for (uint64_t i = 0; i < count; ++i) {
    if (write) {
      __builtin_prefetch(&table[line(i + ahead)], 1);  // the argument must be a constant
    } else {
      __builtin_prefetch(&table[line(i + ahead)], 0);
    }
    uint32_t* p = &table[line(i)];
    s += p[0] + p[15];
    if (write) Bump(p[1]);
  }
  return s;
}

// Sums the table front to back `passes` times, from a start that seed picks.
uint64_t Stream(const std::vector<uint32_t>& table, uint64_t passes, uint64_t seed) {
  const size_t n = table.size();
  const size_t start = static_cast<size_t>((seed >> 40) * 7919 % 16) * (n / 16);
  uint64_t s = 0;
  for (uint64_t pass = 0; pass < passes; ++pass) {
    for (size_t i = start; i < n; ++i) s += table[i];
    for (size_t i = 0; i < start; ++i) s += table[i];
  }
  return s;
}

// Reads `count` random chunks of 32 lines of `table` whole (each line's first and last word),
// every line of the chunk 4 chunks ahead prefetched, and changes every other line of each.
uint64_t Chunks(std::vector<uint32_t>& table, uint64_t count, uint64_t seed) {
  constexpr uint64_t kLines = 32, kAhead = 4;
  const uint64_t chunks = table.size() / (16 * kLines);
  auto chunk = [&](uint64_t i) {
    uint64_t z = (seed + i) * 0x9E3779B97F4A7C15ull;
    z = (z ^ (z >> 31)) * 0xBF58476D1CE4E5B9ull;
    return (z ^ (z >> 29)) % chunks * 16 * kLines;
  };
  uint64_t s = 0;
  for (uint64_t i = 0; i < count; ++i) {
    const uint32_t* ahead = &table[chunk(i + kAhead)];
    for (uint64_t l = 0; l < kLines; ++l) __builtin_prefetch(ahead + 16 * l);
    uint32_t* p = &table[chunk(i)];
    for (uint64_t l = 0; l < kLines; ++l) s += p[16 * l] + p[16 * l + 15];
    for (uint64_t l = 0; l < kLines; l += 2) Bump(p[16 * l + 1]);
  }
  return s;
}

// Seconds for `threads` threads each running f once, all at the same time.
double Run(unsigned threads, const std::function<uint64_t()>& f) {
  std::vector<uint64_t> out(threads);
  const auto start = std::chrono::steady_clock::now();
  std::vector<std::thread> pool;
  for (unsigned t = 0; t < threads; ++t) pool.emplace_back([&, t] { out[t] = f(); });
  for (std::thread& t : pool) t.join();
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  uint64_t sink = 0;
  for (uint64_t v : out) sink ^= v;
  if (sink == 42) std::fprintf(stderr, " ");  // keeps the results live
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app("bpprobe: the machine's own scaling from 1 to N threads (JSON lines)");
  unsigned threads = 2, repeats = 3, ahead = 16;
  std::vector<std::string> only;
  app.add_option("-t,--threads", threads, "threads of the parallel run")
      ->check(CLI::Range(2u, 256u));
  app.add_option("-r,--repeats", repeats, "rounds (each: 1 thread, then N)")
      ->check(CLI::Range(1u, 100u));
  app.add_option("--ahead", ahead, "gather and scatter: prefetch distance, in reads")
      ->check(CLI::Range(0u, 4096u));
  app.add_option("-k,--kernels", only, "the kernels to run (default: all)")
      ->check(CLI::IsMember({"alu", "chase", "gather", "scatter", "stream", "chunks"}));
  CLI11_PARSE(app, argc, argv);

  // A random cyclic permutation (Sattolo): one walk visits the whole table.
  std::vector<uint32_t> next(size_t{64} << 20);
  for (size_t i = 0; i < next.size(); ++i) next[i] = static_cast<uint32_t>(i);
  uint64_t x = 88172645463325252ull;
  for (size_t i = next.size() - 1; i > 0; --i) {
    x ^= x << 13;
    x ^= x >> 7;
    x ^= x << 17;
    std::swap(next[i], next[x % i]);
  }
  // The other kernels' table, apart: the write kernels change it, which would break the walk.
  std::vector<uint32_t> table(next);
  std::atomic<uint64_t> seed{1};
  const std::function<uint64_t()> kernels[] = {
      [] { return Alu(uint64_t{200} << 20); },
      [&] { return Chase(next, uint64_t{4} << 20); },
      [&] {
        return Lines(table, uint64_t{16} << 20, seed.fetch_add(uint64_t{1} << 40), false, ahead);
      },
      [&] {
        return Lines(table, uint64_t{16} << 20, seed.fetch_add(uint64_t{1} << 40), true, ahead);
      },
      [&] { return Stream(table, 16, seed.fetch_add(uint64_t{1} << 40)); },
      [&] { return Chunks(table, uint64_t{1} << 20, seed.fetch_add(uint64_t{1} << 40)); }};
  const char* names[] = {"alu", "chase", "gather", "scatter", "stream", "chunks"};
  for (unsigned r = 0; r < repeats; ++r) {
    for (size_t k = 0; k < std::size(kernels); ++k) {
      if (!only.empty() && std::find(only.begin(), only.end(), names[k]) == only.end()) continue;
      const double one = Run(1, kernels[k]);
      const double many = Run(threads, kernels[k]);
      std::printf(
          "{\"kernel\":\"%s\",\"round\":%u,\"threads\":%u,\"ahead\":%u,\"one_s\":%.4f,"
          "\"parallel_s\":%.4f,\"throughput_ratio\":%.3f}\n",
          names[k], r + 1, threads, ahead, one, many, threads * one / many);
      std::fflush(stdout);
    }
  }
  return 0;
}
