#!/usr/bin/env bash
# --denoise on the farm: the coordinator denoises the finished merged image
# off its event loop (its writer thread), so the farm's EXR - beauty, passes
# and the layer denoised.R/G/B - equals ptworker --denoise's bit for bit:
#  1. one-job ptserve --local 2 --denoise;
#  2. ptctl submit --denoise through a queue with two workers, the
#     coordinator killed (-9) mid-job and restarted: the job resumes and its
#     image is still the standalone one, the PNG preview the denoised layer's.
# A queue refuses --denoise of its own (queued jobs ask with ptctl submit).
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
scene=$src/scenes/cornell_box.gltf
tmp=$(mktemp -d /tmp/pt_denoise_farm_XXXXXX)
srv_pid=
wrk_pids=
cleanup() {
  for p in $wrk_pids; do kill "$p" 2>/dev/null || true; done
  if [ -n "$srv_pid" ] && kill "$srv_pid" 2>/dev/null; then wait "$srv_pid" 2>/dev/null || true; fi
  if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }
json() { python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))" "$@"; }
same() { # NAME: its EXR is the reference's, every layer, the denoised one too
  "$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/$1.exr" > "$tmp/$1.diff" || fail "$1: $(cat "$tmp/$1.diff")"
  grep -q "denoised" "$tmp/$1.exr" || fail "$1: no denoised layer"
}

# 1. One job.
view=(--res 40x32 --spp 32 --seed 3 --denoise)
"$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --chunk 8 -q -o "$tmp/ref.exr" 2> /dev/null
"$bin/ptserve" --local 2 --worker-threads 1 --tile 16 --chunk 8 "${view[@]}" -o "$tmp/one.exr" \
  "$scene" 2> "$tmp/one.log" || fail "one-job ptserve: $(cat "$tmp/one.log")"
same one
cmp -s "$tmp/ref.png" "$tmp/one.png" || fail "one-job: the preview is not the denoised layer's"
rc=0
"$bin/ptserve" --state-dir "$tmp/x" --denoise 2> "$tmp/refused.err" || rc=$?
if [ "$rc" != 2 ] || ! grep -q "ptctl submit --denoise" "$tmp/refused.err"; then
  fail "a queue took --denoise: exit $rc: $(cat "$tmp/refused.err")"
fi

# 2. A queue whose coordinator is killed mid-job and restarted.
view=(--res 40x32 --spp 1024 --seed 3 --denoise)
"$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --chunk 8 -q -o "$tmp/ref.exr" 2> /dev/null
port=0
serve() { # LOG: a queue on $port (0: any; kept for the restart)
  rm -f "$tmp/port"
  PTSERVE_TEST_CKPT_LOG_BYTES=40000 "$bin/ptserve" --state-dir "$tmp/state" \
    --output-dir "$tmp/out" --listen "127.0.0.1:$port" --port-file "$tmp/port" --tile 16 \
    --chunk 8 --lease-timeout 1 2>> "$tmp/$1" &
  srv_pid=$!
  for _ in $(seq 400); do [ -s "$tmp/port" ] && break; sleep 0.05; done
  [ -s "$tmp/port" ] || fail "ptserve did not start: $(cat "$tmp/$1")"
  port=$(cat "$tmp/port")
  PTFARM_SERVER=127.0.0.1:$port
  export PTFARM_SERVER
}
serve serve.log
for w in 1 2; do
  "$bin/ptworker" --server "$PTFARM_SERVER" --threads 1 --prefetch 2 --name "w$w" \
    --cache-dir "$tmp/cache$w" 2>> "$tmp/worker.log" &
  wrk_pids="$wrk_pids $!"
done
id=$("$bin/ptctl" submit "$scene" "${view[@]}" --name denoised)
status() { "$bin/ptctl" --timeout 20 status "$id" --json > "$tmp/status.json"; }
for _ in $(seq 1200); do
  status && [ "$(json "$tmp/status.json" 'd["samples_done"] > 0 or d["state"] != "running"')" = True ] &&
    break
  sleep 0.1
done
[ "$(json "$tmp/status.json" 'd["state"]')" = running ] || fail "the job ended before the kill"
kill -9 "$srv_pid"
wait "$srv_pid" 2> /dev/null || true
srv_pid=
serve serve.log # the same port: the workers reconnect to it
for _ in $(seq 1200); do
  status && [ "$(json "$tmp/status.json" 'd["state"]')" = done ] && break
  sleep 0.1
done
[ "$(json "$tmp/status.json" 'd["state"]')" = done ] || fail "not done: $(cat "$tmp/status.json")"
"$bin/ptctl" fetch "$id" -o "$tmp/queued.exr"
same queued
failed=0
echo "denoise farm: ok"
