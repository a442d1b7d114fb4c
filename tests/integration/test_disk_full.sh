#!/usr/bin/env bash
# A full state folder and a full output folder, on real small filesystems
# (tmpfs in a private mount namespace), with a real ptserve queue and a real
# ptworker: the job pauses (no task leased, the reason in ptctl status, the
# pause logged once), survives a kill -9 while the disk is full, resumes by
# itself when space returns, keeps rendering while its progressive saves fail
# (logged once), waits "writing" while the final image cannot be written,
# and ends DONE with an image bit-identical to a standalone render.
#
# Needs mount namespaces (unshare -m as root, or unshare -Urm): without
# them the test is skipped (77), except with CI=true, where it must run.
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}

if [ "${PT_DISK_NS:-}" != 1 ]; then
  ns=()
  if [ "$(id -u)" = 0 ] && unshare -m true 2>/dev/null; then
    ns=(unshare -m)
  elif unshare -Urm true 2>/dev/null; then
    ns=(unshare -Urm)
  fi
  if [ ${#ns[@]} = 0 ]; then
    if [ "${CI:-}" = true ]; then
      echo "FAIL: no mount namespace here (unshare -m / -Urm), and CI=true" >&2
      exit 1
    fi
    echo "SKIP: no mount namespace (unshare -m / -Urm)" >&2
    exit 77
  fi
  PT_DISK_NS=1 exec "${ns[@]}" bash "$0" "$@"
fi

tmp=$(mktemp -d /tmp/pt_disk_full_XXXXXX)
srv_pid='' wrk_pid=''
cleanup() {
  for p in $wrk_pid $srv_pid; do
    kill -CONT "$p" 2>/dev/null || true
    if kill -9 "$p" 2>/dev/null; then wait "$p" 2>/dev/null || true; fi
  done
  umount "$tmp/state" "$tmp/out" 2>/dev/null || true
  if [ "${failed:-0}" = 0 ] && [ -z "${PT_KEEP_LOGS:-}" ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}
trap cleanup EXIT
failed=1
fail() {
  echo "FAIL: $*" >&2
  tail -n 30 "$tmp"/serve*.log >&2 || true
  exit 1
}
json() { python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))" "$@"; }

mkdir -p "$tmp/state" "$tmp/out" "$tmp/cache"
# The mounts are private to this namespace: nothing outlives the test.
mount --make-rprivate / 2>/dev/null || true
if ! mount -t tmpfs -o size=32m tmpfs "$tmp/state" || ! mount -t tmpfs -o size=4m tmpfs "$tmp/out"; then
  if [ "${CI:-}" = true ]; then fail "cannot mount a tmpfs"; fi
  echo "SKIP: cannot mount a tmpfs here" >&2
  failed=0
  exit 77
fi

# 192 tasks of 32 passes: the worker is held after the first result merges,
# so that the job is still running when the folders fill. The first server
# leases no task past the first two passes (64 spp) until $tmp/lease_go
# exists (PTSERVE_TEST_LEASE_GATE), so however loaded the machine the job
# cannot end before the folders are full.
spp=512
view=(--res 64x48 --spp "$spp" --seed 5)
serve() { # $1: log file, then VAR=VAL... for ptserve's environment
  local log=$1
  shift
  rm -f "$tmp/port"
  env "$@" "$bin/ptserve" --state-dir "$tmp/state" --output-dir "$tmp/out" --listen 127.0.0.1:0 \
    --port-file "$tmp/port" --tile 16 --chunk 32 --save-interval 0.2 -q 2>> "$log" &
  srv_pid=$!
  for _ in $(seq 200); do [ -s "$tmp/port" ] && break; sleep 0.05; done
  [ -s "$tmp/port" ] || fail "ptserve did not start"
  PTFARM_SERVER=127.0.0.1:$(cat "$tmp/port")
  export PTFARM_SERVER
}
work() {
  "$bin/ptworker" --server "$PTFARM_SERVER" --threads 1 --cache-dir "$tmp/cache" \
    2>> "$tmp/worker.log" &
  wrk_pid=$!
}
status() { "$bin/ptctl" status "$id" --json > "$tmp/status.json" 2>/dev/null; }
# Polls until the Python expression over the job's status (d) holds, or fails.
wait_for() { # $1: expression, $2: what it means
  local end=$((SECONDS + 120))
  while [ "$SECONDS" -lt "$end" ]; do
    if status && [ "$(json "$tmp/status.json" "$1")" = True ]; then return 0; fi
    sleep 0.05
  done
  fail "timed out waiting for: $2 (status: $(cat "$tmp/status.json" 2>/dev/null))"
}
fill() { # fills the folder $1 to the last byte
  dd if=/dev/zero of="$1/filler" bs=64k 2>/dev/null || true
  [ "$(df --output=avail "$1" | tail -1)" -le 4 ] || fail "$1 is not full"
}

serve "$tmp/serve1.log" PTSERVE_TEST_LEASE_GATE="64:$tmp/lease_go"
id=$("$bin/ptctl" submit "$src/scenes/cornell_box.gltf" "${view[@]}" --name disk)
work
wait_for 'd["samples_done"] > 0' "the first samples"
# The worker is held while both folders fill, so that the job is not done.
kill -STOP "$wrk_pid"
status
[ "$(json "$tmp/status.json" 'd["state"]')" = running ] || fail "the job ended before the folders filled"
fill "$tmp/state"
fill "$tmp/out"
touch "$tmp/lease_go"
kill -CONT "$wrk_pid"

# The state folder is full: the job pauses with the reason shown.
wait_for '"paused: state folder full" in d["message"] and d["state"] == "running"' "a pause"
status
done1=$(json "$tmp/status.json" 'd["samples_done"]')
sleep 1 # no more merging while paused
status
[ "$(json "$tmp/status.json" 'd["samples_done"]')" = "$done1" ] || fail "samples merged while paused"
[ "$(grep -c "paused" "$tmp/serve1.log")" = 1 ] || fail "the pause is not logged once"
grep -q "No space left on device" "$tmp/serve1.log" || fail "the reason is not logged"

# A crash while full: the job is resumed, not refused as damaged.
kill -9 "$srv_pid"
wait "$srv_pid" 2>/dev/null || true
kill -9 "$wrk_pid"
wait "$wrk_pid" 2>/dev/null || true
srv_pid='' wrk_pid=''
serve "$tmp/serve2.log"
grep -q "damaged\|refus" "$tmp/serve2.log" && fail "the job was refused after the restart"
work
wait_for '"paused: state folder full" in d["message"]' "a pause after the restart"

# Space returns to the state folder: the job resumes by itself and renders
# to the end, but the output folder is full: it waits "writing".
rm "$tmp/state/filler"
wait_for '"writing: cannot write the image: output folder full" in d["message"]' \
  "the final image waiting"
[ "$(json "$tmp/status.json" 'd["state"]')" = running ] || fail "not running while writing"
grep -q "resumed: the state folder takes its writes again" "$tmp/serve2.log" ||
  fail "no resume logged"
[ "$(grep -c "cannot save its progressive image" "$tmp/serve2.log")" -le 1 ] ||
  fail "failed progressive saves logged more than once"
[ "$(grep -c "cannot write its image" "$tmp/serve2.log")" = 1 ] ||
  fail "the failed final image is not logged once"

# Space returns to the output folder: the image is written, the job done.
rm "$tmp/out/filler"
wait_for 'd["state"] == "done"' "the job done"
[ "$(json "$tmp/status.json" 'd["samples_done"]')" = $((64 * 48 * spp)) ] ||
  fail "samples: $(cat "$tmp/status.json")"
"$bin/ptworker" --scene "$src/scenes/cornell_box.gltf" "${view[@]}" --tile 16 --chunk 32 \
  --threads 2 -q -o "$tmp/ref.exr"
"$bin/ptctl" fetch "$id" -o "$tmp/fetched.exr"
"$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/fetched.exr" || fail "the image differs from a clean render"
"$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/out/$id-disk.exr" || fail "the output folder's image differs"
failed=0
echo "PASS"
