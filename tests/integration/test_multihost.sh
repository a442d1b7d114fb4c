#!/usr/bin/env bash
# A ptfarm render across "hosts" made of Linux network namespaces:
#
#   srv  (ptserve)  --veth 10.77.0.0/30--  w1  (ptworker --name w1)
#                   --veth 10.77.0.4/30--  w2
#                   --veth 10.77.0.8/30--  w3
#                   --veth 10.77.0.12/30-- w4  (a worker with the wrong token)
#                   --veth 10.77.0.16/30-- w5  (an idle worker, its link cut)
#
# Each worker talks only to the coordinator's address on its own link; nothing
# is routed and nothing leaves the namespaces. First, while the reference
# renders, w5 connects to a listener that never answers and its link is cut:
# with nothing to send, it must notice the dead link by TCP keepalive within
# its --link-timeout. Then the test renders a reference with
# the standalone ptworker, runs the same job on the farm, cuts w1's link in the
# middle of the render for longer than the lease timeout (its leased tasks must
# be requeued), restores it, lets w4 try the wrong token (it must be refused),
# and requires ptserve to exit 0 with an image that is bit-identical (R, G, B,
# samples) to the reference.
#
# Nothing closes w1's connection during the outage: no FIN or RST can cross a
# link that is down. w1 must notice by itself, through its --link-timeout (its
# heartbeats stay unacknowledged), drop its tasks and, once the link is back,
# rejoin on a new connection: ptserve logs "worker w1 joined" a second time
# while the render still runs, and w1's log says the link timeout fired.
# So that the render cannot end before w1 is back however fast this machine
# is, w2 and w3 are held (SIGSTOP) from the requeue of w1's tasks until w1
# has rejoined; leases of theirs that expire meanwhile are requeued too, and
# their late results dropped. The farm runs on at most 2 CPUs for the same
# reason: a machine with many cores would otherwise finish before the cut.
#
# Needs root or CAP_SYS_ADMIN for `ip netns`; prints SKIP and exits 77 (ctest:
# skipped) without them, except with CI=true, where that is a failure. Environment (set by
# ctest): PT_BIN (the build's bin folder), PT_SOURCE_DIR.
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
# shellcheck source=tests/integration/lib_netns.sh
source "$here/lib_netns.sh"
# shellcheck source=tests/integration/lib_build.sh
source "$here/lib_build.sh"

: "${PT_BIN:?PT_BIN must name the bin folder of the build}"
: "${PT_SOURCE_DIR:?PT_SOURCE_DIR must name the source tree}"
scene=$PT_SOURCE_DIR/scenes/cornell_box.gltf

# The job: long enough (the farm takes 11-18 s on 2 shared cores) that the farm is still rendering
# after the cut, the lease timeout and w1's return; half as many samples in a sanitizer build,
# which renders them three to ten times slower.
res=96x64
spp=$(sanitized_spp 4096)
job=(--res "$res" --spp "$spp" --tile 16 --chunk 8 --seed 3)
lease=3     # --lease-timeout, seconds
link=2      # the workers' --link-timeout, seconds; below $outage, so w1 notices the cut
outage=6    # how long w1's link stays down; must exceed $lease and $link with a margin
port=7000

say() { printf '[%3ds] %s\n' "$SECONDS" "$*"; }

for tool in ptworker ptserve; do
  [[ -x "$PT_BIN/$tool" ]] || fail "$PT_BIN/$tool missing"
done
[[ -x "$PT_BIN/ptexr-diff" ]] || fail "ptexr-diff missing ($PT_BIN/ptexr-diff)"
[[ -f "$scene" ]] || fail "$scene missing"

netns_init "ptmh$$"
netns_require

NETNS_TMP=$(mktemp -d "${TMPDIR:-/tmp}/ptmultihost.XXXXXX")
T=$NETNS_TMP
cd "$T"

# The hosts: one namespace each, a /30 per worker link.
netns_add srv
srv_addr=()   # srv_addr[k]: the coordinator's address on worker k's link
wrk_addr=()
for k in 1 2 3 4 5; do
  netns_add "w$k"
  srv_addr[k]=10.77.0.$((4 * k - 3))
  wrk_addr[k]=10.77.0.$((4 * k - 2))
  netns_veth srv "veth-w$k" "${srv_addr[k]}/30" "w$k" veth-srv "${wrk_addr[k]}/30"
done
say "namespaces: $(netns_name srv), $(netns_name w1) .. $(netns_name w5)"

