#include "bp/transport/shard_map.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <set>

#include <yaml-cpp/yaml.h>

#include "bp/transport/connection.h"

namespace bp::transport {
namespace {

// Collects every problem of a document, one line each: "<source>:<line>:<col>: <key>: <why>".
class Problems {
 public:
  explicit Problems(std::string_view source) : source_(source) {}
  void Add(const YAML::Node& node, std::string_view key, std::string_view why) {
    const YAML::Mark m = node.Mark();
    std::string line = source_;
    if (!m.is_null()) line += ":" + std::to_string(m.line + 1) + ":" + std::to_string(m.column + 1);
    line += ": " + std::string(key) + ": " + std::string(why);
    lines_.push_back(std::move(line));
  }
  bool any() const { return !lines_.empty(); }
  Status ToStatus() const {
    std::string text;
    for (const std::string& l : lines_) text += (text.empty() ? "" : "\n") + l;
    return Status(StatusCode::kInvalidArgument, std::move(text));
  }

 private:
  std::string source_;
  std::vector<std::string> lines_;
};

bool ReadDouble(const YAML::Node& node, double* out) {
  if (!node.IsScalar()) return false;
  const std::string& text = node.Scalar();
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size() || !std::isfinite(v)) return false;
  *out = v;
  return true;
}

bool ReadIndex(const YAML::Node& node, uint64_t limit, uint64_t* out) {
  if (!node.IsScalar()) return false;
  const std::string& text = node.Scalar();
  if (text.empty() || text.size() > 9 ||
      !std::all_of(text.begin(), text.end(), [](char c) { return c >= '0' && c <= '9'; })) {
    return false;
  }
  const uint64_t v = std::stoull(text);
  if (v >= limit) return false;
  *out = v;
  return true;
}

// A list of exactly k items read by read(i, node); false (and one problem) otherwise.
template <class F>
bool ReadList(Problems& p, const YAML::Node& node, std::string_view key, int k,
              std::string_view what, F read) {
  if (!node.IsSequence() || node.size() != static_cast<size_t>(k)) {
    p.Add(node, key, "must be a list of " + std::to_string(k) + " " + std::string(what));
    return false;
  }
  for (int i = 0; i < k; ++i) {
    if (!read(i, node[static_cast<size_t>(i)])) {
      p.Add(node[static_cast<size_t>(i)], key,
            "must be a list of " + std::to_string(k) + " " + std::string(what));
      return false;
    }
  }
  return true;
}

bool ValidName(const std::string& name) {
  return !name.empty() && name.size() <= 64 && std::all_of(name.begin(), name.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' ||
           c == '-';
  });
}

std::string FormatDouble(double v) {
  char text[64];
  std::snprintf(text, sizeof(text), "%.17g", v);
  return text;
}

}  // namespace

std::string ShardPartition(const std::string& partition, std::string_view name) {
  return (partition.empty() ? std::string() : partition + ".") + "shard." + std::string(name);
}

