// Recording files: round trip, clean end, truncation and foreign files as DataLoss.
#include "bp/transport/recording.h"

#include <cstdio>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <unistd.h>

namespace bp::wire {
namespace {

std::string TempPath(const std::string& name) {
  return (std::filesystem::temp_directory_path() /
          ("bp-rec-" + std::to_string(getpid()) + "-" + name))
      .string();
}

TEST(Recording, RoundTripKeepsPayloadsAndTimesExactly) {
  const std::string path = TempPath("roundtrip");
  RecordingWriter writer;
  RecordingHeader header;
  header.set_topic("bp_updates");
  header.set_note("test");
  ASSERT_TRUE(writer.Open(path, header).ok());
  std::vector<std::string> payloads = {"", std::string("\0\xff\x01", 3), std::string(100000, 'x'),
                                       "not protobuf at all"};
  for (size_t i = 0; i < payloads.size(); ++i) {
    ASSERT_TRUE(writer.Append(1000 + i, payloads[i]).ok());
  }
  ASSERT_TRUE(writer.Close().ok());
  EXPECT_EQ(writer.batches(), payloads.size());

  RecordingReader reader;
  ASSERT_TRUE(reader.Open(path).ok());
  EXPECT_EQ(reader.header().topic(), "bp_updates");
  EXPECT_EQ(reader.header().note(), "test");
  EXPECT_EQ(reader.header().version(), SCHEMA_VERSION_1);
  RecordedBatch batch;
  bool end = false;
  for (size_t i = 0; i < payloads.size(); ++i) {
    ASSERT_TRUE(reader.Next(&batch, &end).ok());
    ASSERT_FALSE(end);
    EXPECT_EQ(batch.time_ns(), 1000 + i);
    EXPECT_EQ(batch.payload(), payloads[i]);
  }
  ASSERT_TRUE(reader.Next(&batch, &end).ok());
  EXPECT_TRUE(end);
  std::remove(path.c_str());
}

TEST(Recording, TruncationIsDataLossNamingTheBatch) {
  const std::string path = TempPath("truncated");
  {
    RecordingWriter writer;
    ASSERT_TRUE(writer.Open(path, RecordingHeader()).ok());
    ASSERT_TRUE(writer.Append(1, std::string(1000, 'a')).ok());
    ASSERT_TRUE(writer.Append(2, std::string(1000, 'b')).ok());
  }
  std::filesystem::resize_file(path, std::filesystem::file_size(path) - 10);
  RecordingReader reader;
  ASSERT_TRUE(reader.Open(path).ok());
  RecordedBatch batch;
  bool end = false;
  ASSERT_TRUE(reader.Next(&batch, &end).ok());
  Status s = reader.Next(&batch, &end);
  EXPECT_EQ(s.code(), StatusCode::kDataLoss);
  EXPECT_NE(s.message().find("batch 1 at byte offset"), std::string::npos) << s.message();
  std::remove(path.c_str());
}

TEST(Recording, ForeignOrMissingFilesAreRefused) {
  const std::string path = TempPath("foreign");
  std::ofstream(path) << "hello, this is not a recording";
  RecordingReader reader;
  Status s = reader.Open(path);
  EXPECT_EQ(s.code(), StatusCode::kDataLoss);
  EXPECT_NE(s.message().find("is not a broadphase recording"), std::string::npos);
  std::remove(path.c_str());
  s = reader.Open(TempPath("missing"));
  EXPECT_EQ(s.code(), StatusCode::kNotFound);
  EXPECT_NE(s.message().find("missing"), std::string::npos);
  RecordingWriter writer;
  EXPECT_FALSE(writer.Open("/nonexistent-dir/x.bprec", RecordingHeader()).ok());
  EXPECT_FALSE(writer.Append(1, "x").ok());
}

}  // namespace
}  // namespace bp::wire
