/// @file dir_lock.cpp
#include "crpgs/dir_lock.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>

#include "core/time_text.h"

namespace crpgs {
namespace {

constexpr const char* kLockName = "/.lock";
constexpr const char* kInheritedLockEnv = "CRPGS_INHERITED_LOCK_FD";

struct flock whole_file(short type) {
  struct flock fl {};
  fl.l_type = type;
  fl.l_whence = SEEK_SET;  // l_start = l_len = 0: the whole file
  return fl;
}

std::string read_holder(int fd) {
  char buf[128] = {};
  const ssize_t n = ::pread(fd, buf, sizeof buf - 1, 0);
  std::string s = n > 0 ? std::string(buf, size_t(n)) : std::string();
  while (!s.empty() && (s.back() == '\n' || s.back() == '\0')) s.pop_back();
  return s.empty() ? "another process" : s;
}

}  // namespace

DirectoryLock& DirectoryLock::operator=(DirectoryLock&& o) noexcept {
  if (this != &o) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = o.fd_;
    o.fd_ = -1;
  }
  return *this;
}

DirectoryLock::~DirectoryLock() {
  if (fd_ >= 0) ::close(fd_);  // closing the description releases the lock
}

std::string DirectoryLock::child_environment(int child_fd) {
  return std::string(kInheritedLockEnv) + "=" + std::to_string(child_fd);
}

namespace {
int g_handed_fd = -1;  // taken from the environment, not adopted yet
}  // namespace

void take_handed_over_lock() {
  const char* env = std::getenv(kInheritedLockEnv);
  if (!env) return;
  const int fd = std::atoi(env);
  ::unsetenv(kInheritedLockEnv);  // not for this process's own children
  if (fd <= 2 || ::fcntl(fd, F_SETFD, FD_CLOEXEC) != 0) return;
  g_handed_fd = fd;
}

namespace {

/// The descriptor a parent handed over for `path` (same file, lock taken on it), or -1.
int adopt_inherited(const std::string& path) {
  take_handed_over_lock();
  const int fd = g_handed_fd;
  struct stat a = {}, b = {};
  if (fd < 0 || ::fstat(fd, &a) != 0 || ::stat(path.c_str(), &b) != 0 || a.st_dev != b.st_dev ||
      a.st_ino != b.st_ino)
    return -1;  // meant for another directory
  g_handed_fd = -1;
  return fd;
}

}  // namespace

StatusOr<DirectoryLock> lock_directory(const std::string& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  const std::string path = dir + kLockName;
  int fd = adopt_inherited(path);
  if (fd < 0) fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0)
    return Status(StatusCode::kIoError, "cannot open " + path + ": " + std::strerror(errno));
  // On an adopted descriptor this succeeds: the lock is already this description's.
  struct flock fl = whole_file(F_WRLCK);
  if (::fcntl(fd, F_OFD_SETLK, &fl) != 0) {
    const int err = errno;
    const bool busy = err == EAGAIN || err == EACCES;
    const std::string holder = busy ? read_holder(fd) : std::string();
    ::close(fd);
    if (!busy) return DirectoryLock();  // e.g. ENOLCK on some network file systems
    return Status(StatusCode::kIoError,
                  dir + " is in use (" + holder +
                      "): another crpgs process is writing there; wait for it or pick another "
                      "output directory");
  }
  const std::string text =
      "pid " + std::to_string(::getpid()) + " since " + local_time_text() + "\n";
  // Only the holder writes here. A failed write still locks; messages then name no pid.
  const bool named =
      ::ftruncate(fd, 0) == 0 && ::pwrite(fd, text.data(), text.size(), 0) == ssize_t(text.size());
  static_cast<void>(named);
  return DirectoryLock(fd);
}

std::string directory_lock_holder(const std::string& dir) {
  const int fd = ::open((dir + kLockName).c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return "";
  struct flock fl = whole_file(F_WRLCK);
  std::string holder;
  if (::fcntl(fd, F_OFD_GETLK, &fl) == 0 && fl.l_type != F_UNLCK) holder = read_holder(fd);
  ::close(fd);
  return holder;
}

}  // namespace crpgs
