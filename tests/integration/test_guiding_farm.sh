#!/usr/bin/env bash
# Path guiding on the farm (server/sched/job_guide.c): the coordinator
# learns each pass's distribution from every worker's statistics and the
# image is ptworker --scene ... --guiding on's, bit for bit:
#  1. ptserve --local with 1 worker and time-sized tasks, with 3 workers and
#     fixed 16-sample tasks, and ptctl submit --guiding on to a queue of 3
#     workers with 32-sample tasks; the guided image differs from the
#     unguided one (a farm that dropped guiding would fail).
#  2. A worker killed (SIGKILL) in the middle of the training passes: the
#     others finish the job, bit-identical.
#  3. The coordinator killed (kill -9) in the middle of the training passes,
#     with checkpoints every few results: the restart replays its results
#     log onto the checkpoint, rebuilds the same distributions and ends
#     bit-identical.
#     In 2 and 3 the coordinator's test hook PTSERVE_TEST_LEASE_GATE holds
#     the job mid-training (no task starting at 64 spp or later is leased
#     until a file exists), so the kill comes after a learned pass and
#     before the end however loaded the machine: no race with the polls.
#  4. --guiding auto (and on) of an all-Lambert scene is the unguided image
#     on ptworker and on the farm; on is refused with adaptive sampling and
#     a bad mode by every program (exit 2).
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
scenes=${PT_SHARED_SCENES:-$src/../shared/scenes}
scene=$scenes/CornellBox/cornellBox.gltf
# shellcheck source=tests/integration/lib_shared.sh
. "$(dirname "$0")/lib_shared.sh"
need_shared "$scene"
tmp=$(mktemp -d /tmp/pt_guiding_farm_XXXXXX)
srv_pid=
wpids=()
cleanup() {
  if [ -n "$srv_pid" ] && kill "$srv_pid" 2>/dev/null; then wait "$srv_pid" 2>/dev/null || true; fi
  for p in "${wpids[@]}"; do kill "$p" 2>/dev/null || true; done
  if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }
json() { python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))" "$@"; }
same() { # NAME: the image is the standalone guided render's
  "$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/$1.exr" > "$tmp/$1.diff" ||
    fail "$1 differs from ptworker --guiding on: $(cat "$tmp/$1.diff")"
}

view=(--res 64x48 --spp 128 --seed 11)
"$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --guiding on -q -o "$tmp/ref.exr" \
  2> /dev/null || fail "ptworker --guiding on"
"$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 -q -o "$tmp/plain.exr" 2> /dev/null
if "$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/plain.exr" > /dev/null 2>&1; then
  fail "guiding changes nothing here: the test could not tell it from none"
fi

# 1. One-job mode: 1 worker (time-sized tasks), 3 workers (fixed chunks).
"$bin/ptserve" --local 1 --worker-threads 2 "${view[@]}" --tile 16 --task-time 100 --guiding on \
  -q -o "$tmp/one.exr" "$scene" 2> "$tmp/one.log" || fail "ptserve --local 1: $(cat "$tmp/one.log")"
same one
"$bin/ptserve" --local 3 --worker-threads 1 "${view[@]}" --tile 16 --chunk 16 --guiding on \
  -q -o "$tmp/three.exr" "$scene" 2> "$tmp/three.log" || fail "ptserve --local 3: $(cat "$tmp/three.log")"
same three

