// Writes the fuzz targets' seed corpora (committed under tests/fuzz/corpus/; rerun after a
// schema change):
//   make_fuzz_seeds tests/fuzz/corpus
// update_batch/: inputs of fuzz_update_batch (a configuration byte, then [u16 length][payload]
// records) whose payloads are real UpdateBatch messages: frames of inserts, updates and erases
// in float and double, attributes, and each kind of bad item the daemon must reject.
// engine_ops/: inputs of fuzz_engine_ops, which reads any bytes; seeded random bytes of several
// lengths give the fuzzer long call sequences from the start.
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "broadphase.pb.h"

namespace {

namespace fs = std::filesystem;
using bp::wire::UpdateBatch;

void Write(const fs::path& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!out) {
    std::cerr << "make_fuzz_seeds: cannot write " << path << "\n";
    std::exit(1);
  }
}

// One fuzz_update_batch input: the configuration byte, then each batch as a record.
std::string Input(uint8_t config, const std::vector<UpdateBatch>& batches) {
  std::string out(1, static_cast<char>(config));
  for (const UpdateBatch& b : batches) {
    std::string payload = b.SerializeAsString();
    out.push_back(static_cast<char>(payload.size() & 0xFF));
    out.push_back(static_cast<char>(payload.size() >> 8 & 0xFF));
    out += payload;
  }
  return out;
}

UpdateBatch Batch(uint32_t dim, uint64_t frame) {
  UpdateBatch b;
  b.set_version(bp::wire::SCHEMA_VERSION_1);
  b.set_producer(7);
  b.set_frame(frame);
  b.set_end_of_frame(true);
  b.set_dim(dim);
  b.set_batch_seq(frame);
  return b;
}

// Appends a box at (x, x, ...) of edge w; double or float coordinates.
void AddBox(bp::wire::BoxArray* a, uint64_t id, uint32_t dim, double x, double w, bool dbl) {
  a->add_ids(id);
  for (uint32_t i = 0; i < dim; ++i) {
    if (dbl) {
      a->add_lo64(x + i);
      a->add_hi64(x + i + w);
    } else {
      a->add_lo32(static_cast<float>(x + i));
      a->add_hi32(static_cast<float>(x + i + w));
    }
  }
}

