#!/usr/bin/env bash
# ptserve one-job mode: the output's format follows its name, as ptworker's.
# -o NAME.png writes the PNG alone (RGBA with --transparent; a frame range's
# pattern too); NAME.exr an EXR with its preview beside it, and --view and
# --exposure change only that preview (the EXR is the same bits). Every
# refusal that could come at the end comes first: a name of no known
# format, a missing output folder, a missing --env map, a frame range
# without a '#' run, an unknown view; each exits before the scene is loaded
# (no "triangles" line) and before any worker joins (no sample rendered).
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
scene=$src/scenes/cornell_box.gltf
tmp=$(mktemp -d /tmp/pt_serve_outputs_XXXXXX)
cleanup() { if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi; }
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }

one=("$bin/ptserve" --local 1 --worker-threads 1 --res 24x16 --spp 8 --seed 3)
# $1: exit status wanted, $2: what stderr must say, then ptserve's arguments.
refused() {
  local want=$1 say=$2 rc=0
  shift 2
  "${one[@]}" "$@" > "$tmp/bad.log" 2>&1 || rc=$?
  [ "$rc" = "$want" ] || fail "$* -> exit $rc, want $want: $(cat "$tmp/bad.log")"
  grep -q -- "$say" "$tmp/bad.log" || fail "$*: no '$say': $(cat "$tmp/bad.log")"
  if grep -q "triangles\|joined\|started" "$tmp/bad.log"; then
    fail "$*: refused only after the scene loaded or a worker started: $(cat "$tmp/bad.log")"
  fi
}
refused 2 "follows its name: .exr" -o "$tmp/x.jpg" "$scene"
refused 2 "follows its name" -o "$tmp/x" "$scene"
refused 1 "cannot create its temporary file" -o "$tmp/none/x.png" "$scene"
refused 1 "missing.hdr" --env "$tmp/missing.hdr" -o "$tmp/x.exr" "$scene"
refused 2 "needs a '#'" --frames 0-1 -o "$tmp/x.png" "$scene"
refused 2 "standard, filmic or agx" --view aces -o "$tmp/x.exr" "$scene"
refused 2 "--exposure" --exposure 99 -o "$tmp/x.exr" "$scene"
if ls "$tmp"/x* > /dev/null 2>&1; then fail "a refused job wrote a file: $(ls "$tmp")"; fi

png_type() { od -An -tu1 -j25 -N1 "$1" | tr -d ' '; } # IHDR colour type: 2 RGB, 6 RGBA
is_png() { [ "$(head -c 8 "$1" | od -An -tx1 | tr -d ' \n')" = 89504e470d0a1a0a ]; }

# A .png output: the PNG alone, RGBA when transparent.
"${one[@]}" -q -o "$tmp/a.png" "$scene" 2> "$tmp/a.log" || fail "a.png: $(cat "$tmp/a.log")"
is_png "$tmp/a.png" || fail "a.png is not a PNG"
[ "$(png_type "$tmp/a.png")" = 2 ] || fail "a.png: colour type $(png_type "$tmp/a.png")"
if [ -e "$tmp/a.exr" ] || [ -e "$tmp/a.png.png" ]; then fail "a .png output wrote more: $(ls "$tmp")"; fi
"${one[@]}" -q --transparent -o "$tmp/t.png" "$scene" 2> "$tmp/t.log" || fail "t.png: $(cat "$tmp/t.log")"
[ "$(png_type "$tmp/t.png")" = 6 ] || fail "transparent PNG: colour type $(png_type "$tmp/t.png")"
# A frame range to PNGs: each frame's PNG by the pattern, no EXR.
"${one[@]}" -q --frames 0-1 -o "$tmp/f.#.png" "$scene" 2> "$tmp/f.log" || fail "frames: $(cat "$tmp/f.log")"
is_png "$tmp/f.0.png" || fail "frames: $(ls "$tmp")"
is_png "$tmp/f.1.png" || fail "frames: $(ls "$tmp")"
if ls "$tmp"/f.*.exr > /dev/null 2>&1; then fail "a .png frame range wrote EXRs"; fi

# An .exr output: --view and --exposure change the preview, not the EXR.
"${one[@]}" -q -o "$tmp/s.exr" "$scene" 2> "$tmp/s.log" || fail "s.exr: $(cat "$tmp/s.log")"
"${one[@]}" -q --view agx --exposure 1 -o "$tmp/v.exr" "$scene" 2> "$tmp/v.log" ||
  fail "v.exr: $(cat "$tmp/v.log")"
"$bin/ptexr-diff" "$tmp/s.exr" "$tmp/v.exr" > "$tmp/diff.txt" ||
  fail "--view changed the EXR: $(cat "$tmp/diff.txt")"
is_png "$tmp/s.png" || fail "no preview beside s.exr: $(ls "$tmp")"
is_png "$tmp/v.png" || fail "no preview beside v.exr: $(ls "$tmp")"
if cmp -s "$tmp/s.png" "$tmp/v.png"; then fail "--view agx --exposure 1 left the preview as it was"; fi
# The standard preview is ptworker's, byte for byte (same view code, same pixels).
cmp -s "$tmp/s.png" "$tmp/a.png" || fail "the .exr's preview and the .png output differ"
failed=0
echo "ok"
