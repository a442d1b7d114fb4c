#!/usr/bin/env bash
# Frame ranges on the farm (BoxAnimated): every frame of a frame-range job is
# bit-identical to the standalone render of that frame (ptworker --scene ...
# --frame F where ptworker poses scenes, else the still, which the frames
# then equal), with ptserve --local 1 and --local 2 (one-job mode) and
# through ptctl submit --frames on a queue with two workers; and after a
# kill -9 of the coordinator mid-range and a restart, with the frames done
# before the kill not rendered again. Output names follow the '#' pattern,
# each EXR carries its frame number and time; ptctl status shows the
# frames, ptctl fetch --frame gets one; bad ranges are refused with a clear
# error and a non-zero exit.
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
shared=${PT_SHARED_SCENES:-$src/../shared/scenes}
scene=$shared/BoxAnimated/BoxAnimated.glb
[ -f "$scene" ] || {
  echo "SKIP: no $scene" >&2
  exit 77
}
tmp=$(mktemp -d /tmp/pt_frames_ctl_XXXXXX)
srv_pid='' wrk_pids=''
cleanup() {
  for p in $wrk_pids $srv_pid; do
    if kill -9 "$p" 2>/dev/null; then wait "$p" 2>/dev/null || true; fi
  done
  if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi
}
trap cleanup EXIT
failed=1
fail() {
  echo "FAIL: $*" >&2
  tail -n 20 "$tmp"/serve*.log >&2 2> /dev/null || true
  exit 1
}
json() { python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))" "$@"; }
frame_meta() { # $1: EXR; prints "frame time fps" from its header
  python3 - "$1" << 'PY'
import struct, sys
b = open(sys.argv[1], "rb").read()
i, out = 8, {}
while b[i] != 0:
    n = b.index(b"\0", i); name = b[i:n].decode(); i = n + 1
    n = b.index(b"\0", i); typ = b[i:n].decode(); i = n + 1
    size = struct.unpack_from("<i", b, i)[0]; i += 4
    v = b[i:i + size]; i += size
    if name == "ptfarm.frame": out["f"] = struct.unpack("<i", v)[0]
    if name == "ptfarm.time": out["t"] = struct.unpack("<d", v)[0]
    if name == "framesPerSecond": out["r"] = "%d/%d" % struct.unpack("<iI", v)
print(out.get("f"), repr(out.get("t")), out.get("r"))
PY
}

bg=(--background "1,1,1")
view=(--res 40x30 --spp 32 --seed 3 "${bg[@]}")
frames=(0 1 2 3 4 5)
# ptworker poses a scene at --frame F once animation is in; until then
# every frame is the still, and the frames must equal it.
posed=0
# (Read whole first: grep -q would end the pipe early, and pipefail fail it.)
worker_help=$("$bin/ptworker" --help 2>&1 || true)
[[ "$worker_help" == *"--frame F"* ]] && posed=1
# BoxAnimated has no camera: the farm frames a range once, at the union of
# its frames' poses, says where from, and sends that placement as the
# job's camera; the references are rendered from it.
mkdir -p "$tmp/look"
"$bin/ptserve" --local 1 --worker-threads 1 --res 40x30 --spp 1 "${bg[@]}" --frames 0-5 --fps 24 \
  -o "$tmp/look/l.####.exr" "$scene" 2> "$tmp/serve_look.log" || fail "$(cat "$tmp/serve_look.log")"
look=$(sed -n "s/.*frames 0-5 are framed together: --camera '\(look:[^']*\)'.*/\1/p" \
  "$tmp/serve_look.log")
[ -n "$look" ] || fail "the range's view is not said: $(cat "$tmp/serve_look.log")"
for f in "${frames[@]}"; do
  if [ $posed = 1 ]; then
    "$bin/ptworker" --scene "$scene" "${view[@]}" --camera "$look" --tile 16 --chunk 8 \
      --frame "$f" --fps 24 -q \
      -o "$tmp/ref.$f.exr"
  elif [ "$f" = 0 ]; then
    "$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --chunk 8 -q -o "$tmp/ref.0.exr"
  else
    cp "$tmp/ref.0.exr" "$tmp/ref.$f.exr"
  fi
