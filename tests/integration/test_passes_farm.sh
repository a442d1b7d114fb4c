#!/usr/bin/env bash
# Render passes on the farm (common/render/passes.h): every pass is merged
# exactly like the beauty, so the farm's EXR equals the standalone render's
# bit for bit in all 52 pass channels (ptexr-diff compares every layer), and
# its header has the Cryptomatte manifests (one-job ptserve from the scene it
# loads, a queued job from what its upload check kept in the state folder,
# across a restart too):
#  1. one-job ptserve --passes with two local workers;
#  2. ptctl submit --passes through a queue, one of two workers killed (-9)
#     while it holds tasks, which are requeued;
#  3. the coordinator killed (-9) mid-job with checkpoints written often (its
#     held results and film with their pass sums, then the results log's
#     records replayed), restarted: the job resumes and ends bit-identical.
# A job's passes are refused by a ptserve --state-dir (queued jobs ask for
# them with ptctl submit).
set -euo pipefail
# shellcheck source=tests/integration/lib_farm.sh
. "$(dirname "$0")/lib_farm.sh"
farm_init passes_farm

view=(--res 48x32 --spp 64 --seed 3 --passes all)
"$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --chunk 8 -q -o "$tmp/ref.exr" 2> /dev/null
same() { # NAME: its EXR is the reference's, every layer, with the Cryptomatte manifests
  "$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/$1.exr" > "$tmp/$1.diff" ||
    fail "$1: $(cat "$tmp/$1.diff")"
  grep -q "and 52 named channels" "$tmp/$1.diff" || fail "$1: $(cat "$tmp/$1.diff")"
  # The header is not compressed: the manifests' names are there as text.
  for name in '"tall_block":"' '"right_wall_green":"' '"white":"'; do
    grep -a -q "$name" "$tmp/$1.exr" || fail "$1: no $name in its Cryptomatte manifests"
  done
}

# 1. One job.
"$bin/ptserve" --local 2 --worker-threads 1 --tile 16 --chunk 8 "${view[@]}" -o "$tmp/one.exr" \
  "$scene" 2> "$tmp/one.log" || fail "one-job ptserve: $(cat "$tmp/one.log")"
same one
rc=0
"$bin/ptserve" --state-dir "$tmp/x" --passes albedo 2> "$tmp/refused.err" || rc=$?
if [ "$rc" != 2 ] || ! grep -q "ptctl submit --passes" "$tmp/refused.err"; then
  fail "a queue took --passes: exit $rc: $(cat "$tmp/refused.err")"
fi

# 2. A worker killed while it renders: its tasks are requeued.
view=(--res 48x32 --spp 512 --seed 3 --passes all)
"$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --chunk 8 -q -o "$tmp/ref.exr" 2> /dev/null
port=0
serve serve1.log
workers 2
id=$("$bin/ptctl" submit "$scene" "${view[@]}" --name killed-worker)
until_status "$id" 'd["samples_done"] > 0'
kill_worker
finish "$id" worker_killed
stop_workers
stop_server

# 3. The coordinator killed with checkpoints written every 40 kB of log.
view=(--res 48x32 --spp 2048 --seed 3 --passes all)
"$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --chunk 8 -q -o "$tmp/ref.exr" 2> /dev/null
port=0
# No task past 1024 spp is leased before the kill (the gate never opens), so
# the job cannot end first however loaded the machine; the restarted
# coordinator has no gate and finishes it.
serve serve2.log PTSERVE_TEST_CKPT_LOG_BYTES=40000 PTSERVE_TEST_LEASE_GATE="1024:$tmp/never"
workers 2
id=$("$bin/ptctl" submit "$scene" "${view[@]}" --name killed-server)
for _ in $(seq 1200); do
  compgen -G "$tmp/state/jobs/$id/checkpoint*" > /dev/null && break
  sleep 0.1
done
compgen -G "$tmp/state/jobs/$id/checkpoint*" > /dev/null || fail "no checkpoint written"
until_status "$id" 'd["samples_done"] > 0 or d["state"] != "running"'
hold_workers
status "$id"
[ "$(json "$tmp/status.json" 'd["state"]')" = running ] || fail "the job ended before the kill"
before=$(json "$tmp/status.json" 'd["samples_done"]')
stop_server -9
release_workers
serve serve2.log # the same port: the workers reconnect to it
status "$id"
after=$(json "$tmp/status.json" 'd["samples_done"]')
[ "$after" -ge "$before" ] || fail "$before samples merged before the kill, $after after"
grep -q "job $id resumed" "$tmp/serve2.log" || fail "no resume logged: $(cat "$tmp/serve2.log")"
finish "$id" server_killed
failed=0
echo "passes farm: ok"
