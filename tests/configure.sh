# shellcheck shell=bash
# configure.sh - pt_configure DIR CMAKE-ARGS...: cmake -S . -B DIR with the
# generator and linker tests/run.sh and tests/fuzz/run_fuzzers.sh build with.
# Ninja where there is one (deploy/setup.sh installs it): make's per-target
# dependency steps took a quarter of each build (the release build 129 s
# with make, 96 s with Ninja, 2 cores). A folder configured before keeps its
# generator, which cmake cannot change. lld where there is one (setup
# installs it too): the builds link about a hundred programs, each against
# the same static libraries, and lld links them two to three times faster
# than the system's ld (an ASan ptworker 0.35 s of CPU against 0.9 s).
pt_configure() {
  local dir=$1 gen=() link=()
  shift
  if [[ ! -f $dir/CMakeCache.txt ]] && command -v ninja >/dev/null; then gen=(-G Ninja); fi
  if command -v ld.lld >/dev/null; then link=(-DCMAKE_EXE_LINKER_FLAGS=-fuse-ld=lld); fi
  cmake -S . -B "$dir" "${gen[@]}" "${link[@]}" "$@" >/dev/null
}
