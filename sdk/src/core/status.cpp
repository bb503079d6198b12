/// @file status.cpp
#include "crpgs/status.h"

namespace crpgs {

const char* status_code_name(StatusCode code) {
  switch (code) {
    case StatusCode::kOk:
      return "ok";
    case StatusCode::kInvalidArgument:
      return "invalid argument";
    case StatusCode::kInvalidConfig:
      return "invalid config";
    case StatusCode::kPluginLoadFailed:
      return "plugin load failed";
    case StatusCode::kPluginAbiMismatch:
      return "plugin ABI mismatch";
    case StatusCode::kUnsupportedVersion:
      return "unsupported version";
    case StatusCode::kIoError:
      return "I/O error";
    case StatusCode::kCorruptBitstream:
      return "corrupt bitstream";
    case StatusCode::kDeviceUnavailable:
      return "device unavailable";
    case StatusCode::kNotFound:
      return "not found";
    case StatusCode::kInternal:
      return "internal error";
    case StatusCode::kCancelled:
      return "cancelled";
    case StatusCode::kNonFinite:
      return "non-finite values";
  }
  return "unknown";
}

std::string Status::to_string() const {
  if (ok()) return "ok";
  return std::string(status_code_name(code_)) + ": " + message_;
}

}  // namespace crpgs