# Queue mode: serve LOG [ptserve options]: on $tmp/state, port in $PTFARM_SERVER.
serve() {
  local log=$1
  shift
  rm -f "$tmp/port"
  "$bin/ptserve" --state-dir "$tmp/state" --output-dir "$tmp/out" --listen 127.0.0.1:0 \
    --port-file "$tmp/port" --tile 16 "$@" 2>> "$tmp/$log" &
  srv_pid=$!
  for _ in $(seq 400); do [ -s "$tmp/port" ] && break; sleep 0.05; done
  [ -s "$tmp/port" ] || fail "ptserve did not start: $(cat "$tmp/$log")"
  PTFARM_SERVER=127.0.0.1:$(cat "$tmp/port")
  export PTFARM_SERVER
}
stop() {
  kill "$srv_pid"
  wait "$srv_pid" || true
  srv_pid=
}
status() { "$bin/ptctl" --timeout 20 status "$1" --json > "$tmp/status.json"; }
until_status() { # ID EXPR: polls (up to 120 s) until EXPR over the status (d) holds
  for _ in $(seq 1200); do
    status "$1" && [ "$(json "$tmp/status.json" "$2")" = True ] && return 0
    sleep 0.1
  done
  fail "job $1: never $2: $(cat "$tmp/status.json")"
}
finish() { # ID NAME: the job ends done, its image the standalone guided render's
  until_status "$1" 'd["state"] == "done"'
  "$bin/ptctl" fetch "$1" -o "$tmp/$2.exr"
  same "$2"
}
pass1=$((64 * 48 * 16)) # samples of the first training pass
# Cases 2 and 3 hold the job at 64 spp: pass 2 ([48, 112), learned from 48
# spp) is under way, and no tile can pass 112 spp while held.
hold=64

serve queue.log --local 3 --worker-threads 1 --chunk 32
id=$("$bin/ptctl" submit "$scene" "${view[@]}" --guiding on --name queued)
finish "$id" queued
stop

# 2. A worker killed mid-training; two more go on.
view=(--res 64x48 --spp 512 --seed 11)
"$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --guiding on -q -o "$tmp/ref.exr" \
  2> /dev/null || fail "ptworker --guiding on (512 spp)"
PTSERVE_TEST_LEASE_GATE="$hold:$tmp/go_killw" serve killw.log --task-time 200
for n in 1 2 3; do
  "$bin/ptworker" --server "$PTFARM_SERVER" --threads 1 --name "w$n" --cache-dir "$tmp/cache$n" \
    2> "$tmp/w$n.log" &
  wpids+=($!)
done
id=$("$bin/ptctl" submit "$scene" "${view[@]}" --guiding on --name killw)
until_status "$id" "d['samples_done'] > $((3 * pass1)) or d['state'] != 'running'"
[ "$(json "$tmp/status.json" 'd["state"]')" = running ] || fail "the job ended before the kill"
# Status shows the pass being rendered: past 48 spp of samples merged, pass 1
# or later, its distribution learned from the samples before it.
[ "$(json "$tmp/status.json" \
  'd["guiding"]["pass"] >= 1 and d["guiding"]["learned_spp"] == 16 * (2 ** d["guiding"]["pass"] - 1)')" = True ] ||
  fail "status shows no learned guiding pass: $(cat "$tmp/status.json")"
"$bin/ptctl" --timeout 20 status "$id" > "$tmp/status.txt"
grep -Eq '^guiding +pass [1-9][0-9]*, its distribution learned from [0-9]+ spp$' "$tmp/status.txt" ||
  fail "ptctl status shows no guiding pass: $(cat "$tmp/status.txt")"
kill -9 "${wpids[0]}"
# The others render what it held; the job then waits at the hold, mid-pass.
until_status "$id" "d['samples_done'] >= $((hold * 64 * 48)) or d['state'] != 'running'"
[ "$(json "$tmp/status.json" "d['state'] == 'running' and d['samples_done'] <= 112 * 64 * 48")" = True ] ||
  fail "the job went past the hold: $(cat "$tmp/status.json")"
touch "$tmp/go_killw"
finish "$id" killw
stop
for p in "${wpids[@]}"; do kill "$p" 2>/dev/null || true; done
wpids=()

# 3. The coordinator killed mid-training, checkpoints every 20 kB of log.
rm -rf "$tmp/state"
PTSERVE_TEST_CKPT_LOG_BYTES=20000 PTSERVE_TEST_LEASE_GATE="$hold:$tmp/go_kill9" \
  serve kill9.log --local 2 --worker-threads 1 --task-time 200
