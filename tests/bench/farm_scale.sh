#!/usr/bin/env bash
# Farm scale: how many worker cores one coordinator's event loop can feed.
#
# Runs the real ptserve, in one-job mode and in queue mode (--state-dir on
# the disk this script's --work folder is on, jobs submitted with ptctl),
# against N ptworker-null processes: the worker's own code with the renderer
# replaced by a fill (tests/bench/null_render.c), so the coordinator sees
# everything a farm sends it (handshakes, scene fetches, heartbeats, RESULT
# frames of the real size) except the rendering time. Each null render
# thread sleeps as long as a real core would take over its task
# (--pace, samples/s; 0: no sleep), so a coordinator that sizes tasks by the
# rates it observes sizes them as for real cores, and the machine's processors
# are left to ptserve and the workers' protocol work.
#
# Measured per run, from the kernel: the event loop's CPU time (ptserve's
# main thread, /proc/PID/task/PID/schedstat: user and system, nanoseconds),
# from just before the job starts (one-job mode: ptserve's start; queue mode:
# the submit) to its end; RESULT frames (the workers' task counts, each
# verification copy included); samples merged; bytes on the coordinator's
# sockets (one-job: ptserve's wire line; queue: the kernel's counters of the
# workers' connections, ss -ti). CPU time, not wall time: the machine may be
# shared. Reported per mode as medians over --runs:
#   loop us/result   loop CPU per RESULT frame
#   io us/result     CPU of the I/O threads (ptserve --io-threads, threads
#                    named pt-io: receiving, checksums, decoding) per RESULT
#                    frame, all of them together
#   merge us/result  CPU of the merge threads (ptserve --merge-threads,
#                    threads named pt-merge: the film adds) per RESULT
#                    frame, all of them together; both kinds run beside the
#                    loop, so their time spreads over their number of cores
#   results/s        RESULT frames per second of the job's wall time
#   bytes/sample     coordinator socket bytes (in + out) per sample merged
#   MB/Mpixel        ptserve's peak resident memory (VmHWM) per megapixel of
#                    the job (its base of a few MB included)
#   cores fed        samples one loop core merges per second (samples / loop
#                    CPU seconds) over one real core's rate (--core-rate:
#                    samples/s of one Cornell-box core; 'measure' times the real
#                    ptworker --threads 1 on it here, in CPU time)
# --curve repeats both modes at each chunk size (16 ... 1024 samples per
# task, --spp raised to twice the chunk where it is smaller), unpaced unless
# --pace is given: with a fixed chunk the pace changes only how busy the
# loop is, not the tasks.
#
# The default job is the issue's farm: 2048x2048, tile 32, 16 workers, at
# 1,024 samples per pixel (a final render; with tasks sized by time a tile's
# tasks grow from 16 samples, so a short job is mostly small tasks and feeds
# fewer cores per loop core than a long one). The coordinator's own defaults
# size the tasks unless --chunk is given.
#
# The last line reads `cores fed per loop core: one-job N, queue M` (medians),
# for scripts. Not a pass/fail test.
#
#   tests/bench/farm_scale.sh [--bin DIR] [--workers N] [--threads T]
#       [--res WxH] [--tile N] [--chunk N] [--spp N] [--runs R] [--pace R]
#       [--core-rate R|measure] [--modes one-job,queue] [--curve [LIST]]
#       [--serve-args 'ARGS'] [--work DIR] [--keep]
# --serve-args adds options to every ptserve (e.g. '--io-threads 0
# --merge-threads 0': the loop alone, as before those threads).
set -euo pipefail

bin=build/bin
workers=16
threads=8
res=2048x2048
tile=32
chunk=      # empty: the coordinator's default
spp=1024
runs=3
pace=      # empty: 1.35e6, or 0 with --curve
core_rate=1.35e6
modes=one-job,queue
curve=
curve_list="16 32 64 128 256 512 1024"
work=
keep=0
scene=scenes/cornell_box.gltf
serve_args=()

