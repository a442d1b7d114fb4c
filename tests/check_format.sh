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

# Batches of files per clang-format process, two processes per core: one
# process per file spent most of the check starting processes.
jobs=$(nproc)
rc=0
out=$(printf '%s\0' "${files[@]}" |
  xargs -0 -n 16 -P "$((2 * jobs))" clang-format --dry-run --Werror -- 2>&1) || rc=$?
[[ ${PT_FORMAT_VERBOSE:-0} == 1 && -n $out ]] && printf '%s\n' "$out" >&2
# Diagnostics start "FILE:LINE:COL: error:"; each bad file once.
mapfile -t bad < <(printf '%s\n' "$out" | sed -n 's/^\(.*\):[0-9]*:[0-9]*: error:.*/\1/p' | sort -u)
if ((rc != 0 && ${#bad[@]} == 0)); then
  printf 'check_format: clang-format failed:\n%s\n' "$out" >&2
  exit 1
fi
if ((${#bad[@]})); then
  echo "check_format: ${#bad[@]} of ${#files[@]} files do not follow .clang-format" \
    "($(clang-format --version | head -n 1)):" >&2
  printf '  %s\n' "${bad[@]}" >&2
  exit 1
fi
echo "check_format: ${#files[@]} files follow .clang-format"
