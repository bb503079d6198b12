/// @file progress.h
/// @brief How the trainer reports what it is doing. The library never prints; the CLI implements
/// ProgressCallback (e.g. a throttled progress bar) and the stop/save flags it sets on Ctrl-C.
#pragma once

#include <atomic>
#include <cstdint>
#include <string>

namespace crpgs {

/// One training iteration's numbers. Held-out PSNR is computed only every `eval_interval`
/// iterations; `has_test_psnr` says whether this report carries one.
struct TrainingProgress {
  int iteration = 0;  ///< 1-based, just completed
  int total_iterations = 0;
  double loss = 0;  ///< total loss of this iteration
  double l1 = 0;    ///< L1 part
  bool has_test_psnr = false;
  double test_psnr = 0;  ///< dB, mean over the trace's held-out views (8-bit round trip)
  int64_t anchors = 0;
  int64_t gaussians = 0;             ///< neural Gaussians rendered this iteration
  double iterations_per_second = 0;  ///< over the last report interval
  double elapsed_seconds = 0;        ///< training wall-clock, resumed runs included
  double eta_seconds = 0;
  bool has_rate = false;      ///< rate phase of the rate path: the next field is set
  double bits_per_param = 0;  ///< rate term before lambda (bpp + hash share, docs/method.md §2.5)
};

class ProgressCallback {
 public:
  virtual ~ProgressCallback() = default;
  /// Called every iteration; implementations throttle their own output.
  virtual void on_iteration(const TrainingProgress& p) = 0;
  /// Called after anchors were grown/pruned.
  virtual void on_adjust(int iteration, int64_t grown, int64_t pruned, int64_t anchors) {}
  /// Called after a checkpoint was written (atomically) to `path`.
  virtual void on_checkpoint(int iteration, const std::string& path) {}
  /// Called when an iteration's loss or gradients were not finite (its update is discarded) or
  /// the trainer rolled back to its last good state; `message` names the iteration and group.
  virtual void on_warning(int iteration, const std::string& message) {}
  /// Something worth a line in the log that is not a problem (e.g. a shared prefix written).
  virtual void on_note(int iteration, const std::string& message) {}
};

/// Flags another thread (a signal handler) may set while the trainer runs.
struct TrainControl {
  std::atomic<bool> stop{false};  ///< save a checkpoint and return kCancelled
  std::atomic<bool> save{false};  ///< save a checkpoint now and continue (cleared after)
};

}  // namespace crpgs