Status ShardMap::Parse(std::string_view yaml_text, std::string_view source, ShardMap* out) {
  Problems p(source);
  ShardMap map;
  YAML::Node root;
  try {
    root = YAML::Load(std::string(yaml_text));
  } catch (const YAML::Exception& e) {
    return Status(StatusCode::kInvalidArgument,
                  std::string(source) + ":" + std::to_string(e.mark.line + 1) + ":" +
                      std::to_string(e.mark.column + 1) + ": YAML syntax error: " + e.msg);
  }
  if (!root.IsMap()) {
    return Status(StatusCode::kInvalidArgument,
                  std::string(source) +
                      ": a shard map is a mapping with the keys dimension, "
                      "origin, edge, count and shards");
  }
  static const std::set<std::string> kKeys{"dimension", "origin", "edge", "count", "shards"};
  for (const auto& item : root) {
    const std::string key = item.first.as<std::string>("");
    if (kKeys.count(key) == 0)
      p.Add(item.first, key,
            "unknown key (known: dimension, origin, "
            "edge, count, shards)");
  }
  for (const char* key : {"dimension", "origin", "edge", "count", "shards"}) {
    if (!root[key]) p.Add(root, key, "missing");
  }
  if (p.any()) return p.ToStatus();

  uint64_t dim = 0;
  if (!ReadIndex(root["dimension"], 4, &dim) || dim < 2) {
    p.Add(root["dimension"], "dimension", "must be 2 or 3");
    return p.ToStatus();
  }
  map.dim_ = static_cast<int>(dim);
  const int k = map.dim_;
  ReadList(p, root["origin"], "origin", k, "finite numbers",
           [&](int i, const YAML::Node& n) { return ReadDouble(n, &map.origin_[size_t(i)]); });
  ReadList(p, root["edge"], "edge", k, "positive finite numbers", [&](int i, const YAML::Node& n) {
    return ReadDouble(n, &map.edge_[size_t(i)]) && map.edge_[size_t(i)] > 0;
  });
  uint64_t blocks = 1;
  ReadList(p, root["count"], "count", k, "integers from 1 to 65536",
           [&](int i, const YAML::Node& n) {
             uint64_t c = 0;
             if (!ReadIndex(n, 65537, &c) || c == 0) return false;
             map.count_[size_t(i)] = static_cast<uint32_t>(c);
             blocks *= c;
             return true;
           });
  if (p.any()) return p.ToStatus();
  if (blocks > kMaxBlocks) {
    p.Add(root["count"], "count",
          "the grid has " + std::to_string(blocks) + " blocks; at most " +
              std::to_string(kMaxBlocks));
    return p.ToStatus();
  }
  const YAML::Node shards = root["shards"];
  if (!shards.IsSequence() || shards.size() == 0 || shards.size() > kMaxShards) {
    p.Add(shards, "shards", "must be a list of 1 to 64 shards");
    return p.ToStatus();
  }
  constexpr uint8_t kFree = 0xFF;
  map.owner_.assign(blocks, kFree);
  for (size_t s = 0; s < shards.size(); ++s) {
    const YAML::Node shard = shards[s];
    const std::string where = "shards[" + std::to_string(s) + "]";
    if (!shard.IsMap() || !shard["name"] || !shard["blocks"] || shard.size() != 2) {
      p.Add(shard, where, "must be a mapping with the keys name and blocks");
      continue;
    }
    const std::string name = shard["name"].as<std::string>("");
    if (!ValidName(name)) {
      p.Add(shard["name"], where + ".name", "must be 1 to 64 characters of [A-Za-z0-9_-]");
    } else if (map.Find(name) >= 0) {
      p.Add(shard["name"], where + ".name", "'" + name + "' names two shards");
    }
    map.names_.push_back(name);
    const YAML::Node ranges = shard["blocks"];
    if (!ranges.IsSequence() || ranges.size() == 0) {
      p.Add(ranges, where + ".blocks", "must be a list of ranges {from: [..], to: [..]}");
      continue;
    }
    for (size_t r = 0; r < ranges.size(); ++r) {
      const YAML::Node range = ranges[r];
      const std::string at = where + ".blocks[" + std::to_string(r) + "]";
      if (!range.IsMap() || !range["from"] || !range["to"] || range.size() != 2) {
        p.Add(range, at, "must be a mapping {from: [..], to: [..]} of block indices");
        continue;
      }
      std::array<uint64_t, 3> from{}, to{};
      bool ok = true;
      for (auto [key, corner] : {std::pair{"from", &from}, std::pair{"to", &to}}) {
        ok = ok && ReadList(p, range[key], at + "." + key, k, "block indices within count",
                            [&](int i, const YAML::Node& n) {
                              return ReadIndex(n, map.count_[size_t(i)], &(*corner)[size_t(i)]);
                            });
      }
      if (!ok) continue;
      for (int a = 0; a < k; ++a) {
        if (from[size_t(a)] > to[size_t(a)]) {
          p.Add(range, at, "from is above to on axis " + std::to_string(a));
          ok = false;
        }
      }
      if (!ok) continue;
      uint64_t taken = 0;
      for (uint64_t z = from[2]; z <= to[2]; ++z) {
        for (uint64_t y = from[1]; y <= to[1]; ++y) {
          for (uint64_t x = from[0]; x <= to[0]; ++x) {
            uint8_t& o = map.owner_[(z * map.count_[1] + y) * map.count_[0] + x];
            if (o != kFree && taken++ == 0) {
              p.Add(range, at,
                    "block [" + std::to_string(x) + ", " + std::to_string(y) +
                        (k == 3 ? ", " + std::to_string(z) : "") + "] is already owned by '" +
                        map.names_[o] + "'");
            }
            o = static_cast<uint8_t>(s);
          }
        }
      }
    }
  }
  if (!p.any()) {
    const auto free = std::find(map.owner_.begin(), map.owner_.end(), kFree);
    if (free != map.owner_.end()) {
      const auto b = static_cast<uint64_t>(free - map.owner_.begin());
      const uint64_t x = b % map.count_[0], y = b / map.count_[0] % map.count_[1],
                     z = b / map.count_[0] / map.count_[1];
      p.Add(shards, "shards",
            "block [" + std::to_string(x) + ", " + std::to_string(y) +
                (k == 3 ? ", " + std::to_string(z) : "") +
                "] has no owner (every block needs one)");
    }
  }
  if (p.any()) return p.ToStatus();

  std::string& c = map.canonical_;
  c = "dimension: " + std::to_string(k) + "\n";
  for (auto [key, values] : {std::pair{"origin", &map.origin_}, std::pair{"edge", &map.edge_}}) {
    c += std::string(key) + ": [";
    for (int a = 0; a < k; ++a) c += (a ? ", " : "") + FormatDouble((*values)[size_t(a)]);
    c += "]\n";
  }
  c += "count: [";
  for (int a = 0; a < k; ++a) c += (a ? ", " : "") + std::to_string(map.count_[size_t(a)]);
  c += "]\nowners:";
  for (uint8_t o : map.owner_) c += " " + map.names_[o];
  c += "\n";
  uint64_t h = 0xcbf29ce484222325ull;
  for (char ch : c) h = (h ^ static_cast<unsigned char>(ch)) * 0x100000001b3ull;
  map.digest_ = h;
  map.all_ = map.names_.size() == kMaxShards ? ~Mask{0} : (Mask{1} << map.names_.size()) - 1;
  *out = std::move(map);
  return Status::Ok();
}