# shellcheck source=tests/bench/lib_farm.sh
. "$(dirname "$0")/lib_farm.sh"
while (($#)); do
  case $1 in
  --bin) bin=$2; shift 2 ;;
  --workers) workers=$2; shift 2 ;;
  --threads) threads=$2; shift 2 ;;
  --res) res=$2; shift 2 ;;
  --tile) tile=$2; shift 2 ;;
  --chunk) chunk=$2; shift 2 ;;
  --spp) spp=$2; shift 2 ;;
  --runs) runs=$2; shift 2 ;;
  --pace) pace=$2; shift 2 ;;
  --core-rate) core_rate=$2; shift 2 ;;
  --modes) modes=$2; shift 2 ;;
  --curve)
    curve=1
    if [[ ${2:-} =~ ^[0-9][0-9,\ ]*$ ]]; then curve_list=${2//,/ }; shift; fi
    shift ;;
  --work) work=$2; shift 2 ;;
  --serve-args) read -r -a serve_args <<< "$2"; shift 2 ;;
  --keep) keep=1; shift ;;
  -h | --help) usage; exit 0 ;;
  *) echo "farm_scale: unknown option $1 (--help)" >&2; exit 2 ;;
  esac
done
# Fixed chunks leave the coordinator nothing to size from the rates, so the
# curve runs unpaced (faster) unless told otherwise.
[[ -n $pace ]] || { [[ -n $curve ]] && pace=0 || pace=1.35e6; }
for p in ptserve ptctl ptworker ptworker-null; do
  [[ -x $bin/$p ]] || { echo "farm_scale: no $bin/$p (build first; --bin DIR)" >&2; exit 2; }
done
[[ -r $scene ]] || { echo "farm_scale: run from the repository root ($scene)" >&2; exit 2; }

if [[ -z $work ]]; then
  # The state folder must be on a real disk, as in production (not /dev/shm).
  work=$(mktemp -d "${TMPDIR:-/var/tmp}/farm_scale.XXXXXX")
fi
mkdir -p "$work"
pids=()
cleanup() {
  local p
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  ((keep)) || rm -rf "$work"
}
trap cleanup EXIT


