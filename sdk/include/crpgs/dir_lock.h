/// @file dir_lock.h
/// @brief One writer per run directory: `crpgs train -o DIR` holds DIR/.lock while it writes, and
/// `crpgs sweep` skips a run whose directory another process holds, so two processes never
/// train into (and overwrite) the same checkpoint.
#pragma once

#include <string>

#include "crpgs/status.h"

namespace crpgs {

/// An exclusive lock on DIR/.lock (a Linux open-file-description lock): released when the object
/// is destroyed, and by the kernel when the process ends in any way, so a crash leaves no stale
/// lock. Not inherited by spawned processes, except as fd() and child_environment() arrange.
class DirectoryLock {
 public:
  DirectoryLock() = default;
  DirectoryLock(DirectoryLock&& o) noexcept : fd_(o.fd_) { o.fd_ = -1; }
  DirectoryLock& operator=(DirectoryLock&& o) noexcept;
  DirectoryLock(const DirectoryLock&) = delete;
  DirectoryLock& operator=(const DirectoryLock&) = delete;
  ~DirectoryLock();
  bool held() const { return fd_ >= 0; }
  /// For a process about to be spawned that will lock the same directory (`crpgs sweep` starting
  /// `crpgs train`), so that no other process can take the directory in between: the descriptor
  /// to dup2 into the child as `child_fd`, and the "NAME=VALUE" to add to its environment, with
  /// which the child's lock_directory adopts this lock instead of waiting for it.
  int fd() const { return fd_; }
  static std::string child_environment(int child_fd);

 private:
  friend StatusOr<DirectoryLock> lock_directory(const std::string& dir);
  explicit DirectoryLock(int fd) : fd_(fd) {}
  int fd_ = -1;
};

/// Creates DIR if needed and takes its lock (or adopts the one a parent handed over, see
/// DirectoryLock::fd()). kIoError naming the holder ("pid 123 since
/// 2026-11-24 00:10:00") when another process (or another DirectoryLock) holds it. Where the
/// file system cannot lock (some network file systems), an unheld lock: check held().
StatusOr<DirectoryLock> lock_directory(const std::string& dir);

/// Takes a lock handed over by the parent process (DirectoryLock::fd()) out of the environment,
/// for lock_directory to adopt. Call it first thing in main, before threads exist (it unsets an
/// environment variable); lock_directory calls it too, for processes that did not.
void take_handed_over_lock();

/// Who holds DIR's lock ("pid 123 since ..."), or "" when nobody does (or DIR has no lock file).
std::string directory_lock_holder(const std::string& dir);

}  // namespace crpgs