Status ShardMap::Load(const std::string& path, ShardMap* out) {
  std::string text;
  if (Status s = ReadTextFile(path, &text); !s.ok())
    return Status(s.code(), "shard map: " + s.message());
  return Parse(text, path, out);
}

int ShardMap::Find(std::string_view name) const {
  for (size_t s = 0; s < names_.size(); ++s) {
    if (names_[s] == name) return static_cast<int>(s);
  }
  return -1;
}

uint32_t ShardMap::BlockOf(int axis, double x) const {
  const auto a = static_cast<size_t>(axis);
  const double i = std::floor((x - origin_[a]) / edge_[a]);
  // Clamped in double first: a cast of an out-of-range value is undefined. NaN fails both tests.
  if (!(i > 0)) return 0;
  if (!(i < static_cast<double>(count_[a] - 1))) return count_[a] - 1;
  return static_cast<uint32_t>(i);
}

size_t ShardMap::OwnerOf(const uint32_t* index) const {
  uint64_t b = 0;
  for (int a = dim_ - 1; a >= 0; --a) b = b * count_[size_t(a)] + index[a];
  return owner_[b];
}

ShardMap::Mask ShardMap::Route(const double* lo, const double* hi) const {
  std::array<uint32_t, 3> from{}, to{};
  for (int a = 0; a < dim_; ++a) {
    if (std::isnan(lo[a]) || std::isnan(hi[a]) || lo[a] > hi[a]) return 0;
    from[size_t(a)] = BlockOf(a, lo[a]);
    to[size_t(a)] = BlockOf(a, hi[a]);
  }
  Mask mask = 0;
  std::array<uint32_t, 3> i{};
  for (i[2] = from[2]; i[2] <= to[2]; ++i[2]) {
    for (i[1] = from[1]; i[1] <= to[1]; ++i[1]) {
      for (i[0] = from[0]; i[0] <= to[0]; ++i[0]) {
        mask |= Mask{1} << OwnerOf(i.data());
        if (mask == all_) return mask;  // a huge box: no need to visit every block
      }
    }
  }
  return mask;
}

uint64_t ShardMap::BlocksOwned(size_t shard) const {
  return static_cast<uint64_t>(std::count(owner_.begin(), owner_.end(), shard));
}

}  // namespace bp::transport
