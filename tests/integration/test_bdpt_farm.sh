#!/usr/bin/env bash
# Bidirectional path tracing on the farm: ptctl submit --bdpt (a queue, 2
# local workers) and ptserve --local 2 --bdpt give the image ptworker --scene
# ... --bdpt gives, bit for bit, and that image is not the unidirectional one
# (so a farm that dropped the flag would fail). The box is lit by its lamp
# and by a background through its open front, so light paths start on
# both. Every render also writes the denoiser's passes and the denoised
# layer (--passes, --denoise), which the farm's images carry bit for bit
# too. A render --bdpt cannot take (glass) is refused by all three before
# any work starts, with the reason; queue mode refuses ptserve's own
# --bdpt (a queued job asks with ptctl submit).
#
# --bdpt auto, the default (common/render/bdpt_auto.h): the NVIDIA Cornell
# box (../shared), whose lamp lights a gap under the ceiling, renders with
# bdpt unasked, the same bits as --bdpt, and --bdpt=off takes it back to
# the unidirectional image, on ptworker, ptserve --local and ptctl submit;
# the repository's box, lit straight down, stays unidirectional.
set -euo pipefail
# shellcheck source=tests/integration/lib_farm.sh
. "$(dirname "$0")/lib_farm.sh"
# shellcheck source=tests/integration/lib_shared.sh
. "$(dirname "$0")/lib_shared.sh"
nv=${PT_SHARED_SCENES:-$src/../shared/scenes}/CornellBox/cornellBox.gltf
need_shared "$nv"
farm_init bdpt_farm

bg=0.4,0.5,0.6
passes=albedo,normal,depth,halves
view=(--res 40x32 --spp 24 --seed 5 --background "$bg" --passes "$passes" --denoise)
glass=$src/scenes/glass_things.gltf
"$bin/ptworker" --scene "$scene" "${view[@]}" --bdpt --tile 16 --chunk 8 -q \
  -o "$tmp/ref.exr" 2> "$tmp/ref.log" || fail "ptworker --bdpt: $(cat "$tmp/ref.log")"
"$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --chunk 8 -q \
  -o "$tmp/plain.exr" 2> "$tmp/plain.log" || fail "ptworker: $(cat "$tmp/plain.log")"
if "$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/plain.exr" > /dev/null 2>&1; then
  fail "--bdpt changes nothing here: the test could not tell it from the default"
fi
for layer in albedo.R N.X depth.Z halfA.R denoised.R; do
  grep -aq "$layer" "$tmp/ref.exr" || fail "ptworker --bdpt wrote no $layer"
done
"$bin/ptworker" --scene "$scene" "${view[@]}" --bdpt=off --tile 16 --chunk 8 -q \
  -o "$tmp/off.exr" 2> /dev/null || fail "ptworker --bdpt=off"
"$bin/ptexr-diff" "$tmp/plain.exr" "$tmp/off.exr" > /dev/null ||
  fail "--bdpt auto took bdpt on the repository's box, lit straight down"

# --bdpt auto on the NVIDIA box: on unasked, with its reason.
nview=(--res 32x24 --spp 8 --seed 7)
"$bin/ptworker" --scene "$nv" "${nview[@]}" --bdpt -q -o "$tmp/nv_on.exr" 2> /dev/null ||
  fail "ptworker --bdpt, NVIDIA box"
"$bin/ptworker" --scene "$nv" "${nview[@]}" -o "$tmp/nv_auto.exr" 2> "$tmp/nv_auto.log" ||
  fail "ptworker, NVIDIA box: $(cat "$tmp/nv_auto.log")"
grep -q -- "--bdpt auto: on" "$tmp/nv_auto.log" || fail "auto said nothing: $(cat "$tmp/nv_auto.log")"
"$bin/ptexr-diff" "$tmp/nv_on.exr" "$tmp/nv_auto.exr" > /dev/null ||
  fail "--bdpt auto on the NVIDIA box is not --bdpt"
"$bin/ptworker" --scene "$nv" "${nview[@]}" --bdpt=off -q -o "$tmp/nv_off.exr" 2> /dev/null ||
  fail "ptworker --bdpt=off, NVIDIA box"
if "$bin/ptexr-diff" "$tmp/nv_on.exr" "$tmp/nv_off.exr" > /dev/null 2>&1; then
  fail "--bdpt=off on the NVIDIA box still renders with bdpt"
fi