# The loop thread's CPU time in ns (schedstat; stat's clock ticks when the
# kernel keeps no schedstat).
loop_ns() {
  local pid=$1 ns rest
  if read -r ns rest < "/proc/$pid/task/$pid/schedstat" 2>/dev/null && ((ns > 0)); then
    echo "$ns"
    return
  fi
  read -r rest < "/proc/$pid/task/$pid/stat" || return 1
  rest=${rest##*) }
  # shellcheck disable=SC2086 # fields of stat, split on purpose
  set -- $rest
  echo $((( ${12} + ${13}) * 1000000000 / $(getconf CLK_TCK)))
}

# CPU time in ns of ptserve's threads named $2 (pt-merge: the film adds;
# pt-io: the workers' input), all together; 0 when it has none.
threads_ns() {
  local pid=$1 want=$2 d ns rest sum=0 name
  for d in /proc/"$pid"/task/*; do
    read -r name 2>/dev/null < "$d/comm" || continue
    [[ $name == "$want" ]] || continue
    read -r ns rest 2>/dev/null < "$d/schedstat" || continue
    sum=$((sum + ns))
  done
  echo "$sum"
}

# The process's peak resident memory in KiB.
vm_hwm() { awk '/^VmHWM:/ {print $2}' "/proc/$1/status" 2>/dev/null; }

# Polls until the file holds a line matching the pattern (grep -E), or the
# process is gone, or the seconds pass; 0 when found.
wait_for() {
  local file=$1 pattern=$2 pid=$3 secs=$4 t=0
  while ! grep -Eq "$pattern" "$file" 2>/dev/null; do
    kill -0 "$pid" 2>/dev/null || return 1
    sleep 0.05
    t=$((t + 1))
    ((t < secs * 20)) || return 1
  done
}

# Stops the workers; sets results to the RESULT frames they sent in all.
stop_workers() {
  local dir=$1 p i t
  for p in "${wpids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
  for p in "${wpids[@]}"; do wait "$p" 2>/dev/null || true; done
  wpids=()
  results=0
  for ((i = 0; i < workers; i++)); do
    t=$(sed -n 's/.*stopped: \([0-9]*\) tasks done.*/\1/p' "$dir/w$i.log" | tail -n 1)
    results=$((results + ${t:-0}))
  done
}

# Bytes (sent + received) on the coordinator's established connections.
socket_bytes() {
  ss -tinH state established "( sport = :$1 )" 2>/dev/null |
    grep -oE 'bytes_(sent|received):[0-9]+' | awk -F: '{s += $2} END {printf "%.0f\n", s}'
}

# One run of one mode: sets line to "results samples loop_ns wall_s bytes
# peak_KiB merge_ns io_ns".
run_one_job() {
  local c=$1 s=$2 dir=$3 args=() port cpu last mlast=0 m ilast=0 io
  mkdir -p "$dir"
  [[ -n $c ]] && args+=(--chunk "$c")
  "$bin/ptserve" --listen 127.0.0.1:0 --port-file "$dir/port" --res "$res" --spp "$s" \
    --tile "$tile" "${args[@]}" "${serve_args[@]}" -o "$dir/out.exr" "$scene" 2> "$dir/serve.log" &
  local sp=$!
  pids+=("$sp")
  wait_for "$dir/port" . "$sp" 60 || { echo "farm_scale: ptserve did not start" >&2; return 1; }
  port=$(< "$dir/port")
  wpids=()
  start_workers "$port" "$dir"
  # ptserve waits for its final image's writer after the last merge, so the
  # last reading before it exits holds all of the loop's merging.
  last=0
  local hwm=0 v
  while cpu=$(loop_ns "$sp" 2>/dev/null); do
    last=$cpu
    m=$(threads_ns "$sp" pt-merge)
    ((m < mlast)) || mlast=$m
    io=$(threads_ns "$sp" pt-io)
    ((io < ilast)) || ilast=$io
    # ptserve may exit between the readings: set -e must not end the run.
    v=$(vm_hwm "$sp") || v=
    hwm=${v:-$hwm}
    sleep 0.05
  done
  wait "$sp" || { echo "farm_scale: ptserve failed (see $dir/serve.log)" >&2; return 1; }
  local samples wall bytes
  stop_workers "$dir"
  samples=$(sed -n 's/.*done in [0-9.]*s: \([0-9]*\) samples.*/\1/p' "$dir/serve.log")
  wall=$(sed -n 's/.*done in \([0-9.]*\)s:.*/\1/p' "$dir/serve.log")
  bytes=$(sed -n 's/.*wire: \([0-9]*\) bytes in, \([0-9]*\) out.*/\1 \2/p' "$dir/serve.log" |
    awk '{printf "%.0f\n", $1 + $2}')
  line="$results $samples $last $wall $bytes $hwm $mlast $ilast"
}

run_queue() {
  local c=$1 s=$2 dir=$3 args=() port cpu0 cpu1 m0 m1 i0 i1 id
  mkdir -p "$dir"
  [[ -n $c ]] && args+=(--chunk "$c")
  "$bin/ptserve" --state-dir "$dir/state" --listen 127.0.0.1:0 --port-file "$dir/port" \
    --tile "$tile" --max-spp 1048576 "${args[@]}" "${serve_args[@]}" 2> "$dir/serve.log" &
  local sp=$!
  pids+=("$sp")
  wait_for "$dir/port" . "$sp" 60 || { echo "farm_scale: ptserve did not start" >&2; return 1; }
  port=$(< "$dir/port")
  wpids=()
  start_workers "$port" "$dir"
  wait_joined "$dir/serve.log" || { echo "farm_scale: workers did not join" >&2; return 1; }
  cpu0=$(loop_ns "$sp")
  m0=$(threads_ns "$sp" pt-merge)
  i0=$(threads_ns "$sp" pt-io)
  id=$("$bin/ptctl" --server "127.0.0.1:$port" submit "$scene" --res "$res" --spp "$s")
  wait_for "$dir/serve.log" "job $id (done|failed|cancelled)" "$sp" 3600 ||
    { echo "farm_scale: job $id did not end (see $dir/serve.log)" >&2; return 1; }
  cpu1=$(loop_ns "$sp")
  m1=$(threads_ns "$sp" pt-merge)
  i1=$(threads_ns "$sp" pt-io)
  local bytes samples wall hwm
  hwm=$(vm_hwm "$sp")
  bytes=$(socket_bytes "$port")
  stop_workers "$dir"
  kill -TERM "$sp"
  wait "$sp" || true
  samples=$(sed -n "s/.*job $id done: \([0-9]*\) samples in \([0-9.]*\) s.*/\1/p" "$dir/serve.log")
  wall=$(sed -n "s/.*job $id done: \([0-9]*\) samples in \([0-9.]*\) s.*/\2/p" "$dir/serve.log")
  [[ -n $samples ]] || { echo "farm_scale: job $id failed (see $dir/serve.log)" >&2; return 1; }
  line="$results $samples $((cpu1 - cpu0)) $wall $bytes $hwm $((m1 - m0)) $((i1 - i0))"
}

# "us_per_result results_per_s bytes_per_sample MB_per_Mpixel cores_fed
# merge_us_per_result io_us_per_result" of one run's line.
figures() {
  awk -v rate="$core_rate" -v mpx="$(awk -v r="$res" 'BEGIN {split(r, a, "x"); print a[1] * a[2] / 1e6}')" '{
    r = $1; s = $2; ns = $3; wall = $4; b = $5; kb = $6; mns = $7; ins = $8
    printf "%.2f %.0f %.3f %.1f %.0f %.2f %.2f\n", ns / 1000 / r, r / wall, b / s, kb / 1024 / mpx, s / (ns / 1e9) / rate, mns / 1000 / r, ins / 1000 / r }'
}

