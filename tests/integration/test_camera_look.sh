#!/usr/bin/env bash
# Cameras from the command line: --camera-from X,Y,Z --camera-at X,Y,Z with
# --fov or --ortho gives the same image, bit for bit, from ptworker, from
# ptserve --local (one-job mode) and from ptctl submit on a queue: the
# placement travels with the job. It differs from the file's camera; the
# file's camera picked by name, by index and by node name is one image.
# Half-given placements and mixes are refused as bad usage. ptctl fetch
# -o NAME.png writes the PNG ptworker writes of the same pixels.
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
scene=$src/scenes/cornell_box.gltf
tmp=$(mktemp -d /tmp/pt_camera_look_XXXXXX)
srv_pid=
cleanup() {
  if [ -n "$srv_pid" ] && kill "$srv_pid" 2> /dev/null; then wait "$srv_pid" 2> /dev/null || true; fi
  if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }
same() { # $1 $2: EXRs that must hold the same pixels
  "$bin/ptexr-diff" "$1" "$2" > "$tmp/diff.txt" || fail "$1 and $2 differ: $(cat "$tmp/diff.txt")"
}

view=(--res 40x30 --spp 8 --seed 5 --tile 16 --chunk 8)
look=(--camera-from "0.1,0.35,0.9" --camera-at "-0.2,0.25,-0.3" --fov 50)
ortho=(--camera-from "-0.278,0.273,0.8" --camera-at "-0.278,0.273,0" --ortho 0.7)
"$bin/ptworker" --scene "$scene" "${view[@]}" -q "${look[@]}" -o "$tmp/w.exr"
"$bin/ptworker" --scene "$scene" "${view[@]}" -q "${ortho[@]}" -o "$tmp/wo.exr"
"$bin/ptworker" --scene "$scene" "${view[@]}" -q -o "$tmp/file.exr"
if "$bin/ptexr-diff" "$tmp/w.exr" "$tmp/file.exr" > /dev/null 2>&1; then
  fail "--camera-from rendered the file's camera"
fi
if "$bin/ptexr-diff" "$tmp/w.exr" "$tmp/wo.exr" > /dev/null 2>&1; then
  fail "--ortho rendered the perspective view"
fi
for pick in Camera 0; do
  "$bin/ptworker" --scene "$scene" "${view[@]}" -q --camera "$pick" -o "$tmp/pick.exr"
  same "$tmp/file.exr" "$tmp/pick.exr"
done

# One-job mode: the same bits.
"$bin/ptserve" --local 1 --worker-threads 1 "${view[@]}" -q "${look[@]}" -o "$tmp/s.exr" "$scene" \
  2> "$tmp/s.log" || fail "ptserve: $(cat "$tmp/s.log")"
same "$tmp/w.exr" "$tmp/s.exr"

# A queue: ptctl submit carries the placement in the job.
"$bin/ptserve" --state-dir "$tmp/state" --output-dir "$tmp/out" --listen 127.0.0.1:0 \
  --port-file "$tmp/port" --local 1 --worker-threads 1 --tile 16 --chunk 8 2> "$tmp/serve.log" &
srv_pid=$!
for _ in $(seq 100); do
  if [ -s "$tmp/port" ]; then break; fi
  sleep 0.05
done
[ -s "$tmp/port" ] || fail "ptserve did not start: $(cat "$tmp/serve.log")"
PTFARM_SERVER=127.0.0.1:$(cat "$tmp/port")
export PTFARM_SERVER
for v in look ortho; do
  if [ $v = look ]; then args=("${look[@]}"); else args=("${ortho[@]}"); fi
  id=$("$bin/ptctl" submit "$scene" --res 40x30 --spp 8 --seed 5 "${args[@]}")
  "$bin/ptctl" watch "$id" 2> /dev/null || fail "watch $v: exit $?"
  "$bin/ptctl" fetch "$id" -o "$tmp/q_$v.exr"
done
same "$tmp/w.exr" "$tmp/q_look.exr"
same "$tmp/wo.exr" "$tmp/q_ortho.exr"