# 1. An idle worker's dead link. A listener in srv accepts w5 and never
# answers, so w5 waits for a CHALLENGE with nothing to send; then its link is
# cut. Only keepalive probes can tell w5 the link is dead, and they must
# before the handshake timeout (15 s) would.
idle_port=7001
idle_srv_pid=""
netns_spawn idle_srv_pid "$T/idle-listener.log" srv python3 -c '
import socket, sys, time
s = socket.socket()
s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
s.bind((sys.argv[1], int(sys.argv[2])))
s.listen(1)
c = s.accept()
print("accepted", flush=True)
time.sleep(120)' "${srv_addr[5]}" "$idle_port"
idle_pid=""
for ((i = 0; i < 50; i++)); do
  netns_exec srv ss -Hltn "src ${srv_addr[5]}:$idle_port" | grep -q . && break
  sleep 0.1
done
netns_spawn idle_pid "$T/w5.log" w5 "$PT_BIN/ptworker" --server "${srv_addr[5]}:$idle_port" \
  --threads 1 --cache-dir "$T/cache-w5" --name w5 --link-timeout "$link"
wait_for_log "$T/idle-listener.log" '^accepted' 10 1 "$idle_srv_pid" ||
  fail "w5 did not connect to the silent listener within 10 s"
netns_link_set w5 veth-srv down
idle_cut_at=$SECONDS
say "w5 connected to a silent listener; cut its link"
# Note when w5 gives up, while the reference renders.
(wait_for_log "$T/w5.log" 'retrying in' 30 1 && echo $((SECONDS - idle_cut_at)) >"$T/w5.noticed") &
idle_watch=$!

# The reference, rendered on this machine alone (meanwhile w5's link is dead).
say "reference: ptworker --scene ${job[*]}"
"$PT_BIN/ptworker" --scene "$scene" "${job[@]}" -o "$T/ref.exr" -q >"$T/ref.log" 2>&1 ||
  fail "the reference render failed"
say "reference done"

# w5 must have given up on its silent link within its link timeout, plus a
# keepalive probe interval (1 s) and slack for whole seconds and a loaded machine.
wait "$idle_watch" || fail "w5 did not notice its dead idle link within 30 s"
noticed=$(<"$T/w5.noticed")
((noticed <= link + 3)) || fail "w5 noticed its dead idle link only after $noticed s"
grep -m1 'retrying in' "$T/w5.log" | grep -q -- '(--link-timeout)' ||
  fail "w5's first failure is not its link timeout: $(grep -m1 'retrying in' "$T/w5.log")"
kill -TERM "$idle_pid" "$idle_srv_pid"
say "w5 noticed its dead idle link after ${noticed} s (--link-timeout $link)"

# The farm's processes run on the first two CPUs this test may use.
cpus=$(python3 -c 'import os; print(",".join(map(str, sorted(os.sched_getaffinity(0))[:2])))') ||
  fail "cannot read this process's CPU affinity"
pin=(taskset -c "$cpus")

# 2. The coordinator. It listens on every address of its own namespace: the
# coordinator's address on each worker's link.
head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' >"$T/tok"
head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' >"$T/bad-tok"
chmod 600 "$T/tok" "$T/bad-tok"
srv_log=$T/ptserve.log
srv_pid=""
netns_spawn srv_pid "$srv_log" srv "${pin[@]}" "$PT_BIN/ptserve" --listen "0.0.0.0:$port" \
  --token-file "$T/tok" --port-file "$T/port" --lease-timeout "$lease" --save-interval 1 \
  "${job[@]}" -o "$T/farm.exr" "$scene"
deadline=$((SECONDS + 10))
while [[ ! -s "$T/port" ]] && ((SECONDS <= deadline)); do
  kill -0 "$srv_pid" 2>/dev/null || fail "ptserve exited at start"
  sleep 0.1
done
[[ -s "$T/port" ]] || fail "ptserve wrote no port file in 10 s"
say "ptserve listening on port $(<"$T/port") in $(netns_name srv)"

# 3. Three workers, one per namespace, each with its own scene cache.
wrk_pid=()  # set by netns_spawn
for k in 1 2 3; do
  netns_spawn "wrk_pid[$k]" "$T/w$k.log" "w$k" "${pin[@]}" "$PT_BIN/ptworker" \
    --server "${srv_addr[k]}:$port" --token-file "$T/tok" --threads 1 \
    --cache-dir "$T/cache-w$k" --name "w$k" --link-timeout "$link"
done
for k in 1 2 3; do
  # The peer address proves the worker came over its own link.
  wait_for_log "$srv_log" "worker w$k joined from ${wrk_addr[k]//./\\.}:" 20 1 "$srv_pid" ||
    fail "w$k did not join from ${wrk_addr[k]} within 20 s"
done
say "w1, w2, w3 joined, each from its own link"

