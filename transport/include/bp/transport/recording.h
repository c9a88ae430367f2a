// Recording files: an update stream on disk (transport/broadphase.proto, "Recording file").
//
// Layout: a RecordingHeader, then RecordedBatch messages, each preceded by its byte length as a
// varint (protobuf's delimited format). A RecordedBatch keeps the UpdateBatch payload exactly as
// it was received, malformed or not, so a replay reproduces what the daemon saw.
//
// Thread safety: a writer or reader is used by one thread at a time.
// Invariants: a writer's file is valid after every Append that returned ok and Flush (a crash
// loses at most the batches not yet flushed, never the file's readability up to that point);
// a reader reports truncation or corruption as DataLoss naming the batch index and byte offset.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include "broadphase.pb.h"

#include "bp/status.h"

namespace bp::wire {

/// The magic string of every recording header.
inline constexpr std::string_view kRecordingMagic = "broadphase-recording";

/// Appends batches to a new recording file.
class RecordingWriter {
 public:
  RecordingWriter();
  ~RecordingWriter();
  RecordingWriter(const RecordingWriter&) = delete;
  RecordingWriter& operator=(const RecordingWriter&) = delete;

  /// Creates (truncates) path and writes the header (magic and version are filled in).
  Status Open(const std::string& path, RecordingHeader header);
  /// Appends one batch: its receive time and the payload bytes as received.
  Status Append(uint64_t time_ns, std::string_view payload);
  /// Pushes buffered bytes to the operating system.
  Status Flush();
  /// Flushes and closes; further Appends fail. Idempotent.
  Status Close();
  /// Batches appended so far.
  uint64_t batches() const { return batches_; }
  /// Bytes written so far, header included.
  uint64_t bytes() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  uint64_t batches_ = 0;
};

/// Reads a recording file front to back.
class RecordingReader {
 public:
  RecordingReader();
  ~RecordingReader();
  RecordingReader(const RecordingReader&) = delete;
  RecordingReader& operator=(const RecordingReader&) = delete;

  /// Opens path and reads the header: NotFound if it cannot be opened, DataLoss if the header is
  /// missing or its magic is wrong, InvalidArgument for an unknown version.
  Status Open(const std::string& path);
  /// The header read by Open.
  const RecordingHeader& header() const { return header_; }
  /// Reads the next batch into out. Sets *out_end (and returns ok) at a clean end of file;
  /// DataLoss naming the batch index and offset if the file is truncated or corrupt.
  Status Next(RecordedBatch* out, bool* out_end);
  /// Batches read so far.
  uint64_t batches() const { return batches_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  RecordingHeader header_;
  uint64_t batches_ = 0;
  std::string path_;
};

}  // namespace bp::wire
