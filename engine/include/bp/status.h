// bp::Status: the error value every fallible engine call returns. The engine never throws.
//
// Thread safety: a Status is a plain value; copies are independent.
// Invariant: ok() iff code() == StatusCode::kOk, and then message() is empty.
#pragma once

#include <string>
#include <string_view>
#include <utility>

namespace bp {

/// Why a call was refused.
enum class StatusCode {
  kOk = 0,
  kInvalidArgument,    ///< a bad value: NaN, infinity, lo > hi, bad parameter
  kAlreadyExists,      ///< insert of a key that is present
  kNotFound,           ///< update or erase of a key that is absent
  kResourceExhausted,  ///< the engine holds as many objects as its handles can address
  kInternal,           ///< a broken invariant (found by Validate)
  kUnavailable,        ///< a service or transport cannot be reached or failed (DDS, files)
  kDeadlineExceeded,   ///< a wait or a write timed out
  kDataLoss,           ///< truncated or corrupt data (recordings, payloads)
};

/// Name of a code, e.g. "InvalidArgument".
std::string_view StatusCodeName(StatusCode code);

/// The outcome of a call: ok, or a code and a message naming the item and the reason.
class [[nodiscard]] Status {
 public:
  /// An ok status.
  Status() = default;
  /// A status with a code and a message.
  Status(StatusCode code, std::string message) : code_(code), message_(std::move(message)) {}

  /// The ok status.
  static Status Ok() { return Status(); }

  /// True when the call succeeded.
  bool ok() const { return code_ == StatusCode::kOk; }
  /// The code.
  StatusCode code() const { return code_; }
  /// The message (empty when ok).
  const std::string& message() const { return message_; }
  /// "OK" or "<Code>: <message>".
  std::string ToString() const;

 private:
  StatusCode code_ = StatusCode::kOk;
  std::string message_;
};

}  // namespace bp
