#!/usr/bin/env bash
# Builds ptfarm three times and runs the test suite on each build:
#   build/       Release, warnings as errors: the whole suite
#   build-asan/  AddressSanitizer + UndefinedBehaviorSanitizer (no recover),
#                with assert() on (NDEBUG undefined), clang when present:
#                the whole suite but the Blender add-on's tests (label
#                blender: Blender's Python against a ptserve whose queue and
#                HTTP code the other tests run in this build too) and the
#                dashboard in a browser (label browser: test_http sends its
#                requests with curl here)
#   build-tsan/  ThreadSanitizer (clang), assert() on: the tests labelled
#                "threads" (worker render threads, the coordinator's
#                upload-check and writer threads, the farm end to end),
#                and only what they run is built (target thread_tests)
# then, when clang is present, runs each libFuzzer target for a bounded time.
# Each build uses Ninja when it is installed. Before building it checks
# the sources: clang-format over the C and C++ files
# (tests/check_format.sh) and shellcheck over the scripts
# (tests/check_shell.sh); a failed check does not stop the builds and tests,
# but fails the run at the end. Prints the time of each step at the end and
# exits non-zero when any step failed. Environment:
#   PT_JOBS          parallel build jobs (default: number of cores)
#   PT_TEST_JOBS     tests run at once (default: PT_JOBS + 1)
#   PT_FUZZ_SECONDS  seconds per fuzzer (default 3; 0 skips fuzzing)
#   PT_SKIP_ASAN=1   skip the ASan + UBSan build (for quick local runs)
#   PT_SKIP_TSAN=1   skip the ThreadSanitizer build (for quick local runs)
set -euo pipefail
cd "$(dirname "$0")/.."
jobs=${PT_JOBS:-$(nproc)}
# One test more than cores: the farm's tests wait on sockets and child
# processes, which left 11 % of two cores idle at -j 2 (release suite: 384 s
# at -j 2, 347 s at -j 3, the same machine).
test_jobs=${PT_TEST_JOBS:-$((jobs + 1))}
fuzz_seconds=${PT_FUZZ_SECONDS:-3}

step_names=()
step_secs=()
step_name=""
step_start=$SECONDS
step_end() {
  if [[ -n $step_name ]]; then
    step_names+=("$step_name")
    step_secs+=($((SECONDS - step_start)))
  fi
  step_name=""
}
step() {
  step_end
  step_name="$*"
  step_start=$SECONDS
  printf '\n=== %s ===\n' "$*"
}
print_times() {
  step_end
  local i
  printf '\nstep times (%d s in all):\n' "$SECONDS"
  for i in "${!step_names[@]}"; do
    printf '  %5d s  %s\n' "${step_secs[$i]}" "${step_names[$i]}"
  done
}
# The times come at the end, also when a step fails.
trap print_times EXIT

# shellcheck source=tests/configure.sh
. tests/configure.sh

failed_checks=()
step "format check (clang-format)"
tests/check_format.sh || failed_checks+=("format check: tests/check_format.sh")
step "shell script check (shellcheck)"
tests/check_shell.sh || failed_checks+=("shell script check: tests/check_shell.sh")

step "release build"
pt_configure build -DCMAKE_BUILD_TYPE=Release -DPT_WERROR=ON
cmake --build build -j "$jobs"
step "tests (release)"
ctest --test-dir build --output-on-failure -j "$test_jobs"

if [[ "${PT_SKIP_ASAN:-0}" != 1 ]]; then
  step "sanitizer build (ASan + UBSan)"
  # clang where there is one (deploy/setup.sh installs it for TSan and the
  # fuzzers): GCC 12 took 111 s of CPU on the instrumented glTF importer
  # alone, clang 61, and the release build already compiles with GCC's
  # warnings as errors.
  asan_cc=()
  if command -v clang >/dev/null; then asan_cc=(-DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++); fi
  pt_configure build-asan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPT_SANITIZE=ON -DPT_WERROR=ON \
    "${asan_cc[@]}"
  cmake --build build-asan -j "$jobs"
  step "tests (sanitizers)"
  ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1 \
    ctest --test-dir build-asan -LE 'blender|browser' --output-on-failure -j "$test_jobs"
fi

# clang: GCC 12's ThreadSanitizer instruments the resolvers of target_clones
# functions (common/math/simd.h), which the loader runs before the TSan
# runtime exists, and every program crashes at start.
if [[ "${PT_SKIP_TSAN:-0}" != 1 ]]; then
  step "thread sanitizer build (TSan)"
  # Only what the tests labelled "threads" run (tests/CMakeLists.txt).
  CC=clang CXX=clang++ pt_configure build-tsan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPT_TSAN=ON \
    -DPT_WERROR=ON
  cmake --build build-tsan -j "$jobs" --target thread_tests
  step "tests (thread sanitizer, label threads)"
  TSAN_OPTIONS="halt_on_error=1:second_deadlock_stack=1:suppressions=$PWD/tests/tsan.supp" \
    ctest --test-dir build-tsan -L threads --output-on-failure -j "$test_jobs"
fi

if [[ "$fuzz_seconds" != 0 && -x tests/fuzz/run_fuzzers.sh ]] && command -v clang >/dev/null; then
  step "fuzzers (${fuzz_seconds}s each)"
  tests/fuzz/run_fuzzers.sh "$fuzz_seconds"
fi
if ((${#failed_checks[@]})); then
  printf '\n=== FAILED: %s ===\n' "${failed_checks[@]}"
  exit 1
fi
step "all tests passed"