# ptctl fetch -o NAME.png: the image through the previews' view, the same
# bytes as ptworker's PNG of the same pixels; other names and a missing
# folder are refused before anything is downloaded (no server is asked).
"$bin/ptworker" --scene "$scene" "${view[@]}" -q "${look[@]}" --view agx --exposure 1 -o "$tmp/wa.png"
"$bin/ptctl" fetch "$id" -o "$tmp/q_ortho.png" 2> "$tmp/fetch.log" || fail "fetch png: $(cat "$tmp/fetch.log")"
"$bin/ptworker" --scene "$scene" "${view[@]}" -q "${ortho[@]}" -o "$tmp/wo.png"
cmp -s "$tmp/wo.png" "$tmp/q_ortho.png" || fail "the fetched PNG is not ptworker's"
lid=$("$bin/ptctl" submit "$scene" --res 40x30 --spp 8 --seed 5 "${look[@]}")
"$bin/ptctl" watch "$lid" 2> /dev/null || fail "watch: exit $?"
"$bin/ptctl" fetch "$lid" --view agx --exposure 1 -o "$tmp/qa.png" || fail "fetch agx: exit $?"
cmp -s "$tmp/wa.png" "$tmp/qa.png" || fail "the fetched AgX PNG is not ptworker's"
rc=0
"$bin/ptctl" --server 127.0.0.1:1 fetch 1 -o "$tmp/x.jpg" 2> "$tmp/bad.log" || rc=$?
[ "$rc" = 2 ] || fail "fetch -o x.jpg: exit $rc: $(cat "$tmp/bad.log")"
grep -q "follows its name" "$tmp/bad.log" || fail "fetch -o x.jpg: $(cat "$tmp/bad.log")"
rc=0
"$bin/ptctl" --server 127.0.0.1:1 fetch 1 --view agx -o "$tmp/x.exr" 2> "$tmp/bad.log" || rc=$?
[ "$rc" = 2 ] || fail "fetch --view to an EXR: exit $rc"
rc=0
"$bin/ptctl" --server 127.0.0.1:1 fetch 1 -o "$tmp/none/x.png" 2> "$tmp/bad.log" || rc=$?
[ "$rc" = 1 ] || fail "fetch into a missing folder: exit $rc: $(cat "$tmp/bad.log")"
grep -q "cannot be written" "$tmp/bad.log" || fail "fetch into a missing folder: $(cat "$tmp/bad.log")"

# Refusals: bad usage, before anything is loaded.
bad() { # $1: what stderr must say, then the command
  local want=$1 rc=0
  shift
  "$@" > "$tmp/bad.log" 2>&1 || rc=$?
  [ "$rc" = 2 ] || fail "$* -> exit $rc: $(cat "$tmp/bad.log")"
  grep -q -- "$want" "$tmp/bad.log" || fail "$*: no '$want': $(cat "$tmp/bad.log")"
}
bad "together" "$bin/ptworker" --scene "$scene" -o "$tmp/x.exr" --camera-from 0,0,1
bad "together" "$bin/ptworker" --scene "$scene" -o "$tmp/x.exr" --fov 30
bad "give one" "$bin/ptworker" --scene "$scene" -o "$tmp/x.exr" "${look[@]}" --camera Camera
bad "two projections" "$bin/ptworker" --scene "$scene" -o "$tmp/x.exr" "${look[@]}" --ortho 2
bad "where it looks" "$bin/ptworker" --scene "$scene" -o "$tmp/x.exr" --camera-from 1,1,1 \
  --camera-at 1,1,1
bad "X,Y,Z" "$bin/ptworker" --scene "$scene" -o "$tmp/x.exr" --camera-from 1,1 --camera-at 0,0,0
bad "together" "$bin/ptserve" --local 1 -o "$tmp/x.exr" --camera-at 0,0,0 "$scene"
bad "together" "$bin/ptctl" submit "$scene" --camera-from 0,0,1
failed=0
echo "ok"
