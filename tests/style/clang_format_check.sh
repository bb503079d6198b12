#!/bin/bash
# Checks that every C++/CUDA source of the project follows .clang-format (clang-format 14,
# Debian's `clang-format`, installed by scripts/setup). Skips (exit 77, a visible SKIP line)
# when clang-format is absent. Lists each file that differs and how to fix it.
# Usage: clang_format_check.sh SOURCE_DIR
set -u
SRC=$1
command -v clang-format > /dev/null 2>&1 || {
  echo "SKIP: clang-format not found (Debian package clang-format; scripts/setup installs it)"
  exit 77
}
cd "$SRC" || exit 1
dirs=(sdk plugins apps tests bench tools examples)
if git rev-parse --is-inside-work-tree > /dev/null 2>&1; then
  mapfile -t files < <(git ls-files -- "${dirs[@]}" | grep -E '\.(cpp|h|cu|cuh)$')
else  # a source tarball: every such file under the source directories
  mapfile -t files < <(find "${dirs[@]}" -type f \( -name '*.cpp' -o -name '*.h' -o -name '*.cu' -o -name '*.cuh' \) 2> /dev/null | sort)
fi
[ ${#files[@]} -gt 0 ] || { echo "FAIL: no C++ sources found under $SRC"; exit 1; }
bad=()
for f in "${files[@]}"; do
  [ -f "$f" ] || continue  # deleted in the work tree, not yet in the index
  clang-format --dry-run -Werror "$f" > /dev/null 2>&1 || bad+=("$f")
done
echo "$(clang-format --version | head -1): ${#files[@]} files checked, ${#bad[@]} not formatted"
if [ ${#bad[@]} -gt 0 ]; then
  printf '  %s\n' "${bad[@]}"
  echo "fix: clang-format -i ${bad[*]}"
  exit 1
fi
