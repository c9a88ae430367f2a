#include "bp/transport/recording.h"

#include <cerrno>
#include <cstring>

#include <fcntl.h>
#include <google/protobuf/io/zero_copy_stream_impl.h>
#include <google/protobuf/util/delimited_message_util.h>
#include <unistd.h>

namespace bp::wire {
namespace {

Status Errno(StatusCode code, const std::string& what, const std::string& path) {
  return Status(code, what + " '" + path + "': " + std::strerror(errno));
}

}  // namespace

struct RecordingWriter::Impl {
  int fd = -1;
  std::unique_ptr<google::protobuf::io::FileOutputStream> out;
  std::string path;
  RecordedBatch scratch;
};

RecordingWriter::RecordingWriter() = default;
RecordingWriter::~RecordingWriter() { (void)Close(); }

Status RecordingWriter::Open(const std::string& path, RecordingHeader header) {
  if (impl_) return Status(StatusCode::kInvalidArgument, "recording writer already open");
  int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return Errno(StatusCode::kNotFound, "cannot create recording", path);
  impl_ = std::make_unique<Impl>();
  impl_->fd = fd;
  impl_->path = path;
  impl_->out = std::make_unique<google::protobuf::io::FileOutputStream>(fd);
  header.set_magic(std::string(kRecordingMagic));
  header.set_version(SCHEMA_VERSION_1);
  if (!google::protobuf::util::SerializeDelimitedToZeroCopyStream(header, impl_->out.get())) {
    return Errno(StatusCode::kUnavailable, "cannot write the header of recording", path);
  }
  return Flush();
}

Status RecordingWriter::Append(uint64_t time_ns, std::string_view payload) {
  if (!impl_) return Status(StatusCode::kInvalidArgument, "recording writer is not open");
  impl_->scratch.set_time_ns(time_ns);
  impl_->scratch.set_payload(payload.data(), payload.size());
  if (!google::protobuf::util::SerializeDelimitedToZeroCopyStream(impl_->scratch,
                                                                  impl_->out.get())) {
    return Errno(StatusCode::kUnavailable,
                 "cannot append batch " + std::to_string(batches_) + " to recording", impl_->path);
  }
  ++batches_;
  return Status::Ok();
}

Status RecordingWriter::Flush() {
  if (!impl_) return Status::Ok();
  if (!impl_->out->Flush()) {
    return Errno(StatusCode::kUnavailable, "cannot write recording", impl_->path);
  }
  return Status::Ok();
}

Status RecordingWriter::Close() {
  if (!impl_) return Status::Ok();
  Status status = Flush();
  impl_->out.reset();
  if (::close(impl_->fd) != 0 && status.ok()) {
    status = Errno(StatusCode::kUnavailable, "cannot close recording", impl_->path);
  }
  impl_.reset();
  return status;
}

uint64_t RecordingWriter::bytes() const {
  return impl_ ? static_cast<uint64_t>(impl_->out->ByteCount()) : 0;
}

struct RecordingReader::Impl {
  int fd = -1;
  std::unique_ptr<google::protobuf::io::FileInputStream> in;
  ~Impl() {
    in.reset();
    if (fd >= 0) ::close(fd);
  }
};

RecordingReader::RecordingReader() = default;
RecordingReader::~RecordingReader() = default;

Status RecordingReader::Open(const std::string& path) {
  impl_.reset();
  path_ = path;
  batches_ = 0;
  int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return Errno(StatusCode::kNotFound, "cannot open recording", path);
  impl_ = std::make_unique<Impl>();
  impl_->fd = fd;
  impl_->in = std::make_unique<google::protobuf::io::FileInputStream>(fd);
  bool clean_eof = false;
  if (!google::protobuf::util::ParseDelimitedFromZeroCopyStream(&header_, impl_->in.get(),
                                                                &clean_eof) ||
      header_.magic() != kRecordingMagic) {
    impl_.reset();
    return Status(StatusCode::kDataLoss,
                  "'" + path + "' is not a broadphase recording (no valid header)");
  }
  if (header_.version() != SCHEMA_VERSION_1) {
    impl_.reset();
    return Status(StatusCode::kInvalidArgument,
                  "recording '" + path + "' has schema version " +
                      std::to_string(static_cast<int>(header_.version())) +
                      "; this build reads version 1");
  }
  return Status::Ok();
}

Status RecordingReader::Next(RecordedBatch* out, bool* out_end) {
  *out_end = false;
  if (!impl_) return Status(StatusCode::kInvalidArgument, "recording reader is not open");
  const int64_t offset = impl_->in->ByteCount();
  bool clean_eof = false;
  if (!google::protobuf::util::ParseDelimitedFromZeroCopyStream(out, impl_->in.get(), &clean_eof)) {
    if (clean_eof) {
      *out_end = true;
      return Status::Ok();
    }
    return Status(StatusCode::kDataLoss, "recording '" + path_ + "': batch " +
                                             std::to_string(batches_) + " at byte offset " +
                                             std::to_string(offset) + " is truncated or corrupt");
  }
  ++batches_;
  return Status::Ok();
}

}  // namespace bp::wire