done
if [ $posed = 1 ]; then
  ! "$bin/ptexr-diff" "$tmp/ref.0.exr" "$tmp/ref.3.exr" > /dev/null ||
    fail "frames 0 and 3 of BoxAnimated render the same"
fi
same() { # $1: a frame's reference, $2: the farm's image
  "$bin/ptexr-diff" "$1" "$2" > /dev/null || fail "$2 differs from $1"
}

# One-job mode, one and two local workers.
for n in 1 2; do
  mkdir -p "$tmp/local$n"
  "$bin/ptserve" --local $n --worker-threads 1 "${view[@]}" --tile 16 --chunk 8 --frames 0-5 \
    --fps 24 -q -o "$tmp/local$n/shot.####.exr" "$scene" 2> "$tmp/serve_local$n.log" ||
    fail "ptserve --local $n --frames: $(cat "$tmp/serve_local$n.log")"
  for f in "${frames[@]}"; do same "$tmp/ref.$f.exr" "$tmp/local$n/shot.000$f.exr"; done
done
[ "$(frame_meta "$tmp/local2/shot.0003.exr")" = "3 0.125 24/1" ] ||
  fail "frame header: $(frame_meta "$tmp/local2/shot.0003.exr")"
# A step: only its frames, named by number.
mkdir -p "$tmp/step"
"$bin/ptserve" --local 2 --worker-threads 1 "${view[@]}" --tile 16 --chunk 8 --frames 1-5:2 -q \
  -o "$tmp/step/s_##.exr" "$scene" 2> "$tmp/serve_step.log" || fail "--frames 1-5:2"
[ "$(cd "$tmp/step" && echo ./*.exr)" = "./s_01.exr ./s_03.exr ./s_05.exr" ] ||
  fail "step outputs: $(ls "$tmp/step")"
same "$tmp/ref.3.exr" "$tmp/step/s_03.exr"

# Bad input: a clear error and a non-zero exit, before any render.
bad() { # $1: what the message must say, then the command
  local want=$1 rc=0
  shift
  "$@" > "$tmp/bad.log" 2>&1 || rc=$?
  if [ $rc = 0 ] || ! grep -q -- "$want" "$tmp/bad.log"; then
    fail "$* -> rc $rc: $(cat "$tmp/bad.log")"
  fi
}
one=("$bin/ptserve" --local 1 "${view[@]}")
bad "is not a frame range" "${one[@]}" --frames 1-x -o "$tmp/x.#.exr" "$scene"
bad "ends before it starts" "${one[@]}" --frames 9-3 -o "$tmp/x.#.exr" "$scene"
bad "STEP 0" "${one[@]}" --frames 1-9:0 -o "$tmp/x.#.exr" "$scene"
bad "over the cap of 100000" "${one[@]}" --frames 0-200000 -o "$tmp/x.#.exr" "$scene"
bad "needs a '#'" "${one[@]}" --frames 0-3 -o "$tmp/x.exr" "$scene"
bad "give --frames" "${one[@]}" --fps 30 -o "$tmp/x.exr" "$scene"
bad "is not a number in" "${one[@]}" --frames 0-3 --fps 0 -o "$tmp/x.#.exr" "$scene"
# A missing output folder fails at start (it used to render a still and then
# fail, and retry a range's saves for ever).
bad "cannot create its temporary file" timeout 120 "${one[@]}" --frames 0-3 -o "$tmp/none/x.#.exr" \
  "$scene"
bad "cannot create its temporary file" "${one[@]}" -o "$tmp/none/x.exr" "$scene"
grep -q "joined" "$tmp/bad.log" && fail "a worker joined before the missing folder was found"
if [ $posed = 1 ]; then # the loader knows animations: an unknown one is refused
  bad "the scene has no animations" "${one[@]}" --frames 0-3 --animation Walk -o "$tmp/x.#.exr" \
    "$src/scenes/cornell_box.gltf"
  bad "no animation '3'" "${one[@]}" --frames 0-3 --animation 3 -o "$tmp/x.#.exr" "$scene"
fi
ls "$tmp"/x.* > /dev/null 2>&1 && fail "a refused job wrote an image"

