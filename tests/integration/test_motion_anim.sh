#!/usr/bin/env bash
# Motion blur of animated glTF files: BoxAnimated (node rotation and
# translation) and the Fox (a skin) render with --shutter, moving (the image
# differs from the still at the shutter's opening); a closed shutter
# (--shutter X,X) is bit for bit the still at t + X/fps; ptserve --local 2
# --shutter (tasks carry the shutter, workers pose the scene) equals ptworker
# --shutter, bit for bit.
set -euo pipefail
bin=${PT_BIN:?}
scenes=${PT_SHARED_SCENES:?}
box=$scenes/BoxAnimated/BoxAnimated.glb
fox=$scenes/Fox/Fox.glb
# shellcheck source=tests/integration/lib_shared.sh
. "$(dirname "$0")/lib_shared.sh"
need_shared "$box" "$fox"
tmp=$(mktemp -d /tmp/pt_motion_anim_XXXXXX)
cleanup() { if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi; }
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }
same() { "$bin/ptexr-diff" "$1" "$2" > /dev/null; }

view=(--res 40x30 --spp 8 --seed 5 --tile 16 --chunk 8 --background "1,1,1")
# BoxAnimated: a second of motion from t = 1 (fps 1: the shutter is [1, 2]).
"$bin/ptworker" --scene "$box" "${view[@]}" --time 1 --shutter 0,1 --fps 1 -o "$tmp/blur.exr" \
  2> "$tmp/blur.log" || fail "BoxAnimated --shutter: $(cat "$tmp/blur.log")"
grep -q "nothing in the scene moves" "$tmp/blur.log" && fail "BoxAnimated does not move"
"$bin/ptworker" --scene "$box" "${view[@]}" --time 1 -o "$tmp/still.exr"
same "$tmp/blur.exr" "$tmp/still.exr" && fail "the blurred box equals its still"
# A closed shutter at 0.5 of a frame at 4 fps: the still at 1.125 s.
"$bin/ptworker" --scene "$box" "${view[@]}" --time 1 --shutter 0.5,0.5 --fps 4 \
  -o "$tmp/closed.exr"
"$bin/ptworker" --scene "$box" "${view[@]}" --time 1.125 -o "$tmp/still1125.exr"
same "$tmp/closed.exr" "$tmp/still1125.exr" || fail "--shutter 0.5,0.5 is not the still at 1.125 s"

# The farm: frame time 0, the shutter [0, 1] s.
"$bin/ptworker" --scene "$box" "${view[@]}" --shutter 0,1 --fps 1 -o "$tmp/blur0.exr"
"$bin/ptworker" --scene "$box" "${view[@]}" --time 0 -o "$tmp/still0.exr"
same "$tmp/blur0.exr" "$tmp/still0.exr" && fail "the blurred box at 0 equals its still"
"$bin/ptserve" --local 2 --worker-threads 1 "${view[@]}" --shutter 0,1 --fps 1 \
  -o "$tmp/farm.exr" "$box" 2> "$tmp/farm.log" || fail "ptserve --shutter: $(cat "$tmp/farm.log")"
same "$tmp/blur0.exr" "$tmp/farm.exr" || fail "ptserve --local 2 --shutter differs from ptworker"

# The Fox: a skinned mesh blurs too.
"$bin/ptworker" --scene "$fox" "${view[@]}" --time 1 --shutter 0,0.5 --fps 2 -o "$tmp/fox.exr" \
  2> "$tmp/fox.log" || fail "Fox --shutter: $(cat "$tmp/fox.log")"
grep -q "nothing in the scene moves" "$tmp/fox.log" && fail "the Fox does not move"
"$bin/ptworker" --scene "$fox" "${view[@]}" --time 1 -o "$tmp/fox_still.exr"
same "$tmp/fox.exr" "$tmp/fox_still.exr" && fail "the blurred Fox equals its still"
failed=0
echo "ok: BoxAnimated and the Fox blur; a closed shutter is the still; the farm equals standalone"
