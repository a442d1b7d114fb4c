#!/usr/bin/env bash
# Queue mode's durable steps off the event loop (server/store/state.h), with
# ptserve's test hooks (environment variables read by server/store/state_open.c
# and, the lease gate, server/sched/queue.c):
#  1. While a group commit's fdatasync is held, the loop keeps answering
#     (ptctl status) and merges nothing: a result is merged only once the
#     commit that holds its log record has returned. Then the job completes,
#     bit-identical to the standalone render.
#  2. A failing fdatasync pauses the job like a full disk (nothing merged,
#     the reason shown); it resumes once a commit succeeds, bit-identical.
#  3. kill -9 of the coordinator while a checkpoint is being written (written
#     to its temporary file, not yet renamed, the log rotated): the restart
#     loses no merged sample and the image is bit-identical.
#  4. A disk slower than the results (the commits held) with --max-log-mb 1:
#     the workers are no longer read once a MiB of records waits (the log's
#     bytes not yet durable stay near the cap, read from /metrics), clients
#     are still answered, and no lease expires though the hold lasts three
#     lease timeouts. Once the disk catches up the job completes,
#     bit-identical. With the I/O threads and with the loop reading the
#     workers itself.
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
tmp=$(mktemp -d /tmp/pt_durable_XXXXXX)
srv_pid=
cleanup() {
  # Every gate open: a ptserve stopped mid-test syncs its log first and
  # joins its checkpoint thread, which would otherwise wait for them forever.
  touch "$tmp/commit_go" "$tmp/ckpt_go"
  if [ -n "$srv_pid" ] && kill "$srv_pid" 2>/dev/null; then wait "$srv_pid" 2>/dev/null || true; fi
  if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }
json() { python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))" "$@"; }

view=(--res 64x48 --spp 256 --seed 7)
ref() { # NAME: the standalone render of view
  "$bin/ptworker" --scene "$src/scenes/cornell_box.gltf" "${view[@]}" --tile 16 --chunk 8 -q \
    -o "$tmp/$1.exr" 2> /dev/null
}
ref ref