# The queue: ptctl submit --frames with two workers, killed mid-range.
serve() { # $1: log
  rm -f "$tmp/port" "$tmp/http_port"
  "$bin/ptserve" --state-dir "$tmp/state" --output-dir "$tmp/out" --listen 127.0.0.1:0 \
    --port-file "$tmp/port" --tile 16 --chunk 8 --save-interval 0.2 --http 127.0.0.1:0 \
    --http-port-file "$tmp/http_port" 2>> "$1" &
  srv_pid=$!
  for _ in $(seq 200); do [ -s "$tmp/port" ] && break; sleep 0.05; done
  [ -s "$tmp/port" ] || fail "ptserve did not start"
  PTFARM_SERVER=127.0.0.1:$(cat "$tmp/port")
  export PTFARM_SERVER
  wrk_pids=''
  for w in 1 2; do
    "$bin/ptworker" --server "$PTFARM_SERVER" --threads 1 --name "w$w" \
      --cache-dir "$tmp/cache$w" 2>> "$tmp/worker.log" &
    wrk_pids="$wrk_pids $!"
  done
}
ctl() { "$bin/ptctl" "$@"; }
bad "ends before it starts" ctl submit "$scene" --frames 5-1 --server 127.0.0.1:1
bad "give --frames" ctl submit "$scene" --animation 0 --server 127.0.0.1:1

serve "$tmp/serve1.log"
# Many passes a frame (384 tasks each), so that the kill finds frames done and
# frames in flight: the workers are held (SIGSTOP) from the first frame done
# until the kill, however slow the checks in between.
long=(--res 40x30 --spp 512 --seed 3 "${bg[@]}")
id=$(ctl submit "$scene" "${long[@]}" --frames 0-5 --fps 24 --name shot)
[[ "$id" =~ ^[0-9]+$ ]] || fail "submit printed '$id'"
end=$((SECONDS + 300))
until grep -q "job $id frame [0-9]* done" "$tmp/serve1.log"; do
  [ $SECONDS -lt $end ] || fail "no frame done"
  sleep 0.05
done
for p in $wrk_pids; do kill -STOP "$p"; done
ctl status "$id" > "$tmp/status.txt"
grep -q "^frames     0-5:1, [1-6] done" "$tmp/status.txt" || fail "status: $(cat "$tmp/status.txt")"
ctl status "$id" --json > "$tmp/status.json"
[ "$(json "$tmp/status.json" 'd["frame_range"] == {"first": 0, "last": 5, "step": 1}')" = True ] ||
  fail "status json: $(cat "$tmp/status.json")"
# The dashboard's API: the same frames.
for _ in $(seq 100); do [ -s "$tmp/http_port" ] && break; sleep 0.05; done
python3 -c "import urllib.request,sys; sys.stdout.write(urllib.request.urlopen(sys.argv[1]).read().decode())" \
  "http://127.0.0.1:$(cat "$tmp/http_port")/api/jobs/$id" > "$tmp/api.json" || fail "/api/jobs/$id"
[ "$(json "$tmp/api.json" 'd["frame_range"]["last"] == 5 and isinstance(d["frames"], list)')" = True ] ||
  fail "/api/jobs/$id: $(cat "$tmp/api.json")"
kill -9 "$srv_pid"
wait "$srv_pid" 2> /dev/null || true
for p in $wrk_pids; do
  kill -9 "$p"
  wait "$p" 2> /dev/null || true
done
srv_pid=''
done_before=$(grep -o "job $id frame [0-9]* done" "$tmp/serve1.log" | awk '{print $4}' | sort -u)
[ -n "$done_before" ] || fail "no frame done before the kill"
[ "$(grep -c "job $id frame [0-9]* done" "$tmp/serve1.log")" -lt 6 ] ||
  fail "every frame was done before the kill: nothing to resume"
# A kill -9 between the queue file saying a frame is done and the removal of
# its folder leaves the folder behind: as if so, the restart removes them.
for f in $done_before; do
  mkdir -p "$tmp/state/jobs/$((1000000000000000000 + id * 1000000 + f))"
  : > "$tmp/state/jobs/$((1000000000000000000 + id * 1000000 + f))/results.log"
done

