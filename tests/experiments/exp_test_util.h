// Helpers for the experiments tests: scratch directories and a fake `crpgs train` runner.
#pragma once

#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <string>

namespace crpgs::experiments::test {

/// A fresh directory under the build's test tmp dir.
inline std::string fresh_dir(const std::string& name) {
  const auto p = std::filesystem::path(CRPGS_TEST_TMP_DIR) / "experiments" / name;
  std::filesystem::remove_all(p);
  std::filesystem::create_directories(p);
  return p.string();
}

inline void write_text(const std::string& path, const std::string& text) {
  std::ofstream(path) << text;
}

inline std::string read_text(const std::string& path) {
  std::ifstream f(path);
  return std::string(std::istreambuf_iterator<char>(f), {});
}

/// A stand-in for `crpgs train -c CFG -o DIR [--resume]`: appends "DIR [--resume]" to
/// $FAKE_LOG, writes DIR/checkpoint.pt, then
///  - if DIR ends with $FAKE_CRASH and DIR/.crashed_once is absent: creates it and exits 3;
///  - if DIR ends with $FAKE_HANG: touches DIR/hang_started and sleeps until killed;
///  - else writes DIR/metrics.json (size from `lambda:` in the config, PSNR from the size).
inline std::string write_fake_runner(const std::string& dir) {
  const std::string path = dir + "/fake_train.sh";
  write_text(path, R"sh(#!/bin/bash
set -eu
if [ "$1" = encode ]; then  # encode RUN --rate-scales a,b: a smaller fake file per scale
  run="$2"; scales="$4"
  [ -n "${FAKE_LOG:-}" ] && echo "encode $run $scales" >> "$FAKE_LOG"
  for s in ${scales//,/ }; do
    mkdir -p "$run/rates/scale-$s"
    awk -v s="$s" -v method="$(sed -n 's/.*"method": "\([^"]*\)".*/\1/p' "$run/metrics.json")" 'BEGIN {
      size = int(1000000 / s); printf "{\"format\": \"crpgs.run_metrics/1\", \"method\": \"%s (one model)\", ", method;
      printf "\"lambda\": 0.001, \"size_bytes\": %d, \"psnr_mean\": %.3f, \"rate_scale\": %s, \"base_method\": \"%s\"}\n", size, 30 - s, s, method;
    }' > "$run/rates/scale-$s/metrics.json"
  done
  exit 0
fi
cfg=""; out=""; resume=""; method=""
while [ $# -gt 0 ]; do
  case "$1" in
    -c) cfg="$2"; shift 2 ;;
    -o) out="$2"; shift 2 ;;
    --resume) resume=" --resume"; shift ;;
    --method) method="$2"; shift 2 ;;
    *) shift ;;
  esac
done
echo "fake train: $cfg -> $out"
echo "$method" > "$out/method_arg"
[ -n "${FAKE_LOG:-}" ] && echo "$out$resume" >> "$FAKE_LOG"
echo checkpoint > "$out/checkpoint.pt"
if [ -n "${FAKE_CRASH:-}" ] && [[ "$out" == *"$FAKE_CRASH" ]] && [ ! -e "$out/.crashed_once" ]; then
  touch "$out/.crashed_once"; echo "fake crash" >&2; exit 3
fi
if [ -n "${FAKE_HANG:-}" ] && [[ "$out" == *"$FAKE_HANG" ]]; then
  touch "$out/hang_started"; exec sleep 1000
fi
lambda=$(awk '/lambda:/ {print $2; exit}' "$cfg")
lambda=${lambda:-0.001}
awk -v l="$lambda" -v method="$(awk '/tag:/ {print $2; exit}' "$cfg")" 'BEGIN {
  size = int(2000000 * (0.001 / l) ^ 0.5); psnr = 20 + 1.5 * log(size) / log(2) - 20;
  printf "{\"format\": \"crpgs.run_metrics/1\", \"method\": \"%s\", \"lambda\": %s, ", method, l;
  printf "\"size_bytes\": %d, \"psnr_mean\": %.4f, \"ssim_mean\": 0.8, ", size, psnr;
  printf "\"train_seconds\": 12.5, \"encode_seconds\": 0.5, \"decode_seconds\": 0.25, ";
  printf "\"render_seconds_per_view\": 0.01, ";
  printf "\"bitstream\": {\"geometry\": %d, \"features\": %d, \"mlps\": %d}, ", size / 4, size / 2, size - size / 4 - size / 2;
  printf "\"trace\": [[1.0, 100, %.3f], [5.0, 500, %.3f], [12.0, 1000, %.3f]]}\n", psnr - 5, psnr - 1, psnr;
}' > "$out/metrics.json.tmp"
mv "$out/metrics.json.tmp" "$out/metrics.json"
)sh");
  chmod(path.c_str(), 0755);
  return path;
}

}  // namespace crpgs::experiments::test
