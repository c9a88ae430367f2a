// bp::transport::ShardMap: which daemon (shard) of a sharded world owns which part of space.
//
// Space is cut by a coarse grid of blocks: `origin`, the block edge on each axis, and the number
// of blocks on each axis. Block (i, j, k) is the half-open box [origin + i * edge, origin +
// (i + 1) * edge) on each axis; positions beyond the grid belong to its edge blocks, so the map
// covers all of space. Each shard owns a set of blocks, given as inclusive index ranges, and
// every block has exactly one owner. The same file serves every daemon and every client of the
// world (docs/GUIDE.md, "A world on several daemons").
//
// Routing: a box goes to every shard owning a block it touches, the blocks BlockOf(lo) ..
// BlockOf(hi) on each axis. BlockOf is monotone in each coordinate, so when two boxes overlap,
// the lower corner of their intersection lies in a block both of them touch: every overlapping
// pair is held whole by at least one shard (docs/DESIGN.md proves the rest).
//
// Each shard's daemon runs in DDS partition ShardPartition(partition, name), so a client reaches
// shard s through a Connection scoped to that partition (Connection::Scoped).
//
// Thread safety: a ShardMap is an immutable value after Parse/Load.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "bp/status.h"

namespace bp::transport {

class ShardMap {
 public:
  /// At most this many shards (a shard set is a 64-bit mask).
  static constexpr size_t kMaxShards = 64;
  /// At most this many blocks in the grid.
  static constexpr uint64_t kMaxBlocks = uint64_t{1} << 20;
  using Mask = uint64_t;

  /// Parses a map from YAML text; source names it in errors ("<source>:<line>:<col>: ...",
  /// every problem on its own line).
  static Status Parse(std::string_view yaml_text, std::string_view source, ShardMap* out);
  /// Reads and parses a file.
  static Status Load(const std::string& path, ShardMap* out);

  int dimension() const { return dim_; }
  size_t size() const { return names_.size(); }
  const std::string& name(size_t shard) const { return names_[shard]; }
  /// The shard called name, or -1.
  int Find(std::string_view name) const;

  /// The block index of coordinate x on axis a (clamped to the grid; NaN gives 0).
  uint32_t BlockOf(int axis, double x) const;
  /// The shard owning block (index[0], ..., index[K-1]).
  size_t OwnerOf(const uint32_t* index) const;
  /// The shards a box [lo, hi] (K coordinates each) touches, as a mask (bit s: shard s). A box
  /// with a NaN coordinate or lo > hi touches no shard (0); infinite coordinates clamp to the
  /// grid's edge blocks.
  Mask Route(const double* lo, const double* hi) const;
  /// Every shard.
  Mask all() const { return all_; }
  /// The part of shard s as blocks: the number of blocks it owns.
  uint64_t BlocksOwned(size_t shard) const;

  /// The map in a canonical text form (the same map always prints the same text), and its
  /// 64-bit FNV-1a digest: daemons announce it, clients compare it with theirs.
  const std::string& canonical() const { return canonical_; }
  uint64_t digest() const { return digest_; }

 private:
  int dim_ = 0;
  std::array<double, 3> origin_{};
  std::array<double, 3> edge_{};
  std::array<uint32_t, 3> count_{1, 1, 1};
  std::vector<std::string> names_;
  std::vector<uint8_t> owner_;  // per block, x fastest
  Mask all_ = 0;                // every shard
  std::string canonical_;
  uint64_t digest_ = 0;
};

/// The DDS partition of shard name: "<partition>.shard.<name>" ("shard.<name>" in the default
/// partition).
std::string ShardPartition(const std::string& partition, std::string_view name);

}  // namespace bp::transport