serve "$tmp/serve2.log"
ctl watch "$id" 2> /dev/null || fail "watch exited $?"
ctl status "$id" --json > "$tmp/status.json"
[ "$(json "$tmp/status.json" 'd["state"]')" = "done" ] || fail "state: $(cat "$tmp/status.json")"
[ "$(json "$tmp/status.json" 'd["frames_done"]')" = 6 ] || fail "frames: $(cat "$tmp/status.json")"
grep -q "damaged\|refusing" "$tmp/serve2.log" && fail "the job was refused after the restart"
# A frame done before the kill is not rendered again: no task of it is
# leased after the restart (no frame-done line, no results log of its own).
for f in $done_before; do
  grep -q "job $id frame $f done" "$tmp/serve2.log" && fail "frame $f was rendered again"
done
for f in "${frames[@]}"; do
  pose=()
  [ $posed = 1 ] && pose=(--frame "$f" --fps 24 --camera "$look")
  "$bin/ptworker" --scene "$scene" "${long[@]}" --tile 16 --chunk 8 -q "${pose[@]}" \
    -o "$tmp/long_ref.$f.exr"
  same "$tmp/long_ref.$f.exr" "$tmp/out/$id-shot.000$f.exr"
  [ $posed = 1 ] || break # the still: every frame is checked against frame 0's below
done
if [ $posed = 0 ]; then
  for f in "${frames[@]}"; do same "$tmp/long_ref.0.exr" "$tmp/out/$id-shot.000$f.exr"; done
fi
left=$(find "$tmp/state/jobs" -mindepth 1)
[ -z "$left" ] || fail "files left in the state folder: $left"

# ptctl fetch --frame: that frame's image; a frame the job does not render,
# a still, and no job at all are refused.
ctl fetch "$id" --frame 4 -o "$tmp/f4.exr"
cmp -s "$tmp/f4.exr" "$tmp/out/$id-shot.0004.exr" || fail "fetch --frame 4 differs"
[ "$(frame_meta "$tmp/f4.exr")" = "4 0.16666666666666666 24/1" ] ||
  fail "fetched header: $(frame_meta "$tmp/f4.exr")"
bad "renders no frame 9" ctl fetch "$id" --frame 9 -o "$tmp/f9.exr"
bad "is not a whole number" ctl fetch "$id" --frame x -o "$tmp/f9.exr"
if [ $posed = 1 ]; then
  bad "scene refused: cornell_box.gltf: no animation 'Walk'" ctl submit \
    "$src/scenes/cornell_box.gltf" --frames 0-2 --animation Walk "${view[@]}"
fi
still=$(ctl submit "$scene" "${view[@]}")
ctl watch "$still" 2> /dev/null || fail "watch of the still exited $?"
bad "is a still" ctl fetch "$still" --frame 0 -o "$tmp/s.exr"
bad "no job 999" ctl fetch 999 --frame 0 -o "$tmp/s.exr"
ctl list | grep -q "6/6 frames" || fail "list: $(ctl list)"

# Cancel: every frame ends with the job, their files go, the queue serves on.
cut=$(ctl submit "$scene" "${long[@]}" --frames 0-99 --name cut)
end=$((SECONDS + 120))
until ctl status "$cut" --json > "$tmp/cut.json" && [ "$(json "$tmp/cut.json" 'd["frames_rendering"] > 0')" = True ]; do
  [ $SECONDS -lt $end ] || fail "no frame of the job to cancel started"
  sleep 0.05
done
[ "$(ctl cancel "$cut")" = cancelled ] || fail "cancel"
end=$((SECONDS + 30))
until [ -z "$(find "$tmp/state/jobs" -mindepth 1)" ]; do
  [ $SECONDS -lt $end ] || fail "files of the cancelled range stay: $(find "$tmp/state/jobs")"
  sleep 0.05
done
after=$(ctl submit "$scene" "${view[@]}")
ctl watch "$after" 2> /dev/null || fail "the job after the cancelled range: watch exited $?"
grep -q "Sanitizer\|runtime error:" "$tmp"/serve*.log && fail "sanitizer report"
failed=0
echo "ok: frame ranges one-job and queued (1 and 2 workers, kill -9 mid-range) equal the standalone frames"
