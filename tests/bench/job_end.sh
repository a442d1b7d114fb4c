#!/usr/bin/env bash
# Job ends in queue mode: how long the coordinator stops serving at each.
#
# Runs the real ptserve (--state-dir on the disk of --work, as in
# production) against N ptworker-null processes paced as real cores
# (tests/bench/null_render.c, PTWORKER_NULL_RATE), submits K jobs at once,
# and while they render asks `ptctl status` every 20 ms, timing each reply
# from the client's side. A loop that waits on anything (a job's final image
# written, a film freed) answers late, and every worker waits with it: the
# longest reply is the loop's longest stall. Also reported: the wall seconds
# from the first submit to the last job's end, and what that is per job.
# Reported per run, then as medians over --runs. Not a pass/fail test.
#
# The last line reads `longest status reply: X ms (median Y ms); K jobs in
# Z s` (medians), for scripts.
#
#   tests/bench/job_end.sh [--bin DIR] [--workers N] [--threads T]
#       [--res WxH] [--spp N] [--jobs K] [--runs R] [--pace R] [--work DIR]
set -euo pipefail

bin=build/bin
workers=16
threads=8
res=2048x2048
spp=64
jobs=4
runs=3
pace=1.35e6
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
  --jobs) jobs=$2; shift 2 ;;
  --runs) runs=$2; shift 2 ;;
  --pace) pace=$2; shift 2 ;;
  --work) work=$2; shift 2 ;;
  -h | --help) usage; exit 0 ;;
  --version) echo "job_end.sh (ptfarm bench)"; exit 0 ;;
  *) echo "job_end: unknown option $1 (--help)" >&2; exit 2 ;;
  esac
done
for p in ptserve ptctl ptworker-null; do
  [[ -x $bin/$p ]] || { echo "job_end: no $bin/$p (build first; --bin DIR)" >&2; exit 2; }
done
[[ -r $scene ]] || { echo "job_end: run from the repository root ($scene)" >&2; exit 2; }
[[ -n $work ]] || work=$(mktemp -d "${TMPDIR:-/var/tmp}/job_end.XXXXXX")
mkdir -p "$work"
pids=() wpids=()
cleanup() {
  local p
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT

now_ms() { echo $(($(date +%s%N) / 1000000)); }

# One run: prints "longest_ms median_ms wall_s".
run() {
  local dir=$1 i t=0 ids=() ctl sp
  mkdir -p "$dir"
  "$bin/ptserve" --state-dir "$dir/state" --output-dir "$dir/out" --listen 127.0.0.1:0 \
    --port-file "$dir/port" 2> "$dir/serve.log" &
  sp=$!
  pids+=("$sp")
  while [[ ! -s $dir/port ]]; do
    sleep 0.05
    t=$((t + 1))
    ((t < 1200)) || { echo "job_end: ptserve did not start" >&2; return 1; }
  done
  ctl=("$bin/ptctl" --server "127.0.0.1:$(< "$dir/port")")
  start_workers "$(< "$dir/port")" "$dir"
  wait_joined "$dir/serve.log" || { echo "job_end: workers did not join" >&2; return 1; }
  local t0 t1 a b last
  t0=$(now_ms)
  for ((i = 0; i < jobs; i++)); do
    ids+=("$("${ctl[@]}" submit "$scene" --res "$res" --spp "$spp" --seed "$i")")
  done
  last=${ids[$((jobs - 1))]}
  : > "$dir/replies"
  while :; do
    a=$(now_ms)
    "${ctl[@]}" status "${ids[0]}" > /dev/null
    b=$(now_ms)
    echo $((b - a)) >> "$dir/replies"
    grep -Eq "job $last (done|failed|cancelled)" "$dir/serve.log" && break
    sleep 0.02
  done
  t1=$(now_ms)
  grep -q "job $last done" "$dir/serve.log" || { echo "job_end: job $last did not finish" >&2; return 1; }
  kill "${pids[@]}" 2>/dev/null || true
  wait 2>/dev/null || true
  pids=() wpids=()
  echo "$(sort -g "$dir/replies" | tail -n 1) $(median < "$dir/replies") $(awk -v a="$t0" -v b="$t1" 'BEGIN {printf "%.2f", (b - a) / 1000}')"
}

echo "job end: $jobs jobs of ${res} at $spp spp, $workers null workers x $threads threads (pace $pace)"
: > "$work/runs"
for ((r = 1; r <= runs; r++)); do
  line=$(run "$work/run$r")
  echo "  run $r: longest reply $(echo "$line" | cut -d' ' -f1) ms, median $(echo "$line" | cut -d' ' -f2) ms, wall $(echo "$line" | cut -d' ' -f3) s"
  echo "$line" >> "$work/runs"
done
longest=$(cut -d' ' -f1 "$work/runs" | median)
med=$(cut -d' ' -f2 "$work/runs" | median)
wall=$(cut -d' ' -f3 "$work/runs" | median)
echo "longest status reply: $longest ms (median $med ms); $jobs jobs in $wall s"