id=$("$bin/ptctl" submit "$scene" "${view[@]}" --guiding on --name kill9)
until_status "$id" "d['samples_done'] > $((3 * pass1)) or d['state'] != 'running'"
[ "$(json "$tmp/status.json" 'd["state"]')" = running ] || fail "the job ended before the kill"
# Held, the job waits for its checkpoint (written on a thread of its own).
for _ in $(seq 400); do [ -s "$tmp/state/jobs/$id/checkpoint" ] && break; sleep 0.05; done
children=$(pgrep -P "$srv_pid" || true)
kill -9 "$srv_pid"
wait "$srv_pid" || true
srv_pid=
for c in $children; do kill "$c" 2>/dev/null || true; done
[ -s "$tmp/state/jobs/$id/checkpoint" ] || fail "no checkpoint was written before the kill"
touch "$tmp/go_kill9" # the restart leases on past the hold
PTSERVE_TEST_CKPT_LOG_BYTES=20000 PTSERVE_TEST_LEASE_GATE="$hold:$tmp/go_kill9" \
  serve kill9.log --local 2 --worker-threads 1 --task-time 200
finish "$id" kill9
grep -q "job $id resumed" "$tmp/kill9.log" || fail "no resume logged: $(cat "$tmp/kill9.log")"
stop

# 4. An all-Lambert scene: auto and on guide nothing, on the farm too.
lambert=$src/scenes/cornell_box.gltf
small=(--res 32x32 --spp 32 --seed 3 --tile 16)
"$bin/ptworker" --scene "$lambert" "${small[@]}" -q -o "$tmp/lref.exr" 2> /dev/null
for mode in auto on; do
  "$bin/ptworker" --scene "$lambert" "${small[@]}" --guiding $mode -q -o "$tmp/l$mode.exr" \
    2> /dev/null
  "$bin/ptexr-diff" "$tmp/lref.exr" "$tmp/l$mode.exr" > /dev/null || fail "ptworker --guiding $mode"
  "$bin/ptserve" --local 2 --worker-threads 1 "${small[@]}" --guiding $mode -q \
    -o "$tmp/lf$mode.exr" "$lambert" 2> /dev/null || fail "ptserve --guiding $mode (Lambert)"
  "$bin/ptexr-diff" "$tmp/lref.exr" "$tmp/lf$mode.exr" > /dev/null || fail "ptserve --guiding $mode"
done
expect_refusal() { # WHAT PATTERN CMD...: exit 2 naming PATTERN
  local what=$1 pattern=$2
  shift 2
  set +e
  "$@" 2> "$tmp/refusal.log"
  local rc=$?
  set -e
  if [ $rc != 2 ] || ! grep -q -- "$pattern" "$tmp/refusal.log"; then
    fail "$what: rc $rc: $(cat "$tmp/refusal.log")"
  fi
}
expect_refusal "ptserve --guiding maybe" "--guiding" \
  "$bin/ptserve" --local 1 -o "$tmp/x.exr" --guiding maybe "$scene"
expect_refusal "ptctl submit --guiding maybe" "--guiding" \
  "$bin/ptctl" --server 127.0.0.1:1 submit "$scene" --guiding maybe
expect_refusal "ptserve --guiding on --target-error" "--guiding on" \
  "$bin/ptserve" --local 1 -o "$tmp/x.exr" --guiding on --target-error 0.1 "$scene"
expect_refusal "ptctl submit --guiding on --min-gain" "--guiding on" \
  "$bin/ptctl" --server 127.0.0.1:1 submit "$scene" --guiding on --min-gain 1e-6
expect_refusal "ptserve --state-dir --guiding" "one-job mode" \
  "$bin/ptserve" --state-dir "$tmp/qstate" --listen 127.0.0.1:0 --guiding on
failed=0
echo "ok"
