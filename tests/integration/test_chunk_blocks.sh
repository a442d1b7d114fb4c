#!/usr/bin/env bash
# A --chunk that is not a multiple of 16 is rounded up to one, by ptserve and
# by ptworker, and says so: a task that ended inside a 16-sample block had
# that block's two parts rounded to fixed point apart, and the image's last
# bits then depended on the chunk. With the rounding, the farm at --chunk 8
# and ptworker at --chunk 24 give the standalone default's bits exactly.
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
tmp=$(mktemp -d /tmp/pt_chunk_blocks_XXXXXX)
trap 'rm -rf "$tmp"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
scene=$src/scenes/cornell_box.gltf
common=(--res 32x32 --spp 64 --tile 16 -q)

"$bin/ptworker" --scene "$scene" "${common[@]}" -o "$tmp/ref.exr"
"$bin/ptserve" --local 2 --worker-threads 1 --chunk 8 "${common[@]}" -o "$tmp/farm.exr" \
  "$scene" 2> "$tmp/serve.log"
grep -q -- "--chunk 8 rounded up to 16" "$tmp/serve.log" || fail "ptserve: $(cat "$tmp/serve.log")"
"$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/farm.exr" > "$tmp/diff1" ||
  fail "the farm at --chunk 8: $(cat "$tmp/diff1")"
"$bin/ptworker" --scene "$scene" "${common[@]}" --chunk 24 -o "$tmp/w24.exr" 2> "$tmp/w.log"
grep -q -- "--chunk 24 rounded up to 32" "$tmp/w.log" || fail "ptworker: $(cat "$tmp/w.log")"
"$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/w24.exr" > "$tmp/diff2" ||
  fail "ptworker at --chunk 24: $(cat "$tmp/diff2")"
echo "PASS"
