#!/usr/bin/env bash
# `--version` of every program: one line "PROG VERSION (build ID)" on stdout,
# exit 0, nothing on stderr; VERSION is the project's (CMakeLists.txt), ID is
# 16 hex digits and the same in every program of one build (deployment
# scripts compare it across hosts). Each program's --help mentions --version.
# A stdout that cannot be written is an error (exit 1), not a silent success.
# Environment (set by ctest): PT_BIN (the build's bin folder), PT_SOURCE_DIR.
set -euo pipefail

bin=${PT_BIN:?PT_BIN must name the build\'s bin folder}
src=${PT_SOURCE_DIR:?PT_SOURCE_DIR must name the source tree}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

failures=0
fail() {
  echo "FAIL: $*" >&2
  failures=$((failures + 1))
}

version=$(sed -n 's/^project(ptfarm VERSION \([0-9.]*\).*/\1/p' "$src/CMakeLists.txt")
[[ -n $version ]] || fail "no project version in $src/CMakeLists.txt"

ids=()
for prog in ptserve ptworker ptctl ptdenoise ptbench ptbench-throughput ptbench-merge ptexr-diff; do
  if [[ ! -x $bin/$prog ]]; then
    fail "$bin/$prog missing"
    continue
  fi
  rc=0
  "$bin/$prog" --version >"$tmp/out" 2>"$tmp/err" || rc=$?
  [[ $rc == 0 ]] || fail "$prog --version exited $rc: $(head -c 300 "$tmp/err")"
  [[ -s $tmp/err ]] && fail "$prog --version wrote to stderr: $(head -c 300 "$tmp/err")"
  [[ $(wc -l <"$tmp/out") == 1 ]] || fail "$prog --version printed $(wc -l <"$tmp/out") lines"
  line=$(head -n 1 "$tmp/out")
  re="^$prog ${version//./\\.} \\(build ([0-9a-f]{16})\\)\$"
  if [[ $line =~ $re ]]; then
    ids+=("${BASH_REMATCH[1]}")
  else
    fail "$prog --version: '$line' is not '$prog $version (build <16 hex digits>)'"
  fi
  # --help goes to stdout or (ptexr-diff) stderr; either way it names --version.
  "$bin/$prog" --help >"$tmp/help" 2>&1 || true
  grep -qF -- --version "$tmp/help" || fail "$prog --help does not mention --version"
done

if ((${#ids[@]})); then
  distinct=$(printf '%s\n' "${ids[@]}" | sort -u | wc -l)
  [[ $distinct == 1 ]] || fail "the programs of one build report different ids: ${ids[*]}"
fi

if [[ -w /dev/full ]]; then
  rc=0
  "$bin/ptworker" --version >/dev/full 2>"$tmp/err" || rc=$?
  [[ $rc == 1 ]] || fail "ptworker --version >/dev/full exited $rc, wanted 1"
fi

if ((failures)); then
  echo "test_version: $failures failures" >&2
  exit 1
fi
echo "test_version: ok (${ids[0]})"