# Runs mode m at chunk c (empty: default) --runs times; sets med to its
# medians "us/result results/s bytes/sample MB/Mpixel cores merge_us/result
# io_us/result";
# each run's figures go to stderr.
measure() {
  local m=$1 c=$2 s=$3 i
  : > "$work/fig"
  for ((i = 1; i <= runs; i++)); do
    local dir="$work/$m-${c:-default}-$i"
    if [[ $m == one-job ]]; then run_one_job "$c" "$s" "$dir"; else run_queue "$c" "$s" "$dir"; fi
    echo "$line" | figures >> "$work/fig"
    echo "  run $i: $(tail -n 1 "$work/fig")  (results samples loop_ns wall_s bytes peak_KiB merge_ns io_ns: $line)" >&2
    ((keep)) || rm -rf "$dir"
  done
  local col out=()
  for col in 1 2 3 4 5 6 7; do out+=("$(awk -v c="$col" '{print $c}' "$work/fig" | median)"); done
  med="${out[*]}"
}

if [[ $core_rate == measure ]]; then
  # One real render thread on the Cornell box, in CPU time (the machine may
  # be shared); scene loading and the acceleration build are included.
  cw=512 cs=64
  TIMEFORMAT=%3U+%3S
  cpu=$({ time "$bin/ptworker" --scene "$scene" --threads 1 --res ${cw}x${cw} --spp $cs -q \
    -o "$work/core.exr" 2> /dev/null; } 2>&1)
  core_rate=$(awk -v c="$cpu" -v n=$((cw * cw * cs)) 'BEGIN {split(c, a, "+"); printf "%.4g", n / (a[1] + a[2])}')
  echo "one real core (ptworker --threads 1, Cornell box, ${cw}x${cw}, $cs spp): $core_rate samples/s (CPU time)"
fi

echo "farm scale: ${res}, tile $tile, chunk ${chunk:-default}, $spp spp, $workers null workers x $threads threads" \
  "paced at ${pace} samples/s per thread, core rate $core_rate samples/s, $runs runs, medians"
row() { printf '%-8s %6s %12s %10s %12s %10s %10s %13s %11s\n' "$@"; }
row mode chunk 'loop us/res' results/s bytes/sample MB/Mpixel 'cores fed' 'merge us/res' 'io us/res'

declare -A fed
for m in ${modes//,/ }; do
  [[ $m == one-job || $m == queue ]] || { echo "farm_scale: unknown mode $m" >&2; exit 2; }
done
if [[ -n $curve ]]; then
  for c in $curve_list; do
    s=$spp
    ((s >= 2 * c)) || s=$((2 * c))
    for m in ${modes//,/ }; do
      measure "$m" "$c" "$s"
      read -r us rps bps mem cores mus ius <<< "$med"
      row "$m" "$c" "$us" "$rps" "$bps" "$mem" "$cores" "$mus" "$ius"
      fed[$m]=$cores
    done
  done
else
  for m in ${modes//,/ }; do
    measure "$m" "$chunk" "$spp"
    read -r us rps bps mem cores mus ius <<< "$med"
    row "$m" "${chunk:-dflt}" "$us" "$rps" "$bps" "$mem" "$cores" "$mus" "$ius"
    fed[$m]=$cores
  done
fi
echo "cores fed per loop core: one-job ${fed[one-job]:-n/a}, queue ${fed[queue]:-n/a}"
