#!/usr/bin/env bash
# ptworker --passes (common/render/passes.h): the EXR gets the layers asked
# for and the beauty keeps its bits; the passes are the same bits however
# the image is cut into tiles and chunks and however many threads render it;
# a bad list is refused with exit 2 before anything is written.
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
scene=$src/scenes/cornell_box.gltf
tmp=$(mktemp -d /tmp/pt_passes_cli_XXXXXX)
cleanup() { if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi; }
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }

view=(--res 48x32 --spp 32 --seed 3)
"$bin/ptworker" --scene "$scene" "${view[@]}" -q -o "$tmp/plain.exr" 2> /dev/null
"$bin/ptworker" --scene "$scene" "${view[@]}" -q --passes all -o "$tmp/all.exr" 2> /dev/null
"$bin/ptworker" --scene "$scene" "${view[@]}" -q --passes all --tile 8 --chunk 16 --threads 1 \
  -o "$tmp/split.exr" 2> /dev/null
"$bin/ptworker" --scene "$scene" "${view[@]}" -q --passes depth,albedo -o "$tmp/two.exr" \
  2> /dev/null
# The beauty without passes and with them: the same bits.
"$bin/ptexr-diff" --base "$tmp/plain.exr" "$tmp/all.exr" > "$tmp/d1.txt" ||
  fail "the beauty changed with --passes: $(cat "$tmp/d1.txt")"
# Every pass's 52 channels (20, and 32 of Cryptomatte), the same bits for another split.
"$bin/ptexr-diff" "$tmp/all.exr" "$tmp/split.exr" > "$tmp/d2.txt" ||
  fail "the passes depend on the split: $(cat "$tmp/d2.txt")"
grep -q "and 52 named channels" "$tmp/d2.txt" || fail "not every pass written: $(cat "$tmp/d2.txt")"
# Only the passes asked for: albedo (3 + variance) and depth (Z + variance).
set +e
"$bin/ptexr-diff" "$tmp/two.exr" "$tmp/all.exr" > "$tmp/d3.txt"; rc=$?
set -e
if [ "$rc" != 1 ] || ! grep -q "only in B" "$tmp/d3.txt"; then
  fail "two passes: $(cat "$tmp/d3.txt")"
fi
"$bin/ptexr-diff" "$tmp/two.exr" "$tmp/two.exr" | grep -q "and 6 named channels" ||
  fail "--passes depth,albedo does not write 6 channels"
for bad in "" "albedo," "normals" "all,z"; do
  rc=0
  "$bin/ptworker" --scene "$scene" "${view[@]}" --passes "$bad" -o "$tmp/bad.exr" \
    2> "$tmp/bad.err" || rc=$?
  [ "$rc" = 2 ] || fail "--passes '$bad': exit $rc"
  grep -q "is not a comma-separated list of albedo, normal" "$tmp/bad.err" ||
    fail "--passes '$bad': $(cat "$tmp/bad.err")"
  [ ! -e "$tmp/bad.exr" ] || fail "--passes '$bad' wrote an image"
done
failed=0
echo "passes cli: ok"
