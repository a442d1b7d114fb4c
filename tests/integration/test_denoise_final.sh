#!/usr/bin/env bash
# The finished image arriving while a progressive save is being denoised
# (ptserve --denoise-progressive): the coordinator stops that denoise, drops
# the progressive image, and denoises the final merged image, so the EXR's
# layer denoised.R/G/B is ptworker --denoise's of the same render bit for
# bit, and the PNG preview shows it. PTSERVE_TEST_DENOISE_HOLD makes every
# progressive denoise wait until a final write is asked for, so the final
# always comes while one is running, whatever the machine's load:
#  1. one job (ptserve --local), progressive saves as often as they come;
#  2. the same job a second time: the hold is seen in the log each time.
set -euo pipefail
# shellcheck source=tests/integration/lib_farm.sh
. "$(dirname "$0")/lib_farm.sh"
farm_init denoise_final

view=(--res 48x32 --spp 1024 --seed 5)
"$bin/ptworker" --scene "$scene" "${view[@]}" --denoise --tile 16 --chunk 8 -q \
  -o "$tmp/ref.exr" 2> /dev/null
grep -q "denoised" "$tmp/ref.exr" || fail "the standalone render has no denoised layer"

for run in 1 2; do
  PTSERVE_TEST_DENOISE_HOLD=1 "$bin/ptserve" --local 2 --worker-threads 1 --tile 16 --chunk 8 \
    --save-interval 0 "${view[@]}" --denoise-progressive -o "$tmp/held$run.exr" "$scene" \
    2> "$tmp/held$run.log" || fail "run $run: $(cat "$tmp/held$run.log")"
  grep -q "test hook: a progressive denoise waits for the final write" "$tmp/held$run.log" ||
    fail "run $run: no progressive denoise was running when the final image came"
  same "held$run"
  cmp -s "$tmp/ref.png" "$tmp/held$run.png" || fail "run $run: the preview is not the denoised layer's"
done
failed=0
echo "denoise final during a progressive denoise: ok"
