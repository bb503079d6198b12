#!/bin/bash
# A/B of whole full-schedule trainings (issue #44): fern at 504x378 on 2 threads, each
# repetition trains with build A and build B side by side (both see the same machine load; the
# ratio is what compares), for configs/crpgs.yaml and configs/hac.yaml. Resumable: run the same
# command again and stopped runs resume from their checkpoints (a run's clock leaves out the time
# it was stopped); finished runs are kept. Prints per run the training time, its split by phase
# (metrics.json "phases"; builds before that field print "-") and B/A.
#   bench/ab_full_run.sh A_PREFIX B_PREFIX OUT_DIR [REPS] [SCHEDULE]
# A prefix is an install directory (cmake --install build --prefix DIR) with bin/crpgs, or a
# copy of a build's bin/ and lib/ (its libraries are found through LD_LIBRARY_PATH).
# SCHEDULE: full (default) or fast (the quick check). Env CONFIGS (default "crpgs hac").
set -uo pipefail
[ $# -ge 3 ] || { sed -n 2,12p "$0"; exit 2; }
a=$1 b=$2 out=$3 reps=${4:-1} schedule=${5:-full}
root=$(cd "$(dirname "$0")/.." && pwd)
for config in ${CONFIGS:-crpgs hac}; do
  for rep in $(seq "$reps"); do
    for side in A B; do
      prefix=$a
      [ "$side" = B ] && prefix=$b
      dir=$out/$config/$schedule/rep$rep/$side
      [ -f "$dir/metrics.json" ] && continue
      mkdir -p "$dir"
      resume=""
      [ -f "$dir/checkpoint.pt" ] && resume=--resume
      (cd "$root" && LD_LIBRARY_PATH=$prefix/lib "$prefix/bin/crpgs" train -c "configs/$config.yaml" -o "$dir" $resume \
        --set train.schedule="$schedule" --set train.threads=2 --set rasterizer.threads=2 \
        >> "$dir/stdout.log" 2>> "$dir/stderr.log") &
    done
    wait
  done
done
# The table: one row per run, B's rows with their ratio to A's of the same repetition.
for m in "$out"/*/*/rep*/[AB]/metrics.json; do
  [ -f "$m" ] || continue
  python3 - "$m" <<'EOF'
import json, os, sys
path = sys.argv[1]
m = json.load(open(path))
phases = {p["name"]: p for p in m.get("phases", [])}
def phase(name):
    p = phases.get(name)
    return "-" if p is None else "%d it %.0f s (%.2f it/s)" % (
        p["iterations"], p["seconds"], p["iterations"] / max(p["seconds"], 1e-9))
side_dir = os.path.dirname(path)
ratio = ""
if side_dir.endswith("/B"):
    other = os.path.join(os.path.dirname(side_dir), "A", "metrics.json")
    if os.path.exists(other):
        ratio = "B/A %.3f" % (m["train_seconds"] / json.load(open(other))["train_seconds"])
print("%s\t%.0f s\t%.3f dB\t%d B\traw %s\tnoise %s\trate %s\t%s" % (
    os.path.relpath(side_dir), m["train_seconds"], m["psnr_mean"], m["size_bytes"],
    phase("raw"), phase("fixed_noise"), phase("rate"), ratio))
EOF
done