# Refusals: the reason, a non-zero exit, no output, before anything renders.
bad() { # WHAT PATTERN CMD...
  local what=$1 pattern=$2 rc=0
  shift 2
  "$@" > "$tmp/bad.log" 2>&1 || rc=$?
  if [ $rc = 0 ] || ! grep -q -- "$pattern" "$tmp/bad.log"; then
    fail "$what: rc $rc: $(cat "$tmp/bad.log")"
  fi
}
bad "ptworker --bdpt, glass" "this render has transmissive materials" \
  "$bin/ptworker" --scene "$glass" "${view[@]}" --bdpt -q -o "$tmp/x.exr"
bad "ptserve --state-dir --bdpt" "one-job mode" \
  "$bin/ptserve" --state-dir "$tmp/qstate" --listen 127.0.0.1:0 --bdpt
bad "ptworker --bdpt=maybe" "'maybe' is not on, off or auto" \
  "$bin/ptworker" --scene "$nv" "${nview[@]}" --bdpt=maybe -q -o "$tmp/x.exr"
[ ! -e "$tmp/x.exr" ] || fail "a refused render wrote its output"

serve serve.log
workers 2
bad "ptctl submit --bdpt, glass" "job refused: bidirectional path tracing (--bdpt)" \
  "$bin/ptctl" submit "$glass" "${view[@]}" --bdpt
job=$("$bin/ptctl" submit "$scene" "${view[@]}" --bdpt)
"$bin/ptctl" watch "$job" 2> /dev/null || fail "watch exited $?"
"$bin/ptctl" fetch "$job" -o "$tmp/queued.exr"
"$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/queued.exr" || fail "ptctl submit --bdpt image differs"
# The same scene and view without --bdpt on the same workers: a worker
# must not reuse the renderer it built for the --bdpt job.
job=$("$bin/ptctl" submit "$scene" "${view[@]}")
"$bin/ptctl" watch "$job" 2> /dev/null || fail "watch exited $?"
"$bin/ptctl" fetch "$job" -o "$tmp/queued_plain.exr"
"$bin/ptexr-diff" "$tmp/plain.exr" "$tmp/queued_plain.exr" ||
  fail "ptctl submit after a --bdpt job of the same scene: not the unidirectional image"
# auto and off through the queue: the coordinator decides at submission.
for m in auto off; do
  arg=()
  [ $m = off ] && arg=(--bdpt=off)
  job=$("$bin/ptctl" submit "$nv" "${nview[@]}" "${arg[@]}")
  "$bin/ptctl" watch "$job" 2> /dev/null || fail "watch exited $?"
  "$bin/ptctl" fetch "$job" -o "$tmp/nv_q_$m.exr"
  "$bin/ptexr-diff" "$tmp/nv_$m.exr" "$tmp/nv_q_$m.exr" ||
    fail "ptctl submit (--bdpt $m), NVIDIA box: not ptworker's image"
  # ptctl status says which integrator the job has, and its JSON.
  want=bidirectional
  [ $m = off ] && want=path
  "$bin/ptctl" status "$job" --json > "$tmp/status.json"
  [ "$(json "$tmp/status.json" 'd["integrator"]')" = $want ] ||
    fail "status --json (--bdpt $m): $(cat "$tmp/status.json")"
  "$bin/ptctl" status "$job" | grep -q "^integrator *${want}" ||
    fail "ptctl status (--bdpt $m) does not say $want: $("$bin/ptctl" status "$job")"
done
grep -q -- "--bdpt auto: on" "$tmp/serve.log" || fail "the coordinator did not say it chose bdpt"

"$bin/ptserve" --local 2 --worker-threads 1 "${view[@]}" --bdpt --tile 16 --task-time 50 \
  -o "$tmp/local.exr" "$scene" 2> "$tmp/local.log" ||
  fail "ptserve --local --bdpt: $(cat "$tmp/local.log")"
"$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/local.exr" || fail "ptserve --bdpt image differs"
"$bin/ptserve" --local 2 --worker-threads 1 "${nview[@]}" --task-time 50 \
  -o "$tmp/nv_local.exr" "$nv" 2> "$tmp/nv_local.log" ||
  fail "ptserve --local, NVIDIA box: $(cat "$tmp/nv_local.log")"
"$bin/ptexr-diff" "$tmp/nv_auto.exr" "$tmp/nv_local.exr" ||
  fail "ptserve --local (--bdpt auto), NVIDIA box: not ptworker's image"
failed=0
echo "ok"
