/// @file test_kill_resume.cpp
/// @brief No lost work: `crpgs train` killed with SIGKILL at a random moment leaves either no
/// checkpoint or a complete one, and `--resume` finishes the run with exactly the state of an
/// uninterrupted run of the same config.
#include <gtest/gtest.h>
#include <torch/torch.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <thread>

#include "cli_test_util.h"
#include "crpgs/dir_lock.h"
#include "crpgs/experiments/run_metrics.h"
#include "crpgs/experiments/sweep.h"
#include "crpgs/runtime.h"
#include "crpgs/trainer.h"

namespace crpgs {
namespace {
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

// Plain Scaffold-GS training of a small synthetic scene, a checkpoint every 4 iterations, the
// held-out PSNR every 10 (its trace must survive the kill too).
const char* kConfig = R"yaml(
dataset: {format: synthetic, synthetic_width: 48, synthetic_height: 32, synthetic_views: 12,
          synthetic_points: 1000}
model: {voxel_size: 0.08}
rasterizer: {type: cpu, threads: 1}
train: {schedule: fast, fast_factor: 0.002, iterations: 60, eval_interval: 10,
        checkpoint_interval: 4, threads: 1, seed: 11}
)yaml";

int wait_for(pid_t pid, int* status) {
  while (true) {
    const pid_t r = waitpid(pid, status, 0);
    if (r == pid || (r < 0 && errno != EINTR)) return r;
  }
}

TEST(KillAndResume, SigkillAtARandomPointThenResumeEqualsAnUninterruptedRun) {
#ifndef CRPGS_CLI_PATH
  GTEST_SKIP() << "built without the crpgs CLI (CRPGS_BUILD_APPS=OFF)";
#else
  if (!fs::exists(CRPGS_CLI_PATH))
    GTEST_SKIP() << "the crpgs CLI is not built yet: " << CRPGS_CLI_PATH;
  const fs::path dir = fs::path(CRPGS_TEST_TMP_DIR) / "kill_resume";
  fs::remove_all(dir);
  fs::create_directories(dir);
  const fs::path cfg = dir / "tiny.yaml";
  ASSERT_TRUE(write_file_atomic(cfg.string(), std::string(kConfig)).ok());

  std::string log;
  const auto t0 = Clock::now();
  ASSERT_EQ(test::run_cli("train -c '" + cfg.string() + "' -o '" + (dir / "ref").string() + "'",
                          dir / "ref.log", &log),
            0)
      << log;
  const double full_s = std::chrono::duration<double>(Clock::now() - t0).count();
  // The progress lines' test PSNR (and metrics.json's trace) average every test view here.
  {
    auto m = experiments::read_run_metrics((dir / "ref" / "metrics.json").string());
    ASSERT_TRUE(m.ok()) << m.status().message();
    ASSERT_GE(m->views.size(), 2u);
    ASSERT_LE(m->views.size(), size_t(Trainer::kMaxTraceViews));
    std::vector<std::string> names;
    for (const auto& v : m->views) names.push_back(v.name);
    EXPECT_EQ(m->trace_views, names);
    EXPECT_NE(log.find("test PSNR (progress, trace): mean of " + std::to_string(names.size()) +
                       " test views (" + names[0] + ", "),
              std::string::npos)
        << log;
  }
  // The CLI restarted itself with idle compute threads that sleep (apps/main.cpp; it needs
  // /proc, which a bare chroot may lack).
  if (fs::exists("/proc/self/exe") && !std::getenv("OMP_WAIT_POLICY") &&
      !std::getenv("OPENBLAS_THREAD_TIMEOUT")) {
    EXPECT_NE(log.find("idle compute threads: OMP_WAIT_POLICY=PASSIVE, OPENBLAS_THREAD_TIMEOUT=4"),
              std::string::npos)
        << log;
  }
  // ... and with OpenBLAS kernels as wide as the CPU runs: OpenBLAS falls back to SSE3 ones on
  // CPUs newer than itself (Debian 12's on an Intel Xeon of model 207).
  if (fs::exists("/proc/self/exe") && !std::getenv("OPENBLAS_CORETYPE")) {
    const std::string tag = "BLAS kernels: OpenBLAS ";
    const size_t at = log.find(tag);
    ASSERT_NE(at, std::string::npos) << log;
    const size_t from = at + tag.size();
    const std::string core = log.substr(from, log.find_first_of(" \n", from) - from);
    if (openblas_core_vector_level(core) >= 0) {
      EXPECT_GE(openblas_core_vector_level(core), cpu_vector_level()) << log;
    }
  }

  // Kill at a random moment of the run (seed printed so a failure can be replayed).
  const unsigned seed = std::random_device{}();
  std::mt19937 rng(seed);
  double fraction = std::uniform_real_distribution<double>(0.15, 0.6)(rng);
  const fs::path run = dir / "run";
  bool killed = false;
  for (int attempt = 0; attempt < 4 && !killed; ++attempt, fraction /= 2) {
    fs::remove_all(run);
    const pid_t pid =
        test::spawn_cli({"train", "-c", cfg.string(), "-o", run.string()}, dir / "killed.log");
    ASSERT_GT(pid, 0);
    std::this_thread::sleep_for(std::chrono::duration<double>(fraction * full_s));
    kill(pid, SIGKILL);
    int status = 0;
    ASSERT_EQ(wait_for(pid, &status), pid);
    killed = WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL;
    std::printf("seed %u attempt %d: %s after %.2f s of a %.2f s run\n", seed, attempt,
                killed ? "killed" : "had already finished", fraction * full_s, full_s);
  }
  ASSERT_TRUE(killed) << "the run always finished before the kill";

  // What the kill left: no checkpoint yet, or a complete one.
  int resumed_from = 0;
  if (fs::exists(run / "checkpoint.pt")) {
    const auto ckpt = test::read_archive(run / "checkpoint.pt");
    ASSERT_TRUE(ckpt.count("iteration")) << "checkpoint left by the kill is incomplete";
    resumed_from = int(ckpt.at("iteration").item<int64_t>());
    EXPECT_EQ(resumed_from % 4, 0);
  }
  // The killed process left no stale lock (the resume below gets it), and while another process
  // holds the directory a second writer is refused without touching it.
  {
    auto held = lock_directory(run.string());
    ASSERT_TRUE(held.ok()) << "the SIGKILLed run left its lock: " << held.status().message();
    const auto before = fs::exists(run / "checkpoint.pt")
                            ? fs::last_write_time(run / "checkpoint.pt")
                            : fs::file_time_type::min();
    EXPECT_NE(test::run_cli("train -c '" + cfg.string() + "' -o '" + run.string() + "' --resume",
                            dir / "refused.log", &log),
              0);
    EXPECT_NE(log.find(run.string() + " is in use (pid " + std::to_string(getpid())),
              std::string::npos)
        << log;
    if (fs::exists(run / "checkpoint.pt")) {
      EXPECT_EQ(fs::last_write_time(run / "checkpoint.pt"), before);
    }
  }
  ASSERT_EQ(test::run_cli("train -c '" + cfg.string() + "' -o '" + run.string() +
                              "' --resume --method 'tiny resumed'",
                          dir / "resume.log", &log),
            0)
      << log;
  // metrics.json names the method: the config's file name unless --method says otherwise.
  EXPECT_NE(test::read_text(dir / "ref" / "metrics.json").find("\"method\": \"tiny\""),
            std::string::npos);
  EXPECT_NE(test::read_text(run / "metrics.json").find("\"method\": \"tiny resumed\""),
            std::string::npos);
  if (resumed_from > 0) {
    EXPECT_NE(log.find("resumed at iteration " + std::to_string(resumed_from)), std::string::npos)
        << log;
    EXPECT_EQ(log.find("another config"), std::string::npos) << log;  // the same config
  }
  std::printf("resumed from iteration %d\n", resumed_from);

  const auto a = test::read_archive(dir / "ref" / "checkpoint.pt");
  const auto b = test::read_archive(run / "checkpoint.pt");
  ASSERT_FALSE(a.empty());
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(b.at("iteration").item<int64_t>(), 60);
  for (const auto& [k, v] : a) {
    ASSERT_TRUE(b.count(k)) << k;
    // Wall-clock: differs between any two runs (phase_iterations, its count, is compared).
    if (k == "elapsed_seconds" || k == "phase_seconds") continue;
    if (k == "psnr_trace") {  // [M, 3]: seconds, iteration, PSNR
      EXPECT_TRUE(torch::equal(v.slice(1, 1), b.at(k).slice(1, 1))) << k;
      continue;
    }
    EXPECT_TRUE(torch::equal(v, b.at(k))) << k;
  }

  // The run directory says whether it is finished, whoever trained it (a sweep reads this).
  // A new training into it needs --force; one that fails in its set-up (a mistyped dataset)
  // leaves the finished run as it was: results, config and all.
  EXPECT_EQ(experiments::run_state(run.string()), experiments::RunState::kComplete);
  const std::string config_before = test::read_text(run / "config.yaml");
  const std::string bad_dataset = "' --set dataset.format=colmap --set dataset.path=/nonexistent";
  EXPECT_NE(test::run_cli("train -c '" + cfg.string() + "' -o '" + run.string() + bad_dataset,
                          dir / "refused.log", &log),
            0);
  EXPECT_NE(log.find(run.string() + " holds a run (checkpoint.pt): --resume continues it, "
                                    "--force trains a new one over it"),
            std::string::npos)
      << log;
  EXPECT_NE(test::run_cli(
                "train -c '" + cfg.string() + "' -o '" + run.string() + bad_dataset + " --force",
                dir / "failed.log", &log),
            0);
  EXPECT_NE(log.find("/nonexistent"), std::string::npos) << log;
  EXPECT_EQ(experiments::run_state(run.string()), experiments::RunState::kComplete) << log;
  EXPECT_EQ(test::read_text(run / "config.yaml"), config_before);
  // Into a new directory, the same failure leaves no directory (and no .lock) behind.
  const fs::path fresh = dir / "new" / "run";
  fs::create_directories(fresh.parent_path());
  EXPECT_NE(test::run_cli("train -c '" + cfg.string() + "' -o '" + fresh.string() + bad_dataset,
                          dir / "failed_new.log", &log),
            0);
  EXPECT_NE(log.find("/nonexistent"), std::string::npos) << log;
  EXPECT_FALSE(fs::exists(fresh)) << log;
  EXPECT_TRUE(fs::is_empty(fresh.parent_path()));
  // --force that gets past its set-up removes the earlier run's checkpoint and results at once:
  // killed before its own first checkpoint, it leaves nothing a --resume could take for its own.
  const pid_t forced =
      test::spawn_cli({"train", "-c", cfg.string(), "-o", run.string(), "--force", "--set",
                       "train.iterations=100000", "--set", "train.checkpoint_interval=0", "--set",
                       "train.checkpoint_minutes=0"},
                      dir / "forced.log");
  ASSERT_GT(forced, 0);
  const auto deadline = Clock::now() + std::chrono::seconds(60);
  while (test::read_text(dir / "forced.log").find("resolved config") == std::string::npos &&
         waitpid(forced, nullptr, WNOHANG) == 0 && Clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  kill(forced, SIGKILL);
  int forced_status = 0;
  ASSERT_EQ(wait_for(forced, &forced_status), forced);
  ASSERT_NE(test::read_text(dir / "forced.log").find("resolved config"), std::string::npos)
      << test::read_text(dir / "forced.log");
  EXPECT_FALSE(fs::exists(run / "checkpoint.pt"));
  EXPECT_FALSE(fs::exists(run / "metrics.json"));
  EXPECT_EQ(experiments::run_state(run.string()), experiments::RunState::kInterrupted);
#endif
}

// SIGUSR1 writes a checkpoint and training goes on (from set-up on it never ends the process);
// SIGHUP, like SIGINT and SIGTERM, checkpoints and stops.
TEST(KillAndResume, Sigusr1CheckpointsAndGoesOnSighupStops) {
#ifndef CRPGS_CLI_PATH
  GTEST_SKIP() << "built without the crpgs CLI (CRPGS_BUILD_APPS=OFF)";
#else
  if (!fs::exists(CRPGS_CLI_PATH))
    GTEST_SKIP() << "the crpgs CLI is not built yet: " << CRPGS_CLI_PATH;
  const fs::path dir = fs::path(CRPGS_TEST_TMP_DIR) / "signals";
  fs::remove_all(dir);
  fs::create_directories(dir);
  const fs::path cfg = dir / "tiny.yaml", run = dir / "run", log = dir / "train.log";
  ASSERT_TRUE(write_file_atomic(cfg.string(), std::string(kConfig)).ok());
  // No checkpoints of its own: one that appears was asked for.
  const pid_t pid = test::spawn_cli(
      {"train", "-c", cfg.string(), "-o", run.string(), "--set", "train.iterations=100000", "--set",
       "train.checkpoint_interval=0", "--set", "train.checkpoint_minutes=0"},
      log);
  ASSERT_GT(pid, 0);
  auto alive = [&] { return waitpid(pid, nullptr, WNOHANG) == 0; };
  const auto deadline = Clock::now() + std::chrono::seconds(60);
  // Before this line the process may still be restarting itself (main.cpp): no handler yet.
  while (test::read_text(log).find("resolved config") == std::string::npos && alive() &&
         Clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  while (!fs::exists(run / "checkpoint.pt") && alive() && Clock::now() < deadline) {
    kill(pid, SIGUSR1);
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  ASSERT_TRUE(alive()) << test::read_text(log);
  ASSERT_TRUE(fs::exists(run / "checkpoint.pt")) << test::read_text(log);
  const int64_t saved_at =
      test::read_archive(run / "checkpoint.pt").at("iteration").item<int64_t>();
  EXPECT_GT(saved_at, 0);
  kill(pid, SIGHUP);
  int status = 0;
  ASSERT_EQ(wait_for(pid, &status), pid);
  ASSERT_TRUE(WIFEXITED(status)) << test::read_text(log);
  EXPECT_EQ(WEXITSTATUS(status), 130) << test::read_text(log);
  EXPECT_NE(test::read_text(log).find("interrupted: checkpoint written"), std::string::npos)
      << test::read_text(log);
  const int64_t stopped_at =
      test::read_archive(run / "checkpoint.pt").at("iteration").item<int64_t>();
  EXPECT_GE(stopped_at, saved_at);
  EXPECT_EQ(experiments::run_state(run.string()), experiments::RunState::kInterrupted);

  // Resumed under another config (here two more iterations): it goes on, and says so.
  std::string out;
  ASSERT_EQ(
      test::run_cli("train -c '" + cfg.string() + "' -o '" + run.string() +
                        "' --resume --set train.iterations=" + std::to_string(stopped_at + 2) +
                        " --set train.checkpoint_interval=0 --set train.checkpoint_minutes=0",
                    dir / "resume.log", &out),
      0)
      << out;
  EXPECT_NE(out.find("resumed at iteration " + std::to_string(stopped_at) +
                     " (written under another config"),
            std::string::npos)
      << out;
  EXPECT_EQ(experiments::run_state(run.string()), experiments::RunState::kComplete);
#endif
}

}  // namespace
}  // namespace crpgs
