#!/usr/bin/env bash
# --denoise on the farm: the coordinator denoises the merged image off its
# event loop (its writer thread), so the farm's EXR - beauty, passes and
# the layer denoised.R/G/B - equals ptworker --denoise's bit for bit:
#  1. one-job ptserve --local 2 --denoise, and with --max-denoise-mb under
#     what the frame needs (denoised in regions), ptserve's and ptworker's;
#  2. one-job --denoise-progressive: progressive saves (taken while the job
#     runs) carry a denoised layer too, which is ptdenoise's of the same
#     save bit for bit, and the finished image is still the standalone one;
#  3. ptctl submit --denoise through a queue with two workers, one killed
#     (-9) while it holds tasks, which are requeued; while the finished
#     image is denoised the job's status says so, with its progress;
#  4. ptctl submit --denoise-progressive, the coordinator killed (-9)
#     mid-job with checkpoints written often and restarted: the job resumes
#     and its image is still the standalone one, the PNG preview the
#     denoised layer's.
# A queue refuses --denoise of its own (queued jobs ask with ptctl submit).
set -euo pipefail
# shellcheck source=tests/integration/lib_farm.sh
. "$(dirname "$0")/lib_farm.sh"
farm_init denoise_farm

same() { # NAME: its EXR is the reference's, every layer, the denoised one too
  "$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/$1.exr" > "$tmp/$1.diff" || fail "$1: $(cat "$tmp/$1.diff")"
  grep -q "denoised" "$tmp/$1.exr" || fail "$1: no denoised layer"
}
samples_of() { # EXR: its header's ptfarm.samples (a string attribute)
  python3 - "$1" << 'PY'
import struct, sys
h = open(sys.argv[1], "rb").read(65536)
k = h.index(b"ptfarm.samples\0string\0") + len(b"ptfarm.samples\0string\0")
n = struct.unpack("<i", h[k:k + 4])[0]
print(int(h[k + 4:k + 4 + n].decode()))
PY
}

# 1. One job.
view=(--res 40x32 --spp 32 --seed 3 --denoise)
"$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --chunk 8 -q -o "$tmp/ref.exr" 2> /dev/null
"$bin/ptserve" --local 2 --worker-threads 1 --tile 16 --chunk 8 "${view[@]}" -o "$tmp/one.exr" \
  "$scene" 2> "$tmp/one.log" || fail "one-job ptserve: $(cat "$tmp/one.log")"
same one
cmp -s "$tmp/ref.png" "$tmp/one.png" || fail "one-job: the preview is not the denoised layer's"
# With --max-denoise-mb under what the frame needs (35 MiB at 1024x80), the
# coordinator denoises it in two regions: the same bits. The release build
# only: a sanitizer build denoises ten times slower, and test_denoise checks
# the regions' code under the sanitizers.
if ! sanitized; then
  view=(--res 1024x80 --spp 4 --seed 3 --denoise)
  "$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --chunk 8 -q -o "$tmp/ref.exr" 2> /dev/null
  "$bin/ptserve" --local 2 --worker-threads 1 --tile 16 --chunk 8 "${view[@]}" \
    --max-denoise-mb 32 -o "$tmp/cut.exr" "$scene" 2> "$tmp/cut.log" ||
    fail "--max-denoise-mb: $(cat "$tmp/cut.log")"
  grep -q "denoised in regions of" "$tmp/cut.log" || fail "--max-denoise-mb 32: no regions"
  same cut
  "$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --chunk 8 --max-denoise-mb 32 \
    -o "$tmp/wcut.exr" 2> "$tmp/wcut.log" || fail "ptworker --max-denoise-mb: $(cat "$tmp/wcut.log")"
  grep -q "denoised in regions of" "$tmp/wcut.log" || fail "ptworker --max-denoise-mb 32: no regions"
  same wcut
fi
rc=0
"$bin/ptworker" --scene "$scene" --max-denoise-mb 64 -o "$tmp/w.exr" 2> /dev/null || rc=$?
[ "$rc" = 2 ] || fail "ptworker took --max-denoise-mb without --denoise (exit $rc)"
rc=0
"$bin/ptserve" --state-dir "$tmp/x" --denoise 2> "$tmp/refused.err" || rc=$?
if [ "$rc" != 2 ] || ! grep -q "ptctl submit --denoise" "$tmp/refused.err"; then
  fail "a queue took --denoise: exit $rc: $(cat "$tmp/refused.err")"
fi
rc=0
"$bin/ptserve" --state-dir "$tmp/x" --denoise-progressive 2> "$tmp/refused.err" || rc=$?
if [ "$rc" != 2 ] || ! grep -q "ptctl submit --denoise-progressive" "$tmp/refused.err"; then
  fail "a queue took --denoise-progressive: exit $rc: $(cat "$tmp/refused.err")"
