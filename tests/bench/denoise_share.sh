#!/usr/bin/env bash
# A finished frame's denoising on the coordinator alone, and shared with the
# workers (ptserve --denoise-on-workers): the coordinator's CPU and the wall
# time from "denoising the image" to the job's end.
#
# Runs the real ptserve queue and N real ptworker processes on this machine,
# submits one --denoise job (the Cornell box), and while its finished frame
# is denoised reads the coordinator's CPU time (/proc/PID/stat) and the
# wall clock, from the first `ptctl status` that says "denoising the image"
# to the job's end. Three modes, alternating run by run:
#   alone    the coordinator denoises the frame (its writer thread);
#   shared   --denoise-on-workers: the workers take regions while the
#            coordinator denoises the rest (on one machine they share its
#            cores: the split, not the wall time, is the figure here);
#   workers  shared, the coordinator's own denoising held (the test hook
#            PTSERVE_TEST_DENOISE_GATE) until every region is back, as on a
#            farm whose workers are many: what the coordinator still spends
#            (hashing the crops, serving them, verifying each worker's first
#            region and --verify-fraction of the others).
# The images of every mode are compared with the first (ptexr-diff: the same
# bits). Medians over --runs. Not a pass/fail test. The queue's results log
# holds every result with its passes (about 400 bytes a pixel); --work on a
# tmpfs (/dev/shm) keeps the render from waiting on the disk.
#
#   tests/bench/denoise_share.sh [--bin DIR] [--workers N] [--threads T]
#       [--res WxH] [--spp N] [--region PIXELS] [--runs R] [--work DIR]
set -euo pipefail

bin=build/bin
workers=2
threads=1
res=1920x1080
spp=2
region=512
runs=3
work=
scene=scenes/cornell_box.gltf

# shellcheck source=tests/bench/lib_farm.sh
. "$(dirname "$0")/lib_farm.sh"
while (($#)); do
  case $1 in
  --bin) bin=$2; shift 2 ;;
  --workers) workers=$2; shift 2 ;;
  --threads) threads=$2; shift 2 ;;
  --res) res=$2; shift 2 ;;
  --spp) spp=$2; shift 2 ;;
  --region) region=$2; shift 2 ;;
  --runs) runs=$2; shift 2 ;;
  --work) work=$2; shift 2 ;;
  -h | --help) usage; exit 0 ;;
  --version) echo "denoise_share.sh (ptfarm bench)"; exit 0 ;;
  *) echo "denoise_share: unknown option $1 (--help)" >&2; exit 2 ;;
  esac
done
for p in ptserve ptctl ptworker ptexr-diff; do
  [[ -x $bin/$p ]] || { echo "denoise_share: no $bin/$p (build first; --bin DIR)" >&2; exit 2; }
done
[[ -r $scene ]] || { echo "denoise_share: run from the repository root ($scene)" >&2; exit 2; }
[[ -n $work ]] || work=$(mktemp -d "${TMPDIR:-/var/tmp}/denoise_share.XXXXXX")
mkdir -p "$work"
pids=()
cleanup() {
  local p
  for p in "${pids[@]}"; do kill "$p" 2> /dev/null || true; done
  wait 2> /dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT

now_ms() { echo $(($(date +%s%N) / 1000000)); }
# CPU seconds of process PID so far (user + system).
cpu_s() { awk -v hz="$(getconf CLK_TCK)" '{printf "%.2f", ($14 + $15) / hz}' "/proc/$1/stat"; }

# One run of MODE: prints "wall_s cpu_s" and leaves DIR/out.exr and DIR/serve.log.
run() {
  local mode=$1 dir=$2 t=0 sp ctl id t0 c0 msg state args=() envs=()
  mkdir -p "$dir"
  if [[ $mode != alone ]]; then args=(--denoise-on-workers --denoise-region "$region"); fi
  if [[ $mode == workers ]]; then envs=(PTSERVE_TEST_DENOISE_GATE="$dir/gate"); fi
  env ${envs[@]+"${envs[@]}"} "$bin/ptserve" --state-dir "$dir/state" --output-dir "$dir/out" \
    --listen 127.0.0.1:0 --port-file "$dir/port" ${args[@]+"${args[@]}"} 2> "$dir/serve.log" &
  sp=$!
  pids+=("$sp")
  while [[ ! -s $dir/port ]]; do
    sleep 0.05
    t=$((t + 1))
    ((t < 1200)) || { echo "denoise_share: ptserve did not start" >&2; return 1; }
  done
  ctl=("$bin/ptctl" --server "127.0.0.1:$(< "$dir/port")")
  for ((i = 0; i < workers; i++)); do
    "$bin/ptworker" --server "127.0.0.1:$(< "$dir/port")" --threads "$threads" --name "w$i" \
      --cache-dir "$dir/cache$i" 2> "$dir/w$i.log" &
    pids+=($!)
  done
  id=$("${ctl[@]}" submit "$scene" --res "$res" --spp "$spp" --seed 1 --denoise)
  t0=
  while :; do
    "${ctl[@]}" status "$id" --json > "$dir/status.json"
    state=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["state"])' "$dir/status.json")
    msg=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["message"])' "$dir/status.json")
    if [[ -z $t0 && $msg == "denoising the image"* ]]; then
      t0=$(now_ms)
      c0=$(cpu_s "$sp")
    fi
    if [[ $mode == workers && $msg == "denoising the image: 100 %" && ! -e $dir/gate ]]; then
      touch "$dir/gate"
    fi
    [[ $state == running || $state == queued ]] || break
    sleep 0.1
  done
  [[ $state == "done" && -n $t0 ]] || { echo "denoise_share: job $state, denoising not seen" >&2; return 1; }
  local wall cpu
  wall=$(awk -v a="$t0" -v b="$(now_ms)" 'BEGIN {printf "%.2f", (b - a) / 1000}')
  cpu=$(awk -v a="$c0" -v b="$(cpu_s "$sp")" 'BEGIN {printf "%.2f", b - a}')
  "${ctl[@]}" fetch "$id" -o "$dir/out.exr"
  kill "${pids[@]}" 2> /dev/null || true
  wait 2> /dev/null || true
  pids=()
  rm -rf "$dir/state" "$dir/out" # the results log: about 400 bytes a pixel with the passes
  echo "$wall $cpu"
}

echo "denoise share: ${res} at $spp spp, $workers workers x $threads threads, regions of $region"
modes=(alone shared workers)
for m in "${modes[@]}"; do : > "$work/$m"; done
ref=
for ((r = 1; r <= runs; r++)); do
  for m in "${modes[@]}"; do
    line=$(run "$m" "$work/$m$r")
    echo "  run $r $m: wall $(echo "$line" | cut -d' ' -f1) s, coordinator CPU $(echo "$line" | cut -d' ' -f2) s"
    split=$(grep -o "denoised in .*" "$work/$m$r/serve.log" | sed 's/\x1b\[K//g' || true)
    [[ -z $split ]] || echo "    $split"
    echo "$line" >> "$work/$m"
    if [[ -z $ref ]]; then
      ref=$work/ref.exr
      cp "$work/$m$r/out.exr" "$ref"
    elif ! "$bin/ptexr-diff" "$ref" "$work/$m$r/out.exr" > /dev/null; then
      echo "denoise_share: run $r $m: the image differs from run 1's" >&2
      exit 1
    fi
  done
done
for m in "${modes[@]}"; do
  echo "$m: wall $(cut -d' ' -f1 "$work/$m" | median) s, coordinator CPU $(cut -d' ' -f2 "$work/$m" | median) s (medians)"
done
