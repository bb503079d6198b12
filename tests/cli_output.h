/// @file cli_output.h
/// @brief Output of the `crpgs` executable for tests that need no torch. CRPGS_CLI_PATH is a
/// per-source compile definition (see tests/*/sources.cmake); without it there is nothing to run.
#pragma once

#include <sys/wait.h>

#include <cstdio>
#include <string>

namespace crpgs::test {

#ifdef CRPGS_CLI_PATH
/// `crpgs ARGS` (shell-quoted), stdout and stderr together; its exit status in *rc if given
/// (128 + the signal's number when a signal ended it, as a shell says).
inline std::string crpgs_output(const std::string& args, int* rc = nullptr) {
  std::string out;
  FILE* p = popen(("'" CRPGS_CLI_PATH "' " + args + " 2>&1").c_str(), "r");
  if (!p) return out;
  char buf[512];
  while (std::fgets(buf, sizeof buf, p)) out += buf;
  const int status = pclose(p);
  if (rc) *rc = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  return out;
}
#endif

}  // namespace crpgs::test