# serve LOG [VAR=VALUE...]: ptserve on $tmp/state with two local workers and
# the options in serve_args.
serve_args=()
serve() {
  local log=$1
  shift
  rm -f "$tmp/port"
  env "$@" "$bin/ptserve" --state-dir "$tmp/state" --output-dir "$tmp/out" \
    --listen 127.0.0.1:0 --port-file "$tmp/port" --local 2 --worker-threads 1 --tile 16 \
    --chunk 8 "${serve_args[@]}" 2>> "$tmp/$log" &
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
# status ID: its JSON in $tmp/status.json, answered within 20 s.
status() { "$bin/ptctl" --timeout 20 status "$1" --json > "$tmp/status.json"; }
# until_status ID EXPR: polls (up to 120 s) until EXPR over the status (d) holds.
until_status() {
  for _ in $(seq 1200); do
    status "$1" && [ "$(json "$tmp/status.json" "$2")" = True ] && return 0
    sleep 0.1
  done
  fail "job $1: never $2: $(cat "$tmp/status.json")"
}
# until_file PATH MIN: polls (up to 120 s) until PATH holds more than MIN bytes.
until_file() {
  for _ in $(seq 1200); do
    [ "$(stat -c %s "$1" 2>/dev/null || echo 0)" -gt "$2" ] && return 0
    sleep 0.1
  done
  fail "$1 never grew past $2 bytes"
}
finish() { # ID NAME: the job ends done, its image the standalone render's
  until_status "$1" 'd["state"] == "done"'
  [ "$(json "$tmp/status.json" 'd["samples_done"] == d["samples_total"]')" = True ] ||
    fail "samples: $(cat "$tmp/status.json")"
  "$bin/ptctl" fetch "$1" -o "$tmp/$2.exr"
  "$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/$2.exr" || fail "$2: the image differs"
}
submit() { "$bin/ptctl" submit "$src/scenes/cornell_box.gltf" "${view[@]}" --name "$1"; }

# 1. The commit held: records are written, the loop answers, nothing merges.
serve serve1.log PTSERVE_TEST_COMMIT_GATE="$tmp/commit_go"
id=$(submit held)
until_file "$tmp/state/jobs/$id/results.log" 16 # a record written, its fdatasync held
for _ in 1 2 3 4 5; do
  status "$id" || fail "no answer to status while the commit is held"
  [ "$(json "$tmp/status.json" 'd["samples_done"]')" = 0 ] ||
    fail "merged before its commit returned: $(cat "$tmp/status.json")"
  sleep 0.2
done
touch "$tmp/commit_go"
finish "$id" held
stop

# 2. The commit fails: the job pauses, merges nothing, and resumes.
touch "$tmp/commit_fail"
serve serve2.log PTSERVE_TEST_COMMIT_FAIL="$tmp/commit_fail"
id=$(submit failing)
until_status "$id" '"paused" in d["message"]'
[ "$(json "$tmp/status.json" 'd["samples_done"]')" = 0 ] ||
  fail "merged though its commit failed: $(cat "$tmp/status.json")"
grep -q "paused: cannot make its results log durable" "$tmp/serve2.log" ||
  fail "the pause is not logged: $(cat "$tmp/serve2.log")"
rm "$tmp/commit_fail"
finish "$id" failing
grep -q "job $id resumed" "$tmp/serve2.log" || fail "the resume is not logged"
stop

# 3. kill -9 with a checkpoint half done: written, not renamed into place. A
# longer job, so that it is still running then: 1,536 results, of which the
# checkpoint needs about 50. Step 4 renders the same view, against the same
# reference. No task from 512 samples on is leased (a gate never opened),
# so that the job cannot end before the kill however loaded the machine
# (it did, between the status below and the kill): by then its log holds
# half its results, far past the checkpoint's 400 kB.
view=(--res 64x48 --spp 1024 --seed 7)
ref ref
serve serve3.log PTSERVE_TEST_CKPT_LOG_BYTES=400000 PTSERVE_TEST_CKPT_GATE="$tmp/ckpt_go" \
  PTSERVE_TEST_LEASE_GATE="512:$tmp/lease_go"
id=$(submit killed)
until_file "$tmp/state/jobs/$id/results.old" 16
until_file "$tmp/state/jobs/$id/results.log" 40000
ckpt_tmp() { compgen -G "$tmp/state/jobs/$id/checkpoint.tmp-*" >/dev/null; }
for _ in $(seq 600); do
  ckpt_tmp && break
  sleep 0.1
done
ckpt_tmp || fail "no checkpoint being written"
until_status "$id" 'd["samples_done"] > 0 or d["state"] != "running"'
[ "$(json "$tmp/status.json" 'd["state"]')" = running ] || fail "the job ended before the kill"
before=$(json "$tmp/status.json" 'd["samples_done"]')
# Its local workers outlive it: they are stopped with it (the restart starts
# its own).
children=$(pgrep -P "$srv_pid" || true)
kill -9 "$srv_pid"
wait "$srv_pid" || true
srv_pid=
for c in $children; do kill "$c" 2>/dev/null || true; done
serve serve3.log PTSERVE_TEST_CKPT_LOG_BYTES=400000
status "$id"
after=$(json "$tmp/status.json" 'd["samples_done"]')
[ "$after" -ge "$before" ] || fail "$before samples merged before the kill, $after after"
grep -q "job $id resumed" "$tmp/serve3.log" || fail "no resume logged: $(cat "$tmp/serve3.log")"
finish "$id" killed
stop

# 4. The disk behind: commits held, 1 MiB of the log's records in memory at
# most. 1,536 results of 9 kB: 14 MB of log were nothing held back. The view
# and its reference are step 3's.
metric() { # NAME: its value in /metrics
  python3 - "http://127.0.0.1:$(cat "$tmp/hport")/metrics" "$1" << 'PY'
import sys, urllib.request
for line in urllib.request.urlopen(sys.argv[1], timeout=20).read().decode().splitlines():
    if line.split(" ")[0] == sys.argv[2]:
        print(int(float(line.split(" ")[1])))
PY
}
# The leases the log says expired from the hold on, to its release.
expired_while_held() {
  sed -n '/workers are not read until the disk catches up/,/the disk caught up after/p' \
    "$tmp/$log" | grep "leases expired"
}
for io in 2 0; do
  log=serve4-$io.log
  rm -rf "$tmp/state" "$tmp/commit_go" "$tmp/hport"
  serve_args=(--max-log-mb 1 --lease-timeout 1 --io-threads "$io" --http 127.0.0.1:0
    --http-port-file "$tmp/hport")
  serve "$log" PTSERVE_TEST_COMMIT_GATE="$tmp/commit_go"
  id=$(submit "behind-$io")
  for _ in $(seq 1200); do
    grep -q "workers are not read until the disk catches up" "$tmp/$log" && break
    sleep 0.1
  done
  grep -q "workers are not read until the disk catches up" "$tmp/$log" ||
    fail "io threads $io: never held: $(cat "$tmp/$log")"
  # Leases that expired before the hold are a slow machine's (1 s leases
  # under ThreadSanitizer beside other work), not the hold's: none may
  # expire from its start to its release.
  expired=$(metric ptfarm_tasks_expired_total)
  sleep 3 # three lease timeouts
  ! expired_while_held > /dev/null || fail "io threads $io: $(expired_while_held)"
  status "$id" || fail "io threads $io: no answer to status while held"
  [ "$(json "$tmp/status.json" 'd["state"]')" = running ] || fail "ended while held"
  held=$(metric ptfarm_results_log_unsynced_bytes)
  # The cap, and at most what the round that passed it took in: a few tasks
  # of two one-thread workers.
  if [ "$held" -le $((1 << 20)) ] || [ "$held" -ge $((3 << 19)) ]; then
    fail "io threads $io: $held bytes of results not durable while held"
  fi
  echo "io threads $io: $held bytes of results not durable while held"
  [ "$(metric ptfarm_results_log_holds_total)" = 1 ] || fail "io threads $io: holds"
  [ "$(metric ptfarm_tasks_expired_total)" = "$expired" ] ||
    fail "io threads $io: leases expired while held: $(cat "$tmp/$log")"
  touch "$tmp/commit_go"
  finish "$id" "behind-$io"
  grep -q "the disk caught up after" "$tmp/$log" || fail "io threads $io: no release logged"
  ! expired_while_held > /dev/null || fail "io threads $io: $(expired_while_held)"
  stop
done
failed=0
echo "ok"
