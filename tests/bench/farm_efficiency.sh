#!/usr/bin/env bash
# Distributed efficiency: samples/s of `ptserve --local 2` (one thread per worker)
# against the standalone `ptworker --scene` on 2 threads, same scene and settings,
# runs alternating so both see the same machine load; medians of wall-clock time
# (process start to exit, scene loading and worker start-up included).
#
#   tests/bench/farm_efficiency.sh [BIN_DIR] [RUNS] [SCENE] [RES] [SPP]
set -euo pipefail
bin=${1:-build/bin}
runs=${2:-5}
scene=${3:-scenes/cornell_box.gltf}
res=${4:-256x256}
spp=${5:-128}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
# The standalone render merges chunks of 16; ptserve sizes its tasks by time (its
# default): with exact sums the images are the same bits.
common=(--res "$res" --spp "$spp" --tile 32 --seed 1 -q)
w=${res%x*}; h=${res#*x}
samples=$((w * h * spp))

now() { date +%s.%N; }
median() { sort -g | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR+1)/2] : (a[NR/2] + a[NR/2+1]) / 2}'; }

: > "$out/solo"; : > "$out/farm"
for _ in $(seq "$runs"); do
  t0=$(now); "$bin/ptworker" --scene "$scene" --threads 2 "${common[@]}" --chunk 16 -o "$out/solo.exr" 2>/dev/null; t1=$(now)
  awk -v a="$t0" -v b="$t1" 'BEGIN {print b - a}' >> "$out/solo"
  t0=$(now); "$bin/ptserve" --local 2 --worker-threads 1 "${common[@]}" -o "$out/farm.exr" "$scene" 2>/dev/null; t1=$(now)
  awk -v a="$t0" -v b="$t1" 'BEGIN {print b - a}' >> "$out/farm"
  "$bin/ptexr-diff" "$out/solo.exr" "$out/farm.exr" >/dev/null || { echo "images differ" >&2; exit 1; }
done
ts=$(median < "$out/solo"); tf=$(median < "$out/farm")
printf 'scene %s, %s, %s spp, %d runs each (medians)\n' "$scene" "$res" "$spp" "$runs"
awk -v s="$samples" -v ts="$ts" -v tf="$tf" 'BEGIN {
  printf "standalone, 2 threads:        %.3f s  %.4g samples/s\n", ts, s / ts
  printf "ptserve --local 2 x 1 thread: %.3f s  %.4g samples/s\n", tf, s / tf
  printf "efficiency (farm / standalone samples/s): %.3f\n", ts / tf }'
