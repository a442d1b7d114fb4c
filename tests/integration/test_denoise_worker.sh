#!/usr/bin/env bash
# ptworker --denoise: the EXR keeps the beauty bit for bit (as a render
# without it) and gains the layer denoised.R/G/B, the same bits as
# ptdenoise gives on a render with --passes albedo,normal,depth,halves (on
# another thread count), and the PNG preview is the denoised layer's;
# fewer than 2 samples a pixel is refused before rendering.
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
tmp=$(mktemp -d /tmp/pt_denoise_worker_XXXXXX)
cleanup() { if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "files kept in $tmp" >&2; fi; }
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }
scene=$src/scenes/cornell_box.gltf
view=(--scene "$scene" --res 48x40 --spp 16 --seed 4 -q)

"$bin/ptworker" "${view[@]}" --threads 2 --denoise -o "$tmp/dn.exr" 2> "$tmp/dn.log" ||
  fail "--denoise: $(cat "$tmp/dn.log")"
grep -q "denoised in" "$tmp/dn.log" || fail "no denoising said: $(cat "$tmp/dn.log")"
"$bin/ptworker" "${view[@]}" --threads 1 -o "$tmp/plain.exr" 2> /dev/null
"$bin/ptexr-diff" --base "$tmp/plain.exr" "$tmp/dn.exr" > /dev/null ||
  fail "--denoise changed the beauty"
"$bin/ptworker" "${view[@]}" --threads 1 --passes albedo,normal,depth,halves \
  -o "$tmp/passes.exr" 2> /dev/null
"$bin/ptdenoise" "$tmp/passes.exr" -o "$tmp/tool.exr" --threads 1 2> "$tmp/tool.log" ||
  fail "ptdenoise: $(cat "$tmp/tool.log")"
"$bin/ptexr-diff" "$tmp/tool.exr" "$tmp/dn.exr" > "$tmp/diff.txt" ||
  fail "ptworker --denoise and ptdenoise differ: $(cat "$tmp/diff.txt")"
cmp -s "$tmp/tool.png" "$tmp/dn.png" || fail "the preview is not the denoised layer's"
if cmp -s "$tmp/plain.png" "$tmp/dn.png"; then fail "the preview is the raw beauty's"; fi

rc=0
"$bin/ptworker" --scene "$scene" --res 8x8 --spp 1 --denoise -o "$tmp/one.exr" 2> "$tmp/one.log" ||
  rc=$?
[ "$rc" = 2 ] || fail "--denoise --spp 1: status $rc, not 2"
grep -q "needs 2 samples a pixel" "$tmp/one.log" || fail "--spp 1: $(cat "$tmp/one.log")"
[ ! -e "$tmp/one.exr" ] || fail "--spp 1 wrote an image"

failed=0
echo "ok: ptworker --denoise keeps the beauty and equals ptdenoise, bit for bit"
