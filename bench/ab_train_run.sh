#!/bin/bash
# A/B of whole training iterations between two builds: BM_TrainRun on one checkpoint, the two
# alternated REPS times (this machine's speed drifts; compare the medians as a ratio). Compare
# wall_it_per_s (appended to each line): it is wall-clock for any build.
#   bench/ab_train_run.sh RUN_DIR OLD_PREFIX NEW_PREFIX [REPS]
# A prefix is a build or install directory with bin/bench_train_fern and lib/ (e.g. build, or
# a `cp -a build/bin build/lib` copy of an older commit). CRPGS_BENCH_STEPS sets the steps (20).
set -euo pipefail
[ $# -ge 3 ] || { sed -n 2,7p "$0"; exit 2; }
run=$1 old=$2 new=$3 reps=${4:-3}
for rep in $(seq "$reps"); do
  for prefix in "$old" "$new"; do
    echo "== $prefix (rep $rep)"
    CRPGS_BENCH_RUN=$run CRPGS_BENCH_STEPS=${CRPGS_BENCH_STEPS:-20} LD_LIBRARY_PATH=$prefix/lib \
      CRPGS_PLUGIN_PATH=$prefix/lib/crpgs/plugins "$prefix/bin/bench_train_fern" \
      --benchmark_filter=TrainRun --benchmark_counters_tabular=true 2>&1 |
      grep -E "^Benchmark|TrainRun|rror" |
      # Wall-clock it/s from the Time column (real time per step): builds before session 11
      # computed their it_per_s counter from the main thread's CPU time.
      awk '/TrainRun/ && $3 == "ms" { printf "%s  wall_it_per_s=%.3f\n", $0, 1000 / $2; next } 1'
  done
done
