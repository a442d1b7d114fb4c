#!/usr/bin/env bash
# ptcontact-sheet: three 24x16 frames in rows of 2 make a PNG of
# 2*24+4 x 2*16+4 pixels (read from its IHDR); a frame of another size, a
# missing file and no -o fail with exit 2 and leave no file.
set -euo pipefail
bin=${PT_BIN:?}
scenes=${PT_SHARED_SCENES:?}
box=$scenes/BoxAnimated/BoxAnimated.glb
# shellcheck source=tests/integration/lib_shared.sh
. "$(dirname "$0")/lib_shared.sh"
need_shared "$box"
tmp=$(mktemp -d /tmp/pt_sheet_XXXXXX)
cleanup() { if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi; }
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }

view=(--res 24x16 --spp 1 --threads 1 -q --background "1,1,1")
for f in 0 12 24; do
  "$bin/ptworker" --scene "$box" "${view[@]}" --frame $f -o "$tmp/f$f.exr"
done
"$bin/ptworker" --scene "$box" --res 20x16 --spp 1 -q --background "1,1,1" -o "$tmp/other.exr"

"$bin/ptcontact-sheet" -o "$tmp/sheet.png" --cols 2 "$tmp/f0.exr" "$tmp/f12.exr" "$tmp/f24.exr" ||
  fail "three frames: exit $?"
# IHDR: width and height, big-endian, at bytes 16 and 20.
size=$(od -An -tu1 -j16 -N8 "$tmp/sheet.png" | awk '{print $1*16777216+$2*65536+$3*256+$4 "x" $5*16777216+$6*65536+$7*256+$8}')
[ "$size" = "52x36" ] || fail "sheet is $size, want 52x36"

# The previews' view transform and exposure: another image, same size.
"$bin/ptcontact-sheet" -o "$tmp/agx.png" --view agx --exposure -1 --cols 2 "$tmp/f0.exr" \
  "$tmp/f12.exr" "$tmp/f24.exr" || fail "--view agx: exit $?"
if cmp -s "$tmp/sheet.png" "$tmp/agx.png"; then fail "--view agx made the standard sheet"; fi
rc=0
"$bin/ptcontact-sheet" -o "$tmp/bad.png" --view aces "$tmp/f0.exr" 2> "$tmp/err" || rc=$?
[ "$rc" = 2 ] || fail "--view aces: exit $rc"
grep -q "standard, filmic or agx" "$tmp/err" || fail "--view aces: $(cat "$tmp/err")"
rc=0
"$bin/ptcontact-sheet" -o "$tmp/bad.png" "$tmp/f0.exr" "$tmp/other.exr" 2> "$tmp/err" || rc=$?
[ "$rc" = 2 ] || fail "mismatched size: exit $rc"
grep -q "not the first image's size" "$tmp/err" || fail "mismatched size: $(cat "$tmp/err")"
rc=0
"$bin/ptcontact-sheet" -o "$tmp/bad.png" "$tmp/f0.exr" "$tmp/missing.exr" 2> /dev/null || rc=$?
[ "$rc" = 2 ] || fail "missing file: exit $rc"
rc=0
"$bin/ptcontact-sheet" "$tmp/f0.exr" 2> /dev/null || rc=$?
[ "$rc" = 2 ] || fail "no -o: exit $rc"
[ ! -e "$tmp/bad.png" ] || fail "a failed sheet left a file"
failed=0
echo "ok"
