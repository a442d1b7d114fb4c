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
set -euo pipefail
# shellcheck source=tests/integration/lib_farm.sh
. "$(dirname "$0")/lib_farm.sh"
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

"$bin/ptserve" --local 2 --worker-threads 1 "${view[@]}" --bdpt --tile 16 --task-time 50 \
  -o "$tmp/local.exr" "$scene" 2> "$tmp/local.log" ||
  fail "ptserve --local --bdpt: $(cat "$tmp/local.log")"
"$bin/ptexr-diff" "$tmp/ref.exr" "$tmp/local.exr" || fail "ptserve --bdpt image differs"
failed=0
echo "ok"
