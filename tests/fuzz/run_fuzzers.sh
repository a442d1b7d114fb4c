#!/usr/bin/env bash
# Builds (when needed) and runs each libFuzzer target for a bounded time:
#   tests/fuzz/run_fuzzers.sh SECONDS [TARGET...]
# Targets: fuzz_frame and fuzz_msg (the protocol), fuzz_gltf (the glTF
# loader), fuzz_bundle (scene bundles), fuzz_queue, fuzz_checkpoint and
# fuzz_results_log (the state folder's files), fuzz_exr (the OpenEXR reader),
# fuzz_envmap (the environment map's Radiance decoder and sampler),
# fuzz_draco (KHR_draco_mesh_compression's mesh decoder), fuzz_webp
# (EXT_texture_webp's image decoder), fuzz_meshopt (EXT_meshopt_compression's
# buffer view decoder), fuzz_camera_look (a job's camera placement text);
# all of them by default.
# Build: build-fuzz/ (Debug, clang, -DPT_FUZZ=ON), or $PT_FUZZ_BUILD.
# Each target starts from its committed seeds (tests/fuzz/corpus/<target>;
# fuzz_gltf also from scenes/), with tests/fuzz/<target>.dict when there is
# one, and writes what it discovers to <build>/fuzz-corpus/<target>, never to
# the source tree; a crash is saved as <build>/fuzz-artifacts/<target>-crash-*
# and fails the script. To keep a crash as a regression seed, copy it into
# tests/fuzz/corpus/<target>/ once fixed.
# Environment: PT_JOBS (build jobs and fuzzers run at once, default nproc), PT_FUZZ_MAX_LEN (default 16384: room for a HEARTBEAT past its cap).
set -euo pipefail
cd "$(dirname "$0")/../.."
seconds=${1:?usage: run_fuzzers.sh SECONDS [TARGET...]}
shift
targets=("$@")
[[ ${#targets[@]} -gt 0 ]] ||
  targets=(fuzz_frame fuzz_msg fuzz_gltf fuzz_bundle fuzz_queue fuzz_checkpoint fuzz_results_log
    fuzz_exr fuzz_envmap fuzz_draco fuzz_webp fuzz_meshopt fuzz_camera_look fuzz_manifest
    fuzz_guide fuzz_guide_pack)
build=${PT_FUZZ_BUILD:-build-fuzz}
jobs=${PT_JOBS:-$(nproc)}
max_len=${PT_FUZZ_MAX_LEN:-16384}

command -v clang >/dev/null || { echo "run_fuzzers.sh: clang not found" >&2; exit 1; }
if [[ ! -f "$build/CMakeCache.txt" ]]; then
  # shellcheck source=tests/configure.sh
  . tests/configure.sh
  pt_configure "$build" -DCMAKE_BUILD_TYPE=Debug -DPT_FUZZ=ON \
    -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++
fi
cmake --build "$build" -j "$jobs" --target "${targets[@]}"

mkdir -p "$build/fuzz-artifacts" "$build/fuzz-logs"
# One fuzzer per job, PT_JOBS at a time: each still gets SECONDS of its own
# core, and the run takes SECONDS x targets / jobs. Each one's output goes to
# its log, printed when it ends, so the outputs do not interleave.
run_one() {
  local t=$1
  mkdir -p "$build/fuzz-corpus/$t"
  local extra=() seeds=("tests/fuzz/corpus/$t")
  [[ -f tests/fuzz/$t.dict ]] && extra+=("-dict=tests/fuzz/$t.dict")
  [[ $t == fuzz_gltf ]] && seeds+=(scenes)
  ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1 \
    "$build/bin/$t" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 \
    -max_len="$max_len" -print_final_stats=1 "${extra[@]}" \
    -artifact_prefix="$build/fuzz-artifacts/$t-" \
    "$build/fuzz-corpus/$t" "${seeds[@]}"
}
status=0
pids=()
names=()
# Waits for the oldest running fuzzer and reports it.
reap() {
  local t=${names[0]} rc=0
  wait "${pids[0]}" || rc=$?
  echo "== $t: ${seconds}s"
  cat "$build/fuzz-logs/$t.log"
  if ((rc != 0)); then
    echo "== $t: FAILED (see $build/fuzz-artifacts/)" >&2
    status=1
  fi
  pids=("${pids[@]:1}")
  names=("${names[@]:1}")
}
for t in "${targets[@]}"; do
  ((${#pids[@]} < jobs)) || reap
  run_one "$t" >"$build/fuzz-logs/$t.log" 2>&1 &
  pids+=($!)
  names+=("$t")
done
while ((${#pids[@]} > 0)); do reap; done
exit $status
