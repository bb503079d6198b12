#!/bin/bash
# A/B of whole training iterations between two builds: BM_TrainRun on one checkpoint, the two
# alternated REPS times (this machine's speed drifts; compare the medians as a ratio).
#   bench/ab_train_run.sh RUN_DIR OLD_PREFIX NEW_PREFIX [REPS]
# A prefix is a build or install directory with bin/bench_train_fern and lib/ (e.g. build, or
# a `cp -a build/bin build/lib` copy of an older commit). CRPGS_BENCH_STEPS sets the steps (20).
set -euo pipefail
[ $# -ge 3 ] || { sed -n 2,6p "$0"; exit 2; }
run=$1 old=$2 new=$3 reps=${4:-3}
for rep in $(seq "$reps"); do
  for prefix in "$old" "$new"; do
    echo "== $prefix (rep $rep)"
    CRPGS_BENCH_RUN=$run CRPGS_BENCH_STEPS=${CRPGS_BENCH_STEPS:-20} LD_LIBRARY_PATH=$prefix/lib \
      CRPGS_PLUGIN_PATH=$prefix/lib/crpgs/plugins "$prefix/bin/bench_train_fern" \
      --benchmark_filter=TrainRun --benchmark_counters_tabular=true 2>&1 |
      grep -E "^Benchmark|TrainRun|rror"
  done
done
