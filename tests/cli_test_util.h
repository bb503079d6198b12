/// @file cli_test_util.h
/// @brief Running the `crpgs` executable from tests. CRPGS_CLI_PATH is a per-source compile
/// definition (see tests/*/sources.cmake); tests skip, saying why, when it is not set.
#pragma once

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <torch/serialize/input-archive.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "crpgs/atomic_file.h"

extern char** environ;

namespace crpgs::test {

inline std::string read_text(const std::filesystem::path& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// Runs `crpgs ARGS` (a shell-quoted string) to completion; returns its exit code, its output
/// (prefixed with the command line) in *log.
inline int run_cli(const std::string& args, const std::filesystem::path& log_path,
                   std::string* log) {
#ifdef CRPGS_CLI_PATH
  const std::string cmd =
      std::string("'") + CRPGS_CLI_PATH + "' " + args + " > '" + log_path.string() + "' 2>&1";
  const int rc = std::system(cmd.c_str());
  *log = "$ crpgs " + args + "\n" + read_text(log_path);
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
#else
  (void)args, (void)log_path, (void)log;
  return -1;
#endif
}

/// Starts `crpgs ARGS...` without waiting (stdout and stderr to log_path); returns its pid, or
/// -1 when it cannot be started.
inline pid_t spawn_cli(const std::vector<std::string>& args,
                       const std::filesystem::path& log_path) {
#ifdef CRPGS_CLI_PATH
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_addopen(&fa, 1, log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&fa, 1, 2);
  std::vector<std::string> argv_s{CRPGS_CLI_PATH};
  argv_s.insert(argv_s.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& a : argv_s) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, CRPGS_CLI_PATH, &fa, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&fa);
  return rc == 0 ? pid : -1;
#else
  (void)args, (void)log_path;
  return -1;
#endif
}

/// Every tensor of a torch archive (checkpoint.pt, decoded.pt) by key.
inline std::map<std::string, torch::Tensor> read_archive(const std::filesystem::path& path) {
  std::map<std::string, torch::Tensor> out;
  auto bytes = read_file_bytes(path.string());
  if (!bytes.ok()) return out;
  torch::serialize::InputArchive ar;
  ar.load_from(reinterpret_cast<const char*>(bytes->data()), bytes->size());
  for (const auto& k : ar.keys()) {
    torch::Tensor t;
    ar.read(k, t);
    out[k] = t;
  }
  return out;
}

}  // namespace crpgs::test
