#!/usr/bin/env bash
# Checks that every C and C++ file under version control follows .clang-format
# (clang-format --dry-run --Werror). Prints the files that do not and exits 1;
# `clang-format -i FILE` formats one. PT_FORMAT_VERBOSE=1 also prints
# clang-format's diagnostics. Needs clang-format (deploy/setup.sh installs it)
# and git; works from any folder.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! command -v clang-format >/dev/null; then
  echo "check_format: clang-format is not installed (Debian: clang-format)" >&2
  exit 1
fi
files=()
while IFS= read -r -d '' f; do
  [[ -f $f ]] && files+=("$f") # a file deleted in the work tree is not checked
done < <(git ls-files -z -- '*.c' '*.h' '*.cpp')
if ((${#files[@]} == 0)); then
  echo "check_format: no C or C++ files found (not a git checkout?)" >&2
  exit 1
fi

bad=()
for f in "${files[@]}"; do
  if ! out=$(clang-format --dry-run --Werror -- "$f" 2>&1); then
    bad+=("$f")
    [[ ${PT_FORMAT_VERBOSE:-0} == 1 ]] && printf '%s\n' "$out" >&2
  fi
done
if ((${#bad[@]})); then
  echo "check_format: ${#bad[@]} of ${#files[@]} files do not follow .clang-format" \
    "($(clang-format --version | head -n 1)):" >&2
  printf '  %s\n' "${bad[@]}" >&2
  exit 1
fi
echo "check_format: ${#files[@]} files follow .clang-format"