# 4. Cut w1's link once the farm has merged work (the first progressive save).
deadline=$((SECONDS + 30))
while [[ ! -f "$T/farm.exr" ]] && ((SECONDS <= deadline)); do
  kill -0 "$srv_pid" 2>/dev/null || fail "ptserve exited before its first progressive save"
  sleep 0.1
done
[[ -f "$T/farm.exr" ]] || fail "no progressive save in 30 s"
kill -0 "$srv_pid" 2>/dev/null || fail "the render finished before w1's link could be cut; enlarge the job"
requeued_re='leases expired; tasks requeued|worker w1 left; [1-9][0-9]* leased tasks requeued'
requeued_before=$(log_count "$srv_log" "$requeued_re")
joined_re='worker w1 joined from'
session_re='ptworker: connected to '
netns_link_set w1 veth-srv down
cut_at=$SECONDS
say "cut w1's link (ip link set veth-srv down in $(netns_name w1))"

# 5. Meanwhile a worker with the wrong token tries to join: it must be refused.
st=0
netns_exec w4 timeout 30 "$PT_BIN/ptworker" --server "${srv_addr[4]}:$port" \
  --token-file "$T/bad-tok" --threads 1 --cache-dir "$T/cache-w4" --name intruder \
  >"$T/w4.log" 2>&1 || st=$?
((st != 124)) || fail "the worker with the wrong token was still running after 30 s"
((st != 0)) || fail "the worker with the wrong token exited 0"
grep -q "authentication failed" "$srv_log" ||
  fail "ptserve did not log 'authentication failed' for the wrong token"
! grep -q "worker intruder joined" "$srv_log" || fail "the worker with the wrong token joined"
say "wrong token refused (ptworker exit status $st)"

# Back to w1: its leases must expire while its link is down.
wait_for_log "$srv_log" "$requeued_re" $((outage + lease + 2)) $((requeued_before + 1)) "$srv_pid" ||
  fail "w1's leased tasks were not requeued within $((outage + lease + 2)) s of the cut"
say "w1's leased tasks were requeued"
kill -0 "$srv_pid" 2>/dev/null ||
  fail "the render finished during w1's outage; enlarge the job so w1's rejoin can be checked"
kill -STOP "${wrk_pid[2]}" "${wrk_pid[3]}"
say "holding w2 and w3 until w1 has rejoined"
while ((SECONDS - cut_at < outage)); do sleep 0.1; done
netns_link_set w1 veth-srv up
say "restored w1's link after $((SECONDS - cut_at)) s"

# w1 must rejoin on a new connection, while the render lasts.
wait_for_log "$srv_log" "$joined_re" 20 2 "$srv_pid" || {
  kill -0 "$srv_pid" 2>/dev/null ||
    fail "the render finished $((SECONDS - cut_at - outage)) s after w1's link came back, before w1 rejoined"
  fail "w1 did not rejoin within 20 s of its link coming back"
}
say "w1 rejoined $((SECONDS - cut_at - outage)) s after its link came back"
kill -CONT "${wrk_pid[2]}" "${wrk_pid[3]}"
say "w2 and w3 go on"
# The kernel reports the timeout as ETIMEDOUT, or as the route's error when
# the link's own end went down (the last soft error it saw): both are w1
# noticing by itself, since nothing from the server can cross.
grep -qE "no answer from the server for .* \(--link-timeout\)|(recv|send): (Network is unreachable|No route to host)" "$T/w1.log" ||
  fail "w1's log does not say it noticed the dead link"
(($(log_count "$T/w1.log" "$session_re") >= 2)) || fail "w1's log shows no second session"
say "w1's log: dead link noticed, new session"

# 6. ptserve exits 0 when the image is complete, and the image matches the reference.
wait_pid_timeout "$srv_pid" 600 st
((st != 124)) || fail "ptserve still running after 600 s"
((st == 0)) || fail "ptserve exited with status $st"
say "ptserve exited 0"
for k in 1 2 3; do
  pid=${wrk_pid[k]}
  kill -0 "$pid" 2>/dev/null || fail "worker w$k exited before it was stopped"
  kill -TERM "$pid"
  wait_pid_timeout "$pid" 10 st
  ((st == 0)) || fail "worker w$k: exit status $st after SIGTERM (want 0)"
done
say "workers stopped"
tr '\r' '\n' <"$srv_log" | sed 's/\x1b\[K//g' |
  grep -E 'joined|left;|requeued|authentication|dropped|done in' | sed 's/^/    /' || true
grep -E 'connected to|lost|retrying' "$T/w1.log" | sed 's/^/    /' || true
"$PT_BIN/ptexr-diff" "$T/ref.exr" "$T/farm.exr" || fail "farm.exr differs from the reference"
say "PASS: farm.exr is bit-identical to the reference"
