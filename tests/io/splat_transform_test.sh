#!/bin/bash
# External check of `crpgs export`: PlayCanvas splat-transform (npm @playcanvas/splat-transform)
# reads the exported .ply of a tiny trained model, converts it to .spz and .sog on the CPU and
# both back to .ply; the Gaussian count and the SH degree survive every step and the position
# means agree. The package is installed once into BUILD_DIR/splat_transform and reused offline.
# Skips (exit 77, a visible SKIP line) when it is not installed there yet and node/npm is absent,
# the registry does not answer within 20 s, or the install fails.
# CRPGS_SPLAT_TRANSFORM_VERSION=X pins the version installed (default: npm's choice for this node).
# Usage: splat_transform_test.sh BUILD_DIR CRPGS_EXE
set -u
BUILD=$1
CRPGS=$2
SKIP=77
skip() { echo "SKIP: splat-transform test: $*"; exit $SKIP; }
fail() { echo "FAIL: $*"; exit 1; }

[ -x "$CRPGS" ] || fail "no crpgs executable at $CRPGS"
command -v node > /dev/null 2>&1 || skip "node not found (splat-transform runs on Node.js)"

PREFIX="$BUILD/splat_transform"
PKG_JSON="$PREFIX/node_modules/@playcanvas/splat-transform/package.json"
ST="$PREFIX/node_modules/.bin/splat-transform"
if [ ! -x "$ST" ] || [ ! -f "$PKG_JSON" ]; then
  command -v npm > /dev/null 2>&1 || skip "npm not found (needed once to install @playcanvas/splat-transform)"
  registry=$(npm config get registry 2> /dev/null)
  timeout 20 npm view @playcanvas/splat-transform version > /dev/null 2>&1 ||
    skip "the npm registry ($registry) did not answer within 20 s"
  # Installed beside the cache and moved into place: an interrupted install leaves no cache.
  tmp="$PREFIX.tmp.$$"
  rm -rf "$tmp"
  mkdir -p "$tmp"
  spec="@playcanvas/splat-transform${CRPGS_SPLAT_TRANSFORM_VERSION:+@$CRPGS_SPLAT_TRANSFORM_VERSION}"
  echo "installing $spec into $PREFIX (once)"
  if ! timeout 300 npm install --prefix "$tmp" --no-audit --no-fund "$spec" > "$tmp.log" 2>&1; then
    tail -n 20 "$tmp.log"
    rm -rf "$tmp" "$tmp.log"
    skip "npm install $spec failed (log above)"
  fi
  rm -rf "$PREFIX" "$tmp.log"
  mv "$tmp" "$PREFIX" || fail "cannot move the install to $PREFIX"
fi
VERSION=$(node -p "require('$PKG_JSON').version") || fail "cannot read $PKG_JSON"
echo "splat-transform version: $VERSION (node $(node --version), $PREFIX)"

D="$BUILD/test_tmp/splat_transform"
rm -rf "$D"
mkdir -p "$D"
cd "$D" || fail "cannot enter $D"

# A tiny plain Scaffold-GS model (no rate path, no plugins): seconds of CPU.
cat > tiny.yaml << 'YAML'
dataset: {format: synthetic, synthetic_width: 48, synthetic_height: 32, synthetic_views: 8,
          synthetic_points: 800}
rasterizer: {type: cpu, threads: 1}
train: {iterations: 20, eval_interval: 0, checkpoint_interval: 0, threads: 1}
YAML
timeout 120 "$CRPGS" train -c tiny.yaml -o run > train.log 2>&1 || { cat train.log; fail "crpgs train"; }
timeout 120 "$CRPGS" export run -o scene.ply --sh-degree 3 --refine 200 --threads 1 \
  > export.log 2>&1 ||
  { cat export.log; fail "crpgs export"; }