std::vector<UpdateBatch> Frames(uint32_t dim, bool dbl, std::mt19937_64& rng) {
  std::vector<UpdateBatch> frames;
  std::uniform_int_distribution<int> pos(0, 12);
  UpdateBatch first = Batch(dim, 1);
  for (uint64_t id = 1; id <= 20; ++id) AddBox(first.mutable_inserts(), id, dim, pos(rng), 2, dbl);
  frames.push_back(first);
  for (uint64_t f = 2; f <= 5; ++f) {
    UpdateBatch b = Batch(dim, f);
    for (uint64_t id = 1; id <= 20; id += 3) AddBox(b.mutable_updates(), id, dim, pos(rng), 2, dbl);
    b.add_erases(f);
    AddBox(b.mutable_inserts(), 100 + f, dim, pos(rng), 1, dbl);
    frames.push_back(b);
  }
  return frames;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::cerr << "usage: make_fuzz_seeds CORPUS_DIR\n";
    return 2;
  }
  const fs::path root = argv[1];
  fs::create_directories(root / "update_batch");
  fs::create_directories(root / "engine_ops");
  std::mt19937_64 rng(20261123);

  // Ordinary frames: every dimension and coordinate type with float and double payloads.
  int n = 0;
  for (uint8_t config = 0; config < 6; ++config) {
    const uint32_t dim = 2 + (config & 1);
    for (bool dbl : {false, true}) {
      const auto with_algorithm = static_cast<uint8_t>(config | (n % 8) << 3);
      Write(root / "update_batch" / ("frames_" + std::to_string(n)),
            Input(with_algorithm, Frames(dim, dbl, rng)));
      ++n;
    }
  }

  // Attributes, and each kind of bad item, in one frame after a valid one.
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<std::pair<std::string, UpdateBatch>> bad;
  {
    UpdateBatch b = Batch(3, 2);
    AddBox(b.mutable_inserts(), 50, 3, 1, 3, false);
    AddBox(b.mutable_inserts(), 51, 3, 2, 3, false);
    b.mutable_inserts()->add_static_flags(true);
    b.mutable_inserts()->add_static_flags(true);
    b.mutable_inserts()->add_category(2);
    b.mutable_inserts()->add_category(1);
    b.mutable_inserts()->add_mask(1);
    b.mutable_inserts()->add_mask(~uint64_t{0});
    bad.emplace_back("attributes", b);
  }
  {
    UpdateBatch b = Batch(3, 2);
    AddBox(b.mutable_inserts(), 60, 3, nan, 1, true);
    AddBox(b.mutable_inserts(), 61, 3, inf, 1, true);
    AddBox(b.mutable_inserts(), 62, 3, 1e300, 1, true);             // beyond float
    AddBox(b.mutable_inserts(), 63, 3, 0.5, 1, true);               // not integral
    AddBox(b.mutable_inserts(), 64, 3, 4, -2, true);                // inverted
    AddBox(b.mutable_inserts(), 1, 3, 0, 1, true);                  // live id
    AddBox(b.mutable_inserts(), uint64_t{1} << 48, 3, 0, 1, true);  // id out of range
    AddBox(b.mutable_updates(), 999, 3, 0, 1, true);                // unknown id
    b.add_erases(998);                                              // unknown id
    bad.emplace_back("bad_items", b);
  }
  {
    UpdateBatch b = Batch(3, 2);
    AddBox(b.mutable_inserts(), 70, 3, 1, 1, false);
    b.mutable_inserts()->add_lo64(1.0);              // float and double in one array
    AddBox(b.mutable_updates(), 2, 2, 1, 1, false);  // two coordinates per id in 3-D
    b.mutable_updates()->add_static_flags(true);     // an attribute on an update
    bad.emplace_back("bad_arrays", b);
  }
  {
    UpdateBatch b = Batch(2, 2);  // the wrong dimension for a 3-D daemon
    AddBox(b.mutable_inserts(), 80, 2, 1, 1, false);
    bad.emplace_back("wrong_dim", b);
  }
  {
    UpdateBatch b = Batch(3, 2);
    b.set_producer(0);
    bad.emplace_back("bad_producer", b);
    b.set_producer(7);
    b.set_version(static_cast<bp::wire::SchemaVersion>(9));
    bad.emplace_back("bad_version", b);
  }
  {
    UpdateBatch b = Batch(3, 2);  // more than max_objects (40) inserts
    for (uint64_t id = 200; id < 260; ++id) AddBox(b.mutable_inserts(), id, 3, 0, 1, false);
    bad.emplace_back("capacity", b);
  }
  for (const auto& [name, b] : bad) {
    std::vector<UpdateBatch> frames = Frames(3, false, rng);
    frames.resize(1);
    frames.push_back(b);
    Write(root / "update_batch" / name, Input(1, frames));
  }
  // A truncated payload and garbage.
  std::string truncated = Input(1, Frames(3, false, rng));
  Write(root / "update_batch" / "truncated", truncated.substr(0, truncated.size() / 2));

  // engine_ops: random bytes of several lengths.
  std::uniform_int_distribution<int> byte(0, 255);
  for (size_t len : {size_t{64}, size_t{256}, size_t{1024}, size_t{4096}, size_t{16384}}) {
    std::string bytes;
    for (size_t i = 0; i < len; ++i) bytes.push_back(static_cast<char>(byte(rng)));
    Write(root / "engine_ops" / ("random_" + std::to_string(len) + "_" + std::to_string(n)), bytes);
    ++n;
  }
  std::cout << "make_fuzz_seeds: wrote " << root << "\n";
  return 0;
}
