/// @file status.h
/// @brief Status / StatusOr: how every public SDK function reports failure (Draco style).
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <variant>

namespace crpgs {

enum class StatusCode {
  kOk = 0,
  kInvalidArgument,
  kInvalidConfig,
  kPluginLoadFailed,
  kPluginAbiMismatch,
  kUnsupportedVersion,
  kIoError,
  kCorruptBitstream,
  kDeviceUnavailable,
  kNotFound,
  kInternal,
  kCancelled,
  kNonFinite,  ///< NaN or Inf in a loss, gradient or parameter
};

const char* status_code_name(StatusCode code);

class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(StatusCode code, std::string message) : code_(code), message_(std::move(message)) {}
  bool ok() const { return code_ == StatusCode::kOk; }
  StatusCode code() const { return code_; }
  const std::string& message() const { return message_; }
  /// "kind: message", for logs and CLI output.
  std::string to_string() const;

 private:
  StatusCode code_ = StatusCode::kOk;
  std::string message_;
};

inline Status OkStatus() {
  return Status();
}

/// A value or the Status explaining why there is none. Implicit from both, so a function can
/// `return value;` or `return Status(...)`.
template <typename T>
class [[nodiscard]] StatusOr {
 public:
  StatusOr(Status status) : status_(std::move(status)) {}  // NOLINT(runtime/explicit)
  StatusOr(T value) : value_(std::move(value)) {}          // NOLINT(runtime/explicit)
  bool ok() const { return status_.ok(); }
  const Status& status() const { return status_; }
  T& value() & { return *value_; }
  const T& value() const& { return *value_; }
  T&& value() && { return std::move(*value_); }
  T* operator->() { return &*value_; }
  const T* operator->() const { return &*value_; }
  T& operator*() { return *value_; }

 private:
  Status status_;
  std::optional<T> value_;
};

/// Thrown only inside the CLI and tests to turn a Status into an exception where convenient.
struct StatusError : std::exception {
  explicit StatusError(Status s) : status(std::move(s)), text(status.to_string()) {}
  const char* what() const noexcept override { return text.c_str(); }
  Status status;
  std::string text;
};

}  // namespace crpgs

#define CRPGS_CONCAT_INNER(a, b) a##b
#define CRPGS_CONCAT(a, b) CRPGS_CONCAT_INNER(a, b)

#define CRPGS_RETURN_IF_ERROR(expr)        \
  do {                                     \
    ::crpgs::Status _crpgs_st = (expr);    \
    if (!_crpgs_st.ok()) return _crpgs_st; \
  } while (0)

#define CRPGS_ASSIGN_OR_RETURN_IMPL(tmp, lhs, expr) \
  auto tmp = (expr);                                \
  if (!tmp.ok()) return tmp.status();               \
  lhs = std::move(tmp).value()

#define CRPGS_ASSIGN_OR_RETURN(lhs, expr) \
  CRPGS_ASSIGN_OR_RETURN_IMPL(CRPGS_CONCAT(_crpgs_so_, __LINE__), lhs, expr)
