#!/usr/bin/env bash
# ptworker --scene with glTF animation: --frame 36 --fps 24 (and --frame 36
# alone, 24 fps by default) is bit-identical to --time 1.5, and --animation 0
# (BoxAnimated's one animation) to playing all; the frame differs from the
# still (no animation options). Bad options and a file with a malformed
# sampler exit non-zero with the reason; that file still renders as a still
# without the options.
set -euo pipefail
bin=${PT_BIN:?}
scenes=${PT_SHARED_SCENES:?}
box=$scenes/BoxAnimated/BoxAnimated.glb
# shellcheck source=tests/integration/lib_shared.sh
. "$(dirname "$0")/lib_shared.sh"
need_shared "$box"
tmp=$(mktemp -d /tmp/pt_anim_cli_XXXXXX)
cleanup() { if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi; }
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }

view=(--res 40x30 --spp 8 --seed 5 --threads 2 -q --background "1,1,1")
"$bin/ptworker" --scene "$box" "${view[@]}" --time 1.5 -o "$tmp/time.exr"
"$bin/ptworker" --scene "$box" "${view[@]}" --frame 36 --fps 24 -o "$tmp/frame.exr"
"$bin/ptworker" --scene "$box" "${view[@]}" --frame 36 -o "$tmp/frame24.exr"
"$bin/ptworker" --scene "$box" "${view[@]}" --animation 0 --time 1.5 -o "$tmp/anim0.exr"
"$bin/ptworker" --scene "$box" "${view[@]}" -o "$tmp/still.exr"
"$bin/ptexr-diff" "$tmp/time.exr" "$tmp/frame.exr" > /dev/null || fail "--frame 36 --fps 24 != --time 1.5"
"$bin/ptexr-diff" "$tmp/time.exr" "$tmp/frame24.exr" > /dev/null || fail "--fps is not 24 by default"
"$bin/ptexr-diff" "$tmp/time.exr" "$tmp/anim0.exr" > /dev/null || fail "--animation 0 != all"
! "$bin/ptexr-diff" "$tmp/time.exr" "$tmp/still.exr" > /dev/null || fail "the frame at 1.5 s is the still"

# The Fox has three animations: a frame of it plays the first and says so
# once; --animation all plays them all at once (another image), --animation 0
# the first (the same bits, and nothing said).
fox=$scenes/Fox/Fox.glb
if [ -f "$fox" ]; then
  fview=(--res 24x24 --spp 2 --seed 5 --threads 2 --background "1,1,1" --time 1)
  "$bin/ptworker" --scene "$fox" "${fview[@]}" -o "$tmp/fox.exr" 2> "$tmp/fox.log"
  [ "$(grep -c "3 animations; playing the first, 0 'Survey'" "$tmp/fox.log")" = 1 ] ||
    fail "the Fox's first animation is not said once: $(cat "$tmp/fox.log")"
  "$bin/ptworker" --scene "$fox" "${fview[@]}" --animation 0 -o "$tmp/fox0.exr" 2> "$tmp/fox0.log"
  if grep -q "playing the first" "$tmp/fox0.log"; then fail "--animation 0 still said it"; fi
  "$bin/ptworker" --scene "$fox" "${fview[@]}" -q --animation all -o "$tmp/foxall.exr"
  "$bin/ptexr-diff" "$tmp/fox.exr" "$tmp/fox0.exr" > /dev/null || fail "the default is not animation 0"
  # A frame range on the farm: said by the coordinator and once by its
  # worker, not once a frame.
  "$bin/ptserve" --local 1 --worker-threads 1 --res 16x16 --spp 1 --background "1,1,1" \
    --frames 0-5 -o "$tmp/fox.#.png" "$fox" 2> "$tmp/foxes.log" || fail "frames: $(cat "$tmp/foxes.log")"
  [ "$(grep -c "playing the first" "$tmp/foxes.log")" = 2 ] ||
    fail "the first animation is not said once a process: $(grep "playing" "$tmp/foxes.log")"
  "$bin/ptworker" --list "$fox" > "$tmp/list.txt" || fail "--list: exit $?"
  grep -q "animations (3)" "$tmp/list.txt" || fail "--list: $(cat "$tmp/list.txt")"
  grep -q "1 'Walk': 21 channels, 0 to 0.708333 s" "$tmp/list.txt" || fail "--list: $(cat "$tmp/list.txt")"
  if "$bin/ptexr-diff" "$tmp/fox.exr" "$tmp/foxall.exr" > /dev/null; then
    fail "--animation all is the first alone"
  fi
else
  case "${CI:-}" in true | 1 | yes) fail "$fox is missing" ;; esac
fi

# Bad options: status 2 (arguments) or 1 (the scene refuses), with the reason.
expect() { # expect STATUS PATTERN ARGS...
  local want=$1 pat=$2 rc=0
  shift 2
  "$bin/ptworker" "${view[@]}" -o "$tmp/bad.exr" "$@" 2> "$tmp/err.log" || rc=$?
  [ "$rc" = "$want" ] || fail "$*: status $rc, not $want: $(cat "$tmp/err.log")"
  grep -q -- "$pat" "$tmp/err.log" || fail "$*: no '$pat' in: $(cat "$tmp/err.log")"
}
expect 1 "no animation 'Nope'; animations: 0 ''" --scene "$box" --animation Nope
expect 1 "no animation '3'" --scene "$box" --animation 3 --time 1
expect 2 "'-1' is not a number" --scene "$box" --time -1
expect 2 "'nan' is not a number" --scene "$box" --time nan
expect 2 "give one" --scene "$box" --time 1 --frame 2
expect 2 "needs --frame" --scene "$box" --fps 30

# A malformed sampler: times out of order.
python3 - "$tmp/bad.gltf" <<'PY'
import base64, json, struct, sys
data = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0) + struct.pack("<3f", 0, 1, 0.5) \
    + struct.pack("<9f", 0, 0, 0, 1, 0, 0, 2, 0, 0)
d = {"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
     "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
     "animations": [{"name": "Slide", "channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}}],
                     "samplers": [{"input": 1, "output": 2}]}],
     "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
                   {"bufferView": 1, "componentType": 5126, "count": 3, "type": "SCALAR"},
                   {"bufferView": 2, "componentType": 5126, "count": 3, "type": "VEC3"}],
     "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
                     {"buffer": 0, "byteOffset": 36, "byteLength": 12},
                     {"buffer": 0, "byteOffset": 48, "byteLength": 36}],
     "buffers": [{"byteLength": len(data),
                  "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode()}]}
json.dump(d, open(sys.argv[1], "w"))
PY
expect 1 "animation 0 ('Slide') sampler 0: input times are not increasing at key 2" \
  --scene "$tmp/bad.gltf" --time 0.5
"$bin/ptworker" --scene "$tmp/bad.gltf" "${view[@]}" -o "$tmp/bad_still.exr" ||
  fail "the malformed file does not render as a still"
failed=0
echo "ok"
