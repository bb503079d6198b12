/// @file run_metrics.h
/// @brief metrics.json: what one training run measured (size, quality per test view, times,
/// PSNR-vs-time trace, peak memory, bitstream breakdown). Written by `crpgs train` at the end
/// of a run, read by `crpgs sweep` (a run with a readable metrics.json is finished) and
/// `crpgs report`.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "crpgs/status.h"

namespace crpgs::experiments {

/// Format tag stored in every metrics.json ("format" key).
inline constexpr const char* kRunMetricsFormat = "crpgs.run_metrics/1";

/// What the bytes of a bitstream encode.
enum class BitstreamCategory {
  kGeometry,   ///< anchor positions
  kFeatures,   ///< anchor features
  kScaling,    ///< anchor scalings
  kOffsets,    ///< neural Gaussian offsets
  kMasks,      ///< pruning masks
  kLinks,      ///< cross-representation links
  kHashGrids,  ///< context and feature-model sections: hash tables with their own MLPs
  kMlps,       ///< the neural Gaussians' MLPs
  kOther,      ///< headers, anything else
};
inline constexpr int kNumBitstreamCategories = 9;
/// "geometry", "features", "scaling", "offsets", "masks", "links", "hash_grids", "mlps", "other".
const char* category_name(BitstreamCategory c);
/// Bytes per category, indexed by static_cast<int>(BitstreamCategory).
using BitstreamBreakdown = std::array<uint64_t, kNumBitstreamCategories>;

struct ViewMetrics {
  std::string name;
  double psnr = 0;  ///< dB
  double ssim = 0;
  double render_seconds = 0;  ///< time to render this view (NaN if not measured)
};

/// One point of the PSNR-vs-training-time trace.
struct TracePoint {
  double seconds = 0;  ///< training wall-clock since the start (excluding evaluation)
  int iteration = 0;
  double psnr = 0;  ///< dB, mean over RunMetrics::trace_views, 8-bit round trip
};

/// Training time spent in one phase of the schedule (docs/method.md, the quantisation phases):
/// whole steps, link builds included, evaluation excluded; resumed processes included.
struct PhaseTime {
  std::string name;  ///< "raw", "fixed_noise" or "rate"
  int iterations = 0;
  double seconds = 0;
};

/// Where a result came from, for its record to be rerun and compared.
struct Provenance {
  std::string version;  ///< crpgs version, e.g. "0.1.0"; empty: not recorded (older runs)
  std::string commit;   ///< git commit of the sources the binary was built from
  std::string libtorch;
  std::string cpu;     ///< CPU model (/proc/cpuinfo "model name")
  int cpus = -1;       ///< logical CPUs of the machine
  int threads = -1;    ///< compute threads of the run (train.threads as resolved)
  std::string device;  ///< where the model trained: "cpu" or "cuda"
  int64_t seed = -1;
};

/// This process's version, commit, libtorch and machine, with the run's seed, threads, device.
Provenance this_process_provenance(int64_t seed, int threads, const std::string& device);

struct RunMetrics {
  std::string method;       ///< e.g. "hac", "crpgs" (the sweep's run.json may relabel it)
  std::string dataset;      ///< e.g. "fern"
  double lambda = NAN;      ///< rate-distortion trade-off; NaN when not applicable
  std::string config_hash;  ///< Config::hash() of the resolved config, hex

  uint64_t size_bytes = 0;         ///< total compressed size
  BitstreamBreakdown breakdown{};  ///< should add up to size_bytes
  /// What the bitstream holds: coded anchors, and their neural Gaussians whose offset mask is
  /// on (the most a render spawns; what an exported .ply holds). -1: not recorded (older runs).
  int64_t anchors = -1;
  int64_t gaussians = -1;

  std::vector<ViewMetrics> views;  ///< test views
  double psnr_mean = NAN;          ///< mean over views (filled from views if NaN)
  double ssim_mean = NAN;

  double train_seconds = NAN;
  double encode_seconds = NAN;
  double decode_seconds = NAN;
  /// Mean of views[].render_seconds (filled from views if NaN).
  double render_seconds_per_view = NAN;
  /// Per phase of the schedule, in order (runs with a rate model; older files: empty).
  std::vector<PhaseTime> phases;
  std::vector<TracePoint> trace;
  /// The test views the trace averages (Trainer::trace_views). Files from before it was
  /// recorded traced the first test view alone: read as views[0]'s name.
  std::vector<std::string> trace_views;
  int64_t peak_memory_bytes = 0;  ///< peak resident set size, see peak_rss_bytes()
  /// A file re-encoded from another run's trained model with every quantisation step scaled
  /// (`crpgs encode --rate-scales`, "one model, many rates"): the scale and that run's method.
  /// NaN and "" for a run's own bitstream.
  double rate_scale = NAN;
  std::string base_method;
  Provenance provenance;
};

/// What a PSNR trace of these test views measures: "test view NAME" or "mean of N test views".
std::string trace_measure(const std::vector<std::string>& views);

/// Peak resident set size of this process so far (getrusage ru_maxrss), in bytes.
int64_t peak_rss_bytes();

/// Fills psnr_mean, ssim_mean and render_seconds_per_view from `views` where they are NaN.
void fill_means(RunMetrics& m);

std::string to_json(const RunMetrics& m);
StatusOr<RunMetrics> run_metrics_from_json(const std::string& text);

/// Writes metrics.json atomically (after fill_means).
Status write_run_metrics(const std::string& path, const RunMetrics& m);
StatusOr<RunMetrics> read_run_metrics(const std::string& path);

/// A run directory is finished when RUN/metrics.json is readable and no RUN/.running marker is
/// left: whoever trains it (a sweep or `crpgs train`) marks it started before training, which
/// also removes an older metrics.json, and finished after writing the new one, so a crashed
/// attempt never passes for finished and a finished one never for unfinished.
Status mark_run_started(const std::string& run_dir);
void mark_run_finished(const std::string& run_dir);
bool run_marked_started(const std::string& run_dir);

}  // namespace crpgs::experiments
