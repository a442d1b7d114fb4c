#!/usr/bin/env bash
# Builds ptfarm twice and runs the whole test suite on both builds:
#   build/       Release, warnings as errors
#   build-asan/  AddressSanitizer + UndefinedBehaviorSanitizer (no recover),
#                with assert() on (NDEBUG undefined)
# then, when clang is present, runs each libFuzzer target for a bounded time.
# Exits non-zero when any step fails. Environment:
#   PT_JOBS          parallel build jobs (default: number of cores)
#   PT_FUZZ_SECONDS  seconds per fuzzer (default 20; 0 skips fuzzing)
#   PT_SKIP_ASAN=1   skip the sanitizer build (for quick local runs)
set -euo pipefail
cd "$(dirname "$0")/.."
jobs=${PT_JOBS:-$(nproc)}
fuzz_seconds=${PT_FUZZ_SECONDS:-20}

step() { printf '\n=== %s ===\n' "$*"; }

step "release build"
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DPT_WERROR=ON >/dev/null
cmake --build build -j "$jobs"
step "tests (release)"
ctest --test-dir build --output-on-failure -j "$jobs"

if [[ "${PT_SKIP_ASAN:-0}" != 1 ]]; then
  step "sanitizer build (ASan + UBSan)"
  cmake -S . -B build-asan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPT_SANITIZE=ON -DPT_WERROR=ON >/dev/null
  cmake --build build-asan -j "$jobs"
  step "tests (sanitizers)"
  ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1 \
    ctest --test-dir build-asan --output-on-failure -j "$jobs"
fi

if [[ "$fuzz_seconds" != 0 && -x tests/fuzz/run_fuzzers.sh ]] && command -v clang >/dev/null; then
  step "fuzzers (${fuzz_seconds}s each)"
  tests/fuzz/run_fuzzers.sh "$fuzz_seconds"
fi
step "all tests passed"
