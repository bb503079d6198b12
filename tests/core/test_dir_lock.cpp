// Run-directory hygiene: one writer per directory (DirectoryLock, released on destruction and when
// the holder dies), and the temporary files a killed writer leaves.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include "crpgs/atomic_file.h"
#include "crpgs/dir_lock.h"

namespace crpgs {
namespace {

std::string fresh_lock_dir(const std::string& name) {
  const auto p = std::filesystem::path(CRPGS_TEST_TMP_DIR) / "dir_lock" / name;
  std::filesystem::remove_all(p);
  return p.string();  // lock_directory creates it
}

TEST(DirectoryLock, SecondHolderIsRefusedWithTheFirstOnesPid) {
  const std::string dir = fresh_lock_dir("twice");
  EXPECT_EQ(directory_lock_holder(dir), "");  // no directory yet
  auto first = lock_directory(dir);
  ASSERT_TRUE(first.ok()) << first.status().message();
  const std::string me = "pid " + std::to_string(::getpid()) + " since ";
  EXPECT_EQ(directory_lock_holder(dir).rfind(me, 0), 0u) << directory_lock_holder(dir);

  auto second = lock_directory(dir);  // another open description: refused even in this process
  ASSERT_FALSE(second.ok());
  EXPECT_EQ(second.status().code(), StatusCode::kIoError);
  EXPECT_NE(second.status().message().find(dir + " is in use (" + me), std::string::npos)
      << second.status().message();

  first = DirectoryLock();  // released
  EXPECT_EQ(directory_lock_holder(dir), "");
  auto third = lock_directory(dir);
  EXPECT_TRUE(third.ok()) << third.status().message();
}

TEST(DirectoryLock, MovedLockStaysHeld) {
  const std::string dir = fresh_lock_dir("moved");
  auto lock = lock_directory(dir);
  ASSERT_TRUE(lock.ok());
  DirectoryLock moved = std::move(lock).value();
  EXPECT_TRUE(moved.held());
  EXPECT_FALSE(lock_directory(dir).ok());
}

TEST(DirectoryLock, AChildAdoptsTheLockItsParentHandedOver) {
  // What `crpgs sweep` does for `crpgs train`, within one process: the lock's description
  // survives on another descriptor, announced in the environment, and lock_directory adopts it.
  const std::string dir = fresh_lock_dir("handed");
  auto parent = lock_directory(dir);
  ASSERT_TRUE(parent.ok());
  const int inherited = ::dup(parent->fd());
  ASSERT_GT(inherited, 2);
  const std::string env = DirectoryLock::child_environment(inherited);
  const std::string name = env.substr(0, env.find('='));
  ASSERT_EQ(::setenv(name.c_str(), env.substr(env.find('=') + 1).c_str(), 1), 0);
  parent = DirectoryLock();  // the parent lets go: the child's descriptor keeps the lock
  EXPECT_NE(directory_lock_holder(dir), "");
  auto other = lock_directory(fresh_lock_dir("other"));  // another directory adopts nothing
  ASSERT_TRUE(other.ok()) << other.status().message();
  EXPECT_NE(other->fd(), inherited);
  EXPECT_EQ(std::getenv(name.c_str()), nullptr);  // taken out, not passed on to children
  auto child = lock_directory(dir);
  ASSERT_TRUE(child.ok()) << child.status().message();
  EXPECT_EQ(child->fd(), inherited);
  EXPECT_FALSE(lock_directory(dir).ok());  // still exclusive
  child = DirectoryLock();
  EXPECT_EQ(directory_lock_holder(dir), "");
}

TEST(DirectoryLock, AHolderThatDiesLeavesNoStaleLock) {
  const std::string dir = fresh_lock_dir("died");
  int ready[2], go[2];
  ASSERT_EQ(::pipe(ready), 0);
  ASSERT_EQ(::pipe(go), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    auto lock = lock_directory(dir);
    char c = lock.ok() ? '1' : '0';
    if (::write(ready[1], &c, 1) != 1 || ::read(go[0], &c, 1) != 1) ::_exit(3);
    ::_exit(1);  // no destructor runs: only the kernel can release the lock
  }
  char c = 0;
  ASSERT_EQ(::read(ready[0], &c, 1), 1);
  ASSERT_EQ(c, '1');
  const std::string holder = directory_lock_holder(dir);
  EXPECT_EQ(holder.rfind("pid " + std::to_string(child) + " since ", 0), 0u) << holder;
  EXPECT_FALSE(lock_directory(dir).ok());
  ASSERT_EQ(::write(go[1], "x", 1), 1);
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  EXPECT_EQ(directory_lock_holder(dir), "");
  EXPECT_TRUE(lock_directory(dir).ok());
  for (int fd : {ready[0], ready[1], go[0], go[1]}) ::close(fd);
}

// What a killed write_file_atomic leaves behind goes; everything else stays.
TEST(AtomicFile, ReadingADirectoryIsAnErrorNotAHugeAllocation) {
  const std::string dir = std::string(CRPGS_TEST_TMP_DIR) + "/a_directory";
  std::filesystem::create_directories(dir);
  auto r = read_file_bytes(dir);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("is a directory"), std::string::npos) << r.status().message();
}

TEST(AtomicFile, StaleTempFilesAreRemovedAndNothingElse) {
  const std::string dir = std::string(CRPGS_TEST_TMP_DIR) + "/stale_tmp";
  std::filesystem::remove_all(dir);
  ASSERT_TRUE(write_file_atomic(dir + "/checkpoint.pt", "kept").ok());
  for (const char* name : {"checkpoint.pt.tmp.123.0", "metrics.json.tmp.9.17"})
    ASSERT_TRUE(write_file_atomic(dir + "/" + name, "half").ok());
  for (const char* name : {"notes.tmp.txt", "a.tmp.1.x", ".tmp.1.2", "b.tmp.12"})
    ASSERT_TRUE(write_file_atomic(dir + "/" + name, "kept").ok());
  EXPECT_EQ(remove_stale_temp_files(dir), 2);
  EXPECT_FALSE(std::filesystem::exists(dir + "/checkpoint.pt.tmp.123.0"));
  EXPECT_FALSE(std::filesystem::exists(dir + "/metrics.json.tmp.9.17"));
  for (const char* name : {"checkpoint.pt", "notes.tmp.txt", "a.tmp.1.x", ".tmp.1.2", "b.tmp.12"})
    EXPECT_TRUE(std::filesystem::exists(dir + "/" + name)) << name;
  EXPECT_EQ(remove_stale_temp_files(dir + "/missing"), 0);
}

}  // namespace
}  // namespace crpgs
