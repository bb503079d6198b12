#!/usr/bin/env bash
# The export benchmark (bench/results/export.md): for each scene and method of the fast
# benchmark's λ = 1e-3 runs, `crpgs export` of its bitstream at SH degrees DEGREES (--refine
# REFINE), each .ply's test-view PSNR beside the anchor model's (export reads the file back);
# then the SH-3 .ply through splat-transform to .spz and .sog (CPU) and back to .ply, each read
# by `crpgs import` on the same test views. One thread throughout. Resumable: a step whose log
# ends complete is not redone.
#
# Usage: bench/export_all.sh CRPGS RUNS_DIR OUT_DIR
# Env:   SCENES (default "flower lego mic fern bonsai"), METHODS (default "hac crpgs"),
#        DEGREES (default "0 1 2 3"), REFINE (export's --refine; default 200, the sessions-35-37
#        tables), ST (splat-transform; default build/splat_transform/node_modules/.bin/
#        splat-transform, which the test suite installs)
# Writes OUT_DIR/<scene>_<method>/{sh<d>.ply,sh<d>.log,scene.spz,scene.sog,back_*.ply,*.log} and
# OUT_DIR/summary.tsv (scene, method, step, Gaussians, bytes, anchor PSNR, PSNR, seconds).
set -uo pipefail
crpgs=${1:?usage: bench/export_all.sh CRPGS RUNS_DIR OUT_DIR}
runs=${2:?runs directory (runs/benchmark_fast)}
out=${3:?output directory}
st=${ST:-build/splat_transform/node_modules/.bin/splat-transform}
mkdir -p "$out"
summary=$out/summary.tsv
[ -f "$summary" ] || printf 'scene\tmethod\tstep\tgaussians\tbytes\tanchor_psnr\tpsnr\tseconds\n' > "$summary"

# mean PSNR of the table a log ends with: export's "mean ANCHOR EXPORTED ..." or import's
# "mean PSNR SSIM ...".
mean_col() { awk -v c="$2" '$1 == "mean" {v = $c} END {print v}' "$1"; }
record() {  # SCENE METHOD STEP GAUSSIANS BYTES ANCHOR PSNR SECONDS
  grep -q "^$1	$2	$3	" "$summary" || printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$@" >> "$summary"
}

for scene in ${SCENES:-flower lego mic fern bonsai}; do
  for method in ${METHODS:-hac crpgs}; do
    run=$runs/$scene/$method/lambda-1.0e-3_schedule-fast
    if [ ! -f "$run/scene.crpgs" ]; then
      echo "skip $scene/$method: no $run/scene.crpgs"
      continue
    fi
    d=$out/${scene}_$method
    mkdir -p "$d"
    anchor=""
    for deg in ${DEGREES:-0 1 2 3}; do
      log=$d/sh$deg.log
      if ! grep -q "^mean" "$log" 2> /dev/null; then
        start=$(date +%s)
        "$crpgs" export "$run/scene.crpgs" -o "$d/sh$deg.ply" --sh-degree "$deg" \
          --refine "${REFINE:-200}" --threads 1 \
          > "$log" 2>&1 || { echo "FAILED: export $scene/$method SH $deg (see $log)"; continue; }
        echo "elapsed $(($(date +%s) - start)) s" >> "$log"
      fi
      anchor=$(mean_col "$log" 2)
      n=$(sed -n 's/^wrote .*: \([0-9]*\) Gaussians, SH degree.*/\1/p' "$log")
      record "$scene" "$method" "sh$deg" "$n" "$(stat -c %s "$d/sh$deg.ply")" "$anchor" \
        "$(mean_col "$log" 3)" "$(sed -n 's/^elapsed \([0-9]*\) s/\1/p' "$log")"
      echo "$scene/$method SH $deg: anchor $anchor dB, exported $(mean_col "$log" 3) dB, $n Gaussians"
    done
    [ -x "$st" ] || { echo "skip the .spz/.sog round trip: no splat-transform at $st"; continue; }
    [ -f "$d/sh3.ply" ] || continue
    for fmt in spz sog; do
      log=$d/back_$fmt.log
      if ! grep -q "^mean" "$log" 2> /dev/null; then
        start=$(date +%s)
        args=(-w -g cpu)
        [ $fmt = sog ] && args+=(-i 1 --max-workers 0)  # as tests/io/splat_transform_test.sh
        { "$st" "${args[@]}" "$d/sh3.ply" "$d/scene.$fmt" &&
          "$st" -w -g cpu "$d/scene.$fmt" "$d/back_$fmt.ply" &&
          "$crpgs" import "$d/back_$fmt.ply" -c "$run/config.yaml" --threads 1; } > "$log" 2>&1 ||
          { echo "FAILED: $fmt round trip $scene/$method (see $log)"; continue; }
        echo "elapsed $(($(date +%s) - start)) s" >> "$log"
      fi
      n=$(sed -n 's/^.*back_'$fmt'.ply: \([0-9]*\) Gaussians, SH degree.*/\1/p' "$log")
      record "$scene" "$method" "$fmt" "$n" "$(stat -c %s "$d/scene.$fmt")" "$anchor" \
        "$(mean_col "$log" 2)" "$(sed -n 's/^elapsed \([0-9]*\) s/\1/p' "$log")"
      echo "$scene/$method .$fmt: $(stat -c %s "$d/scene.$fmt") B, $(mean_col "$log" 2) dB after the round trip"
    done
  done
done
column -t -s $'\t' "$summary"
