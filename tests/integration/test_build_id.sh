#!/usr/bin/env bash
# The renderer build id follows the sources at build time:
#
# - this build's programs report the id its build wrote
#   (generated/build_id.c, compiled into libptbase);
# - a copy of the source tree, configured like this build (generator,
#   compilers, build type, flags) and built there, writes this build's id:
#   the id depends on what is built, not on where;
# - after a comment is appended to a file under common/, rebuilding the copy
#   in the same build folder, without re-running cmake by hand, writes
#   another id and compiles it into the copy's libptbase.
#
# The copy builds libptbase only (the id's C file is one of its sources), not
# a whole ptworker: that took 1.5 to 4 minutes of CI on 2 cores. That a
# coordinator refuses a worker whose id differs from its own, and goes on
# serving, is tests/server/test_loop.c's refused peer (a HELLO with another
# build). The sanitizer builds skip this test (exit 77): it tests the build
# system, not the code.
# Environment (set by ctest): PT_BIN (the build's bin folder), PT_SOURCE_DIR;
# PT_BUILD_JOBS (default 2) parallel jobs for the copy's build.
set -euo pipefail

bin=${PT_BIN:?PT_BIN must name the build\'s bin folder}
src=${PT_SOURCE_DIR:?PT_SOURCE_DIR must name the source tree}
cache=$bin/../CMakeCache.txt
tmp=$(mktemp -d /tmp/pt_build_id_XXXXXX)
failed=1
cleanup() {
  if [[ $failed == 0 ]]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}
trap cleanup EXIT
fail() {
  echo "FAIL: $*" >&2
  exit 1
}
say() { printf '[%3ds] %s\n' "$SECONDS" "$*"; }

[[ -f $cache ]] || fail "no CMakeCache.txt beside $bin"
cached() { sed -n "s/^$1:[A-Z]*=//p" "$cache" | head -n 1; }
if [[ $(cached PT_SANITIZE) == ON || $(cached PT_TSAN) == ON ]]; then
  echo "SKIP: a sanitizer build; the release build runs this test"
  failed=0
  exit 77
fi

# version_id PROGRAM: the build id from PROGRAM --version.
version_id() {
  local line re='\(build ([0-9a-f]{16})\)$'
  line=$("$1" --version) || fail "$1 --version failed"
  [[ $line =~ $re ]] || fail "$1 --version: '$line' has no build id"
  echo "${BASH_REMATCH[1]}"
}
orig=$(version_id "$bin/ptserve")
[[ $(version_id "$bin/ptworker") == "$orig" ]] || fail "ptserve and ptworker of one build differ"

# The sources as git sees them (tracked and untracked, not ignored: no build
# folders), else everything but build folders.
copy=$tmp/src
mkdir -p "$copy"
if git -C "$src" rev-parse --git-dir >/dev/null 2>&1; then
  (cd "$src" && git ls-files -z --cached --others --exclude-standard |
    tar --null --ignore-failed-read -T - -cf -) | tar -xf - -C "$copy"
else
  (cd "$src" && tar --exclude='./build*' --exclude=./.git -cf - .) | tar -xf - -C "$copy"
fi

bt=$(cached CMAKE_BUILD_TYPE)
BT=${bt^^}
config=(-G "$(cached CMAKE_GENERATOR)" -DCMAKE_BUILD_TYPE="$bt" -DBUILD_TESTING=OFF
  -DCMAKE_C_COMPILER="$(cached CMAKE_C_COMPILER)" -DCMAKE_CXX_COMPILER="$(cached CMAKE_CXX_COMPILER)"
  -DCMAKE_C_FLAGS="$(cached CMAKE_C_FLAGS)" -DCMAKE_CXX_FLAGS="$(cached CMAKE_CXX_FLAGS)"
  "-DCMAKE_C_FLAGS_$BT=$(cached "CMAKE_C_FLAGS_$BT")"
  "-DCMAKE_CXX_FLAGS_$BT=$(cached "CMAKE_CXX_FLAGS_$BT")")
jobs=${PT_BUILD_JOBS:-2}
# file_id FILE: the id a generated build_id.c holds.
file_id() {
  local re='return "([0-9a-f]{16})";'
  [[ -f $1 ]] || fail "no $1"
  [[ $(cat "$1") =~ $re ]] || fail "$1 holds no build id"
  echo "${BASH_REMATCH[1]}"
}
[[ $(file_id "$bin/../generated/build_id.c") == "$orig" ]] ||
  fail "the programs' id $orig is not the one this build wrote"

say "building libptbase in a copy of the tree ($bt)"
cmake -S "$copy" -B "$copy/build" "${config[@]}" >"$tmp/configure.log" 2>&1 ||
  fail "configure of the copy: $(tail -n 20 "$tmp/configure.log")"
cmake --build "$copy/build" -j "$jobs" --target ptbase >"$tmp/build.log" 2>&1 ||
  fail "build of the copy: $(tail -n 30 "$tmp/build.log")"
copied=$(file_id "$copy/build/generated/build_id.c")
[[ $copied == "$orig" ]] ||
  fail "the copy's id $copied is not this build's $orig (was this build made from other sources?)"
lib=$copy/build/common/libptbase.a
grep -qa "$orig" "$lib" || fail "the copy's $lib does not hold its id $orig"

say "appending a comment to common/render/film.c and rebuilding"
echo "/* test_build_id: an edit that changes no code */" >>"$copy/common/render/film.c"
cmake --build "$copy/build" -j "$jobs" --target ptbase >"$tmp/rebuild.log" 2>&1 ||
  fail "rebuild of the copy: $(tail -n 30 "$tmp/rebuild.log")"
edited=$(file_id "$copy/build/generated/build_id.c")
[[ $edited != "$orig" ]] || fail "the edited build kept the id $orig"
grep -qa "$edited" "$lib" || fail "the rebuilt $lib does not hold the new id $edited"
grep -qa "$orig" "$lib" && fail "the rebuilt $lib still holds the old id $orig"
say "ids: this build $orig, the edited copy $edited"

failed=0
echo "test_build_id: ok"
