#!/usr/bin/env bash
# ptctl submit --transparent against a real ptserve queue (--state-dir, local
# workers), under a uniform --background that escaping camera rays would see:
# the fetched image has the A channel and is bit-identical (R, G, B, samples,
# A) to the standalone --transparent render, so the film flags and the
# environment both reach the workers; a job whose paths reach
# the depth cap (the closed white furnace with --max-depth 2) shows the exact
# count in `ptctl status`, which says nothing of it otherwise.
set -euo pipefail
# shellcheck source=tests/integration/lib_farm.sh
. "$(dirname "$0")/lib_farm.sh"
farm_init transparent_ctl
serve serve.log
workers 2
ctl() { "$bin/ptctl" "$@"; }

view=(--res 64x16 --spp 16 --seed 5 --background "0.25,0.5,1")
id=$(ctl submit "$src/scenes/cornell_box.gltf" "${view[@]}" --transparent)
ctl watch "$id" 2> /dev/null || fail "watch exited $?"
ctl fetch "$id" -o "$tmp/farm.exr"
"$bin/ptworker" --scene "$src/scenes/cornell_box.gltf" "${view[@]}" --tile 16 --chunk 8 \
  --transparent -q -o "$tmp/ref.exr"
"$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/farm.exr" > "$tmp/diff.txt" ||
  fail "fetched image differs: $(cat "$tmp/diff.txt")"
grep -q "samples A bit for bit" "$tmp/diff.txt" || fail "no A channel: $(cat "$tmp/diff.txt")"
ctl status "$id" > "$tmp/status.txt"
! grep -q "depth cap" "$tmp/status.txt" || fail "a depth cap shown: $(cat "$tmp/status.txt")"
# Without --transparent the farm's image has no A channel (ptexr-diff tells).
opaque=$(ctl submit "$src/scenes/cornell_box.gltf" "${view[@]}")
ctl watch "$opaque" 2> /dev/null || fail "watch exited $?"
ctl fetch "$opaque" -o "$tmp/opaque.exr"
set +e
"$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/opaque.exr" > "$tmp/diff2.txt"; rc=$?
set -e
if [ "$rc" != 1 ] || ! grep -q "A channel" "$tmp/diff2.txt"; then
  fail "opaque job: $(cat "$tmp/diff2.txt")"
fi

cap=$(ctl submit "$src/scenes/furnace.gltf" --res 8x8 --spp 16 --max-depth 2)
ctl watch "$cap" 2> /dev/null || fail "watch exited $?"
ctl status "$cap" > "$tmp/cap.txt"
grep -q "depth cap  1024 paths reached it" "$tmp/cap.txt" || fail "status: $(cat "$tmp/cap.txt")"
ctl status "$cap" --json > "$tmp/cap.json"
grep -q '"paths_capped": 1024,' "$tmp/cap.json" || fail "status --json: $(cat "$tmp/cap.json")"
# After a restart the finished job keeps its count (the queue file has it).
restart_server serve.log
ctl status "$cap" > "$tmp/cap2.txt"
grep -q "depth cap  1024 paths reached it" "$tmp/cap2.txt" || fail "after restart: $(cat "$tmp/cap2.txt")"
failed=0
echo "ok: ptctl submit --transparent and the depth-cap count"
