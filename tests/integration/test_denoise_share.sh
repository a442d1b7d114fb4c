#!/usr/bin/env bash
# ptserve --denoise-on-workers: a finished frame's denoising shared with the
# workers (server/sched/dnshare.h). A queue with two workers denoises a
# --denoise job's frame in regions of 32 pixels; the coordinator's own
# denoising is held (PTSERVE_TEST_DENOISE_GATE) until the job's status says
# every region is done, so the workers' results make the whole frame:
#  1. the EXR - beauty, passes and denoised layer - equals ptworker
#     --denoise's bit for bit; the log counts every region from the
#     workers, each worker's first verified (denoised again here, the same
#     bits), none differing;
#  2. one worker lies (PTWORKER_TEST_DENOISE_LIE flips a bit of each region
#     it returns): its first region's bits differ from the coordinator's,
#     it is blocked, its regions are denoised again, and the image is still
#     the standalone one.
# Then a queue without the test gate: the coordinator races the workers and
# the image is the same, its results waiting for their commit held within
# --max-log-mb 3. (A merge that took a result's passes once left their bytes
# counted: 64 samples of 96 x 64 leaked past 3 MiB, and the queue stopped
# reading its workers for good.)
set -euo pipefail
# shellcheck source=tests/integration/lib_farm.sh
. "$(dirname "$0")/lib_farm.sh"
farm_init denoise_share

# Each region is denoised from a crop of the whole frame (its margin is 96
# pixels): a sanitizer build, where that is most of the test's CPU, gates
# 64 x 64 in 4 regions.
view=(--res 96x64 --spp 8 --seed 5 --denoise)
regions=6 # 96 x 64 in regions of 32
if sanitized; then
  view=(--res 64x64 --spp 8 --seed 5 --denoise)
  regions=4
fi
"$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --chunk 8 -q -o "$tmp/ref.exr" 2> /dev/null

share_run() { # NAME: a job through a gated queue of two workers, one lying with LIE=1
  serve_args=(--denoise-on-workers --denoise-region 32 --verify-fraction 0)
  serve "$1.log" PTSERVE_TEST_DENOISE_GATE="$tmp/gate_$1"
  "$bin/ptworker" --server "$PTFARM_SERVER" --threads 1 --name honest \
    --cache-dir "$tmp/cache1" 2>> "$tmp/worker_$1.log" &
  wrk_pids="$!"
  if [ "${LIE:-0}" = 1 ]; then
    PTWORKER_TEST_DENOISE_LIE=1 "$bin/ptworker" --server "$PTFARM_SERVER" --threads 1 --name liar \
      --cache-dir "$tmp/cache2" 2>> "$tmp/worker_$1.log" &
  else
    "$bin/ptworker" --server "$PTFARM_SERVER" --threads 1 --name second \
      --cache-dir "$tmp/cache2" 2>> "$tmp/worker_$1.log" &
  fi
  wrk_pids="$wrk_pids $!"
  id=$("$bin/ptctl" submit "$scene" "${view[@]}" --name "$1")
  until_status "$id" 'd["message"] == "denoising the image: 100 %"'
  touch "$tmp/gate_$1"
  finish "$id" "$1"
  grep -q "denoised" "$tmp/$1.exr" || fail "$1: no denoised layer"
  stop_workers
  stop_server
  unset serve_args
}

share_run honest
line=$(grep "denoised in $regions regions of 32 pixels" "$tmp/honest.log") ||
  fail "honest: no regions logged: $(cat "$tmp/honest.log")"
echo "honest: $line"
echo "$line" | grep -q ": $regions from workers (2 of them verified), 0 by the coordinator; lying workers: 0" ||
  fail "honest: not every region from the workers, each one's first verified: $line"

LIE=1 share_run lying
line=$(grep "denoised in $regions regions of 32 pixels" "$tmp/lying.log") ||
  fail "lying: no regions logged: $(cat "$tmp/lying.log")"
echo "lying: $line"
echo "$line" | grep -q "; lying workers: 1" || fail "lying: the liar was not caught: $line"
grep -q "worker liar.* blocked: a region it denoised differs" "$tmp/lying.log" ||
  fail "lying: the liar was not blocked: $(cat "$tmp/lying.log")"

# No gate: the coordinator races its workers. 32 samples in a sanitizer
# build (a leak of 5 MB then, still past 3 MiB).
view=(--res 96x64 --spp "$(sanitized_spp 64)" --seed 5 --denoise)
"$bin/ptworker" --scene "$scene" "${view[@]}" --tile 16 --chunk 8 -q -o "$tmp/ref.exr" 2> /dev/null
serve_args=(--denoise-on-workers --denoise-region 32 --max-log-mb 3)
serve race.log
workers 2
id=$("$bin/ptctl" submit "$scene" "${view[@]}" --name race)
finish "$id" race
grep -q "denoised in 6 regions of 32 pixels" "$tmp/race.log" ||
  fail "race: no regions logged: $(cat "$tmp/race.log")"
stop_workers
stop_server
failed=0
echo "denoise share: ok"
