#!/usr/bin/env bash
# --shutter on the farm: ptctl submit --shutter and ptserve --shutter (one-job
# mode, local workers) give the image ptworker --scene ... --shutter gives, bit
# for bit, for a shutter of a quarter to three quarters of a frame at 30 fps;
# a malformed shutter (not two numbers, open after close, outside [0, 1]) is
# refused by all three with a non-zero exit and the rule it breaks, and queue
# mode refuses ptserve's own --shutter (a queued job asks with ptctl). A
# frame-range job with a shutter (BoxAnimated, ptctl submit --frames and
# ptserve --frames) blurs each frame over its own shutter: frame F is bit for
# bit ptworker --scene ... --frame F --fps R --shutter O,C, not the shutter
# at time 0.
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
tmp=$(mktemp -d /tmp/pt_shutter_ctl_XXXXXX)
srv_pid=
cleanup() {
  if [ -n "$srv_pid" ] && kill "$srv_pid" 2>/dev/null; then wait "$srv_pid" 2>/dev/null || true; fi
  if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }

scene=$src/scenes/cornell_box.gltf
view=(--res 48x32 --spp 16 --seed 5)
shutter=(--shutter "0.25,0.75" --fps 30)
"$bin/ptworker" --scene "$scene" "${view[@]}" "${shutter[@]}" --tile 16 --chunk 8 -q \
  -o "$tmp/ref.exr" 2> "$tmp/ref.log" || fail "ptworker --shutter: $(cat "$tmp/ref.log")"

# Refusals: each names the rule and exits 2, before anything runs.
expect_refusal() { # WHAT LOG PATTERN CMD...
  local what=$1 log=$2 pattern=$3
  shift 3
  set +e
  "$@" 2> "$log"
  local rc=$?
  set -e
  if [ $rc != 2 ] || ! grep -q -- "$pattern" "$log"; then
    fail "$what: rc $rc: $(cat "$log")"
  fi
}
for bad in 0.5 0.5,0.25 0,1.5 -0.1,0.5 a,b 0,0.5,1; do
  case $bad in
  0.5,0.25) why="after it closes" ;;
  0,1.5 | -0.1,0.5) why="\[0, 1\]" ;;
  *) why="OPEN,CLOSE" ;;
  esac
  expect_refusal "ptworker --shutter $bad" "$tmp/w.log" "$why" \
    "$bin/ptworker" --scene "$scene" -o "$tmp/x.exr" --shutter="$bad"
  expect_refusal "ptserve --shutter $bad" "$tmp/s.log" "$why" \
    "$bin/ptserve" --local 1 -o "$tmp/x.exr" --shutter="$bad" "$scene"
  expect_refusal "ptctl submit --shutter $bad" "$tmp/c.log" "$why" \
    "$bin/ptctl" --server 127.0.0.1:1 submit "$scene" --shutter="$bad"
done
expect_refusal "ptctl submit --fps 0" "$tmp/c.log" "--fps" \
  "$bin/ptctl" --server 127.0.0.1:1 submit "$scene" --shutter 0,0.5 --fps 0
expect_refusal "ptserve --state-dir --shutter" "$tmp/q.log" "one-job mode" \
  "$bin/ptserve" --state-dir "$tmp/qstate" --listen 127.0.0.1:0 --shutter 0,0.5

"$bin/ptserve" --state-dir "$tmp/state" --output-dir "$tmp/out" --listen 127.0.0.1:0 \
  --port-file "$tmp/port" --local 2 --worker-threads 1 --tile 16 --chunk 8 2> "$tmp/serve.log" &
srv_pid=$!
for _ in $(seq 100); do [ -s "$tmp/port" ] && break; sleep 0.05; done
[ -s "$tmp/port" ] || fail "ptserve did not start: $(cat "$tmp/serve.log")"
PTFARM_SERVER=127.0.0.1:$(cat "$tmp/port")
export PTFARM_SERVER
job=$("$bin/ptctl" submit "$scene" "${view[@]}" "${shutter[@]}")
"$bin/ptctl" watch "$job" 2> /dev/null || fail "watch exited $?"
"$bin/ptctl" fetch "$job" -o "$tmp/queued.exr"
"$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/queued.exr" || fail "ptctl submit --shutter image differs"