fi
rc=0
"$bin/ptworker" --scene "$scene" --denoise-progressive -o "$tmp/w.exr" 2> /dev/null || rc=$?
[ "$rc" = 2 ] || fail "ptworker took --denoise-progressive (exit $rc): its saves are not progressive"

# 2. Progressive saves denoised: copies of the output taken while it runs
# (half as many samples in a sanitizer build, which renders them slower).
view=(--res 48x32 --spp "$(sanitized_spp 2048)" --seed 3)
"$bin/ptworker" --scene "$scene" "${view[@]}" --denoise --tile 16 --chunk 8 -q \
  -o "$tmp/ref.exr" 2> /dev/null
"$bin/ptserve" --local 2 --worker-threads 1 --tile 16 --chunk 8 --save-interval 0 "${view[@]}" \
  --denoise-progressive -o "$tmp/prog.exr" "$scene" 2> "$tmp/prog.log" &
srv_pid=$!
snaps=0
while kill -0 "$srv_pid" 2> /dev/null; do
  if [ -f "$tmp/prog.exr" ] && ! cmp -s "$tmp/prog.exr" "$tmp/snap$snaps.exr" 2> /dev/null; then
    snaps=$((snaps + 1))
    cp "$tmp/prog.exr" "$tmp/snap$snaps.exr"
  fi
  sleep 0.02
done
wait "$srv_pid" || fail "one-job --denoise-progressive: $(cat "$tmp/prog.log")"
srv_pid=
same prog
final=$(samples_of "$tmp/prog.exr")
checked=0
for ((k = 1; k <= snaps; k++)); do
  s=$(samples_of "$tmp/snap$k.exr")
  [ "$s" -lt "$final" ] || continue
  grep -q "denoised" "$tmp/snap$k.exr" || fail "progressive save $k ($s samples) has no denoised layer"
  "$bin/ptdenoise" "$tmp/snap$k.exr" -o "$tmp/snap${k}_dn.exr" --no-preview 2> /dev/null
  "$bin/ptexr-diff" "$tmp/snap$k.exr" "$tmp/snap${k}_dn.exr" > "$tmp/snap$k.diff" ||
    fail "progressive save $k: its denoised layer is not ptdenoise's: $(cat "$tmp/snap$k.diff")"
  checked=$((checked + 1))
done
echo "progressive saves: $snaps taken, $checked before the end checked"
[ "$checked" -gt 0 ] || fail "no progressive save seen before the end ($snaps copies)"

# 3. A queue, one of two workers killed while it renders.
view=(--res 40x32 --spp 512 --seed 3 --denoise)
"$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --chunk 8 -q -o "$tmp/ref.exr" 2> /dev/null
serve serve1.log PTSERVE_TEST_DENOISE_GATE="$tmp/denoise_gate"
workers 2
id=$("$bin/ptctl" submit "$scene" "${view[@]}" --name killed-worker)
until_status "$id" 'd["samples_done"] > 0'
kill_worker
# Once every sample is merged the status says the image is being denoised
# (held there by the test hook until the gate file exists).
until_status "$id" 'd["message"].startswith("denoising the image: ")'
[ "$(json "$tmp/status.json" 'd["state"]')" = running ] || fail "denoising: the job is not running"
touch "$tmp/denoise_gate"
finish "$id" worker_killed
stop_workers
stop_server

# 4. A queue whose coordinator is killed mid-job and restarted.
view=(--res 40x32 --spp 1024 --seed 3)
"$bin/ptworker" --scene "$scene" "${view[@]}" --denoise --tile 16 --chunk 8 -q \
  -o "$tmp/ref.exr" 2> /dev/null
port=0
# No task past 512 spp is leased before the kill (the gate never opens), so
# the job cannot end first however loaded the machine; the restarted
# coordinator has no gate and finishes it.
serve serve2.log PTSERVE_TEST_CKPT_LOG_BYTES=40000 PTSERVE_TEST_LEASE_GATE="512:$tmp/never"
workers 2
id=$("$bin/ptctl" submit "$scene" "${view[@]}" --denoise-progressive --name denoised)
until_status "$id" 'd["samples_done"] > 0 or d["state"] != "running"'
hold_workers
status "$id"
[ "$(json "$tmp/status.json" 'd["state"]')" = running ] || fail "the job ended before the kill"
stop_server -9
release_workers
serve serve2.log # the same port: the workers reconnect to it
finish "$id" server_killed
cmp -s "$tmp/ref.png" "$tmp/out/$id-denoised.png" ||
  fail "queued: the preview is not the denoised layer's"
failed=0
echo "denoise farm: ok"