cat export.log
N=$(sed -n 's/^wrote .*: \([0-9][0-9]*\) Gaussians, SH degree 3 .*/\1/p' export.log)
[ -n "$N" ] && [ "$N" -gt 0 ] || fail "no Gaussian count in the export output"

# The header of a binary .ply: every line up to end_header.
header() { LC_ALL=C head -c 65536 "$1" | LC_ALL=C sed -n '1,/^end_header/p'; }
check_ply() {  # FILE WHAT: N vertices and 45 f_rest (SH degree 3)
  local h n r
  h=$(header "$1")
  n=$(echo "$h" | sed -n 's/^element vertex \([0-9]*\).*/\1/p')
  r=$(echo "$h" | grep -c '^property [a-z0-9]* f_rest_')
  [ "$n" = "$N" ] || fail "$2: $1 has $n vertices, crpgs exported $N"
  [ "$r" = 45 ] || fail "$2: $1 has $r f_rest properties, SH degree 3 has 45"
  echo "$2: $1: $n vertices, $r f_rest"
}
check_ply scene.ply "crpgs export"

run_st() {  # LOG ARGS...: splat-transform, its output in LOG
  local log=$1
  shift
  timeout 300 "$ST" "$@" > "$log" 2>&1 || { cat "$log"; fail "splat-transform $*"; }
}
# splat-transform's own reading of our file (-m: per-column summary, with the row count).
run_st sum_scene.txt -q scene.ply null -m
rows=$(sed -n 's/^\*\*Row Count:\*\* *\([0-9]*\).*/\1/p' sum_scene.txt)
[ "$rows" = "$N" ] || { cat sum_scene.txt; fail "splat-transform reads $rows Gaussians in scene.ply, crpgs exported $N"; }
echo "splat-transform reads scene.ply: $rows Gaussians"

# To .spz and .sog (CPU: -g cpu; one SH k-means iteration, no worker threads) and back to .ply.
run_st spz.log -w -g cpu scene.ply scene.spz
run_st sog.log -w -g cpu -i 1 --max-workers 0 scene.ply scene.sog
for f in scene.spz scene.sog; do
  [ -s "$f" ] || fail "splat-transform wrote no $f"
done
run_st back_spz.log -w -g cpu scene.spz back_spz.ply
run_st back_sog.log -w -g cpu scene.sog back_sog.ply
echo "sizes: scene.ply $(stat -c %s scene.ply) B, scene.spz $(stat -c %s scene.spz) B, scene.sog $(stat -c %s scene.sog) B"
check_ply back_spz.ply "scene.spz -> .ply"
check_ply back_sog.ply "scene.sog -> .ply"

# Position means through each format agree with the direct read within 0.1% of the extent
# (both formats quantise positions far finer than that).
col() { awk -F'|' -v c="$2" '{g = $2; gsub(/ /, "", g)} g == c {gsub(/ /, "", $3); gsub(/ /, "", $4); gsub(/ /, "", $6); print $3, $4, $6}' "$1"; }
for b in back_spz back_sog; do
  run_st "sum_$b.txt" -q "$b.ply" null -m
  for c in x y z; do
    read -r lo hi mean_a <<< "$(col sum_scene.txt "$c")"
    read -r _ _ mean_b <<< "$(col "sum_$b.txt" "$c")"
    [ -n "${mean_b:-}" ] && [ -n "${mean_a:-}" ] || fail "no '$c' column in the splat-transform summary"
    awk -v a="$mean_a" -v b="$mean_b" -v lo="$lo" -v hi="$hi" \
      'BEGIN { d = a - b; if (d < 0) d = -d; exit !(d <= 1e-3 * (hi - lo) + 1e-6) }' ||
      fail "$b.ply: mean $c $mean_b, scene.ply $mean_a (extent $lo..$hi)"
  done
  echo "$b.ply: x/y/z means agree with scene.ply"
done
echo "PASS: splat-transform $VERSION read crpgs's .ply ($N Gaussians, SH degree 3) and converted it to .spz and .sog and back with $N Gaussians"
