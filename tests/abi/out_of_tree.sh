#!/usr/bin/env bash
# Installs the SDK into a temporary prefix, builds examples/ against the INSTALLED package
# (find_package(crpgs)), and loads the example plugins with the installed crpgs.
# Usage: out_of_tree.sh BUILD_DIR SOURCE_DIR
set -euo pipefail
build=$1 src=$2
work=$build/test_tmp/out_of_tree
rm -rf "$work" && mkdir -p "$work"
cmake --install "$build" --prefix "$work/prefix" >/dev/null
cmake -S "$src/examples" -B "$work/build" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_PREFIX_PATH="$work/prefix" >"$work/configure.log" || { cat "$work/configure.log"; exit 1; }
cmake --build "$work/build" -j 2 >"$work/build.log" || { cat "$work/build.log"; exit 1; }
crpgs="$work/prefix/bin/crpgs"
out=$(env -u CRPGS_PLUGIN_PATH "$crpgs" --plugin-dir "$work/build/plugins" plugins)
echo "$out"
fail() { echo "FAIL: $*"; exit 1; }
grep -Eq '^features +gain +1\.0 +org\.example\.features\.gain' <<<"$out" || fail "gain not listed"
grep -Eq '^entropy +laplace +1\.0' <<<"$out" || fail "laplace not listed"
# The installed tool also finds the installed in-tree plugins (exe-relative plugin dir).
grep -Eq "^entropy +gaussian .*$work/prefix/lib/crpgs/plugins" <<<"$out" || fail "installed plugins not found"
desc=$("$crpgs" --plugin-dir "$work/build/plugins" plugins describe gain)
grep -q 'initial value of every channel gain' <<<"$desc" || fail "describe gain"
if err=$("$crpgs" --plugin-dir "$work/build/plugins" plugins describe gian 2>&1); then
  fail "describe of an unknown type succeeded"
fi
grep -q "no component of type 'gian', did you mean 'gain'?" <<<"$err" || fail "bad message: $err"
printf 'features:\n  type: gain\n  init: 2.5\n' >"$work/cfg.yaml"
# Capture first: with pipefail, `grep -q` closing the pipe early would fail the writer (SIGPIPE).
checked=$("$crpgs" --plugin-dir "$work/build/plugins" config check "$work/cfg.yaml")
grep -q 'init: 2.5' <<<"$checked" || fail "config with the example plugin"
printf 'features:\n  type: gain\n  init: -1\n' >"$work/bad.yaml"
if err=$("$crpgs" --plugin-dir "$work/build/plugins" config check "$work/bad.yaml" 2>&1); then
  fail "out-of-range value accepted"
fi
grep -q "bad.yaml:3:9: features.init: '-1' is out of range" <<<"$err" || fail "bad message: $err"
echo "out-of-tree plugin check: ok"
