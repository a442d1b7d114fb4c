#!/usr/bin/env bash
# The renderer build id follows the sources at build time, and a coordinator
# refuses a worker built from other sources:
#
# - a copy of the source tree, configured like this build (generator,
#   compilers, build type, flags) and built there (ptworker only), reports
#   this build's id: the id depends on what is built, not on where;
# - after a comment is appended to a file under common/, rebuilding the copy
#   in the same build folder, without re-running cmake by hand, changes the id;
# - this build's ptserve refuses the edited ptworker (exit 1, "build ... differs")
#   and then renders with this build's ptworker.
#
# Builds the renderer once more (a minute or two on 2 cores), so the
# sanitizer builds skip it (exit 77): it tests the build system, not the code.
# Environment (set by ctest): PT_BIN (the build's bin folder), PT_SOURCE_DIR;
# PT_BUILD_JOBS (default 2) parallel jobs for the copy's build.
set -euo pipefail

bin=${PT_BIN:?PT_BIN must name the build\'s bin folder}
src=${PT_SOURCE_DIR:?PT_SOURCE_DIR must name the source tree}
cache=$bin/../CMakeCache.txt
tmp=$(mktemp -d /tmp/pt_build_id_XXXXXX)
srv_pid=
wrk_pid=
failed=1
cleanup() {
  local p
  for p in $wrk_pid $srv_pid; do
    if kill "$p" 2>/dev/null; then
      wait "$p" 2>/dev/null || true
    fi
  done
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
say "building ptworker in a copy of the tree ($bt)"
cmake -S "$copy" -B "$copy/build" "${config[@]}" >"$tmp/configure.log" 2>&1 ||
  fail "configure of the copy: $(tail -n 20 "$tmp/configure.log")"
cmake --build "$copy/build" -j "$jobs" --target ptworker >"$tmp/build.log" 2>&1 ||
  fail "build of the copy: $(tail -n 30 "$tmp/build.log")"
copied=$(version_id "$copy/build/bin/ptworker")
[[ $copied == "$orig" ]] ||
  fail "the copy's id $copied is not this build's $orig (was this build made from other sources?)"

say "appending a comment to common/render/film.c and rebuilding"
echo "/* test_build_id: an edit that changes no code */" >>"$copy/common/render/film.c"
cmake --build "$copy/build" -j "$jobs" --target ptworker >"$tmp/rebuild.log" 2>&1 ||
  fail "rebuild of the copy: $(tail -n 30 "$tmp/rebuild.log")"
edited=$(version_id "$copy/build/bin/ptworker")
[[ $edited != "$orig" ]] || fail "the edited build kept the id $orig"
grep -q "film.c" "$tmp/rebuild.log" || fail "the rebuild did not recompile film.c"
say "ids: this build $orig, the edited copy $edited"

# This build's coordinator, one small job; workers come and go.
"$bin/ptserve" --listen 127.0.0.1:0 --port-file "$tmp/port" --res 16x16 --spp 4 --tile 16 \
  --chunk 4 -q -o "$tmp/out.exr" "$src/scenes/cornell_box.gltf" 2>"$tmp/serve.log" &
srv_pid=$!
for _ in $(seq 100); do
  [[ -s $tmp/port ]] && break
  sleep 0.05
done
[[ -s $tmp/port ]] || fail "ptserve did not start: $(cat "$tmp/serve.log")"
server=127.0.0.1:$(cat "$tmp/port")

rc=0
timeout 60 "$copy/build/bin/ptworker" --server "$server" --threads 1 --name edited \
  --cache-dir "$tmp/cache-edited" >"$tmp/edited.log" 2>&1 || rc=$?
[[ $rc == 1 ]] || fail "the edited worker exited $rc, wanted 1 (refused): $(cat "$tmp/edited.log")"
grep -q "refused.*build $edited differs.*$orig" "$tmp/edited.log" ||
  fail "the edited worker's log does not say its build was refused: $(cat "$tmp/edited.log")"
kill -0 "$srv_pid" 2>/dev/null || fail "ptserve ended after the refusal: $(cat "$tmp/serve.log")"

"$bin/ptworker" --server "$server" --threads 1 --name same --cache-dir "$tmp/cache-same" \
  >"$tmp/same.log" 2>&1 &
wrk_pid=$!
rc=0
for _ in $(seq 600); do
  kill -0 "$srv_pid" 2>/dev/null || break
  sleep 0.1
done
kill -0 "$srv_pid" 2>/dev/null && fail "ptserve still runs after 60 s: $(cat "$tmp/serve.log")"
wait "$srv_pid" || rc=$?
srv_pid=
[[ $rc == 0 ]] || fail "ptserve exited $rc with this build's worker: $(cat "$tmp/serve.log")"
[[ -s $tmp/out.exr ]] || fail "no image from the render"
grep -q "refused" "$tmp/same.log" && fail "this build's worker was refused: $(cat "$tmp/same.log")"

failed=0
echo "test_build_id: ok"