"$bin/ptserve" --local 2 --worker-threads 1 "${view[@]}" "${shutter[@]}" --tile 16 --chunk 8 -q \
  -o "$tmp/local.exr" "$scene" 2> "$tmp/local.log" ||
  fail "ptserve --local --shutter: $(cat "$tmp/local.log")"
"$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/local.exr" || fail "ptserve --shutter image differs"

# Frame ranges with a shutter: one --fps times the frames and the shutter.
box=${PT_SHARED_SCENES:-$src/../shared/scenes}/BoxAnimated/BoxAnimated.glb
if [ -f "$box" ]; then
  bview=(--res 40x30 --spp 16 --seed 3 --background "1,1,1")
  "$bin/ptworker" --scene "$box" "${bview[@]}" --frame 3 "${shutter[@]}" --tile 16 --chunk 8 -q \
    -o "$tmp/box_ref3.exr" 2> "$tmp/box_ref.log" ||
    fail "ptworker --frame --shutter: $(cat "$tmp/box_ref.log")"
  "$bin/ptworker" --scene "$box" "${bview[@]}" "${shutter[@]}" --tile 16 --chunk 8 -q \
    -o "$tmp/box_ref0.exr" 2> "$tmp/box_ref.log" ||
    fail "ptworker --shutter: $(cat "$tmp/box_ref.log")"
  ! "$bin/ptexr-diff" "$tmp/box_ref0.exr" "$tmp/box_ref3.exr" > /dev/null ||
    fail "BoxAnimated's frame 3 blurs as frame 0 does"
  job=$("$bin/ptctl" submit "$box" "${bview[@]}" --frames 2-3 "${shutter[@]}")
  "$bin/ptctl" watch "$job" 2> /dev/null || fail "watch of the frame range exited $?"
  "$bin/ptctl" fetch "$job" --frame 3 -o "$tmp/box_queued3.exr"
  # BoxAnimated has no camera: frames 2-3 are seen from the place the
  # coordinator chose for both (the single frame 3-3 below from its own).
  look=$(sed -n "s/.*job $job: frames 2-3 are framed together: --camera '\(look:[^']*\)'.*/\1/p" \
    "$tmp/serve.log")
  [ -n "$look" ] || fail "the range's view is not said: $(cat "$tmp/serve.log")"
  "$bin/ptworker" --scene "$box" "${bview[@]}" --frame 3 "${shutter[@]}" --camera "$look" \
    --tile 16 --chunk 8 -q -o "$tmp/box_look3.exr"
  "$bin/ptexr-diff" "$tmp/box_look3.exr" "$tmp/box_queued3.exr" ||
    fail "ptctl submit --frames --shutter: frame 3 differs from ptworker --frame 3 --shutter"
  mkdir -p "$tmp/boxlocal"
  "$bin/ptserve" --local 2 --worker-threads 1 "${bview[@]}" --frames 3-3 "${shutter[@]}" --tile 16 \
    --chunk 8 -q -o "$tmp/boxlocal/b.####.exr" "$box" 2> "$tmp/boxlocal.log" ||
    fail "ptserve --local --frames --shutter: $(cat "$tmp/boxlocal.log")"
  "$bin/ptexr-diff" "$tmp/box_ref3.exr" "$tmp/boxlocal/b.0003.exr" ||
    fail "ptserve --frames --shutter: frame 3 differs from ptworker --frame 3 --shutter"
else
  echo "note: no $box; frame ranges with a shutter not checked" >&2
fi
grep -q "Sanitizer\|runtime error:" "$tmp/serve.log" && fail "sanitizer report"
failed=0
echo "ok: --shutter through ptctl submit, ptserve one-job mode and ptworker"
