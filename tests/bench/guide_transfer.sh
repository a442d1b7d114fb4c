#!/usr/bin/env bash
# Path guiding on the farm: what the coordinator holds and sends per
# training pass (server/sched/job_guide.c).
#
# Runs ptserve --local N --guiding on over a scene at a given size (default
# 1920x1080, the NVIDIA Cornell box of ../shared/scenes) and reads from the
# logs, for each pass's distribution: its bytes (the GUIDE encoding that TASK
# names by hash, protocol/guide.h), the bytes on the wire (packed with zlib,
# what workers fetch once), its nodes, the coordinator's build and pack
# times, and each worker's fetch time (first GUIDE_GET to the distribution
# unpacked and checked, over loopback). Writes a table on stdout and the
# logs in --work.
#
#   tests/bench/guide_transfer.sh [--bin DIR] [--scene FILE] [--res WxH]
#                                 [--spp N] [--workers N] [--work DIR]
#
# The training passes end at 16, 48, 112... samples per pixel, the last
# running to spp when less than the next pass is left: --spp 48 builds one
# learned distribution (pass 1's, from 16 samples of every pixel), the
# shortest run that measures it; --spp 112 two. Guiding never runs with
# adaptive sampling. The coordinator's resident memory is sampled every
# 0.2 s: the most it held while each pass rendered, and its peak.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
bin=$here/../../build/bin
scene=$here/../../../shared/scenes/CornellBox/cornellBox.gltf
res=1920x1080
spp=48
workers=2
work=$(mktemp -d /tmp/pt_guide_transfer_XXXXXX)
while [ $# -gt 0 ]; do
  case $1 in
  --bin) bin=$2 ;;
  --scene) scene=$2 ;;
  --res) res=$2 ;;
  --spp) spp=$2 ;;
  --workers) workers=$2 ;;
  --work) work=$2 ;;
  -h | --help)
    sed -n '2,22p' "$0"
    exit 0
    ;;
  *)
    echo "guide_transfer.sh: unknown option $1" >&2
    exit 2
    ;;
  esac
  shift 2
done
mkdir -p "$work"
log=$work/ptserve.log
t0=$(date +%s.%N)
"$bin/ptserve" --local "$workers" --res "$res" --spp "$spp" --guiding on \
  -o "$work/out.exr" "$scene" > "$log" 2>&1 &
pid=$!
# The coordinator's resident memory every 0.2 s, each sample with the
# passes whose distribution was installed by then (its log's lines).
rss=$work/rss.txt
: > "$rss"
while kill -0 "$pid" 2> /dev/null; do
  kb=$(sed -n 's/^VmRSS:[[:space:]]*\([0-9]*\) kB/\1/p' "/proc/$pid/status" 2> /dev/null || true)
  hwm=$(sed -n 's/^VmHWM:[[:space:]]*\([0-9]*\) kB/\1/p' "/proc/$pid/status" 2> /dev/null || true)
  n=$(grep -c 'guiding pass [0-9]*: a distribution' "$log" || true)
  if [ -n "$kb" ]; then echo "$n $kb $hwm" >> "$rss"; fi
  sleep 0.2
done
wait "$pid"
t1=$(date +%s.%N)
echo "scene $(basename "$scene") $res, $spp spp, $workers workers: $(echo "$t1 - $t0" | bc) s"
# Per pass rendered: the most the coordinator held while its tasks ran (a
# distribution installed and, before the last, the next one's statistics),
# and its peak (VmHWM) so far, in MiB.
awk '{ if ($2 > m[$1]) m[$1] = $2; h[$1] = $3 }
     END { for (k in m) printf "coordinator, pass %d rendering: resident %.1f MiB, peak so far %.1f MiB\n", k, m[k] / 1024, h[k] / 1024 }' "$rss" |
  sort
printf '%-6s %12s %12s %10s %12s %10s %8s %s\n' pass bytes wire spatial directional build_ms pack_ms \
  fetch_ms
# The first distribution (pass 0) is uniform: its sizes from the fetch lines.
fetched='guiding distribution [0-9a-f]* ([0-9]* bytes, [0-9]* unpacked) fetched in [0-9]* ms'
first=$(grep -o "$fetched" "$log" | head -n "$workers")
if [ -n "$first" ]; then
  p=$(echo "$first" | head -n 1 | sed 's/.*(\([0-9]*\) bytes.*/\1/')
  b=$(echo "$first" | head -n 1 | sed 's/.* \([0-9]*\) unpacked.*/\1/')
  ms=$(echo "$first" | sed 's/.* in \([0-9]*\) ms/\1/' | tr '\n' ' ')
  printf '%-6s %12s %12s %10s %12s %10s %8s %s\n' 0 "$b" "$p" 1 "-" "-" "-" "$ms"
fi
grep -o 'guiding pass [0-9]*: a distribution of [0-9]* bytes, [0-9]* packed ([0-9]* spatial, [0-9]* directional nodes) built in [0-9]* ms[a-z ]* (packed in [0-9]* ms)' "$log" |
  while read -r line; do
    read -r _ _ k _ _ _ b _ p _ s _ q _ _ _ _ <<<"$line"
    k=${k%:}
    b=${b%,}
    s=${s#(}
    ms=${line#* built in }
    ms=${ms%% ms*}
    pms=${line##*packed in }
    pms=${pms% ms)}
    fetch=$(grep -o "guiding distribution [0-9a-f]* ($p bytes, $b unpacked) fetched in [0-9]* ms" "$log" |
      sed 's/.* in \([0-9]*\) ms/\1/' | tr '\n' ' ')
    printf '%-6s %12s %12s %10s %12s %10s %8s %s\n' "$k" "$b" "$p" "$s" "$q" "$ms" "$pms" "$fetch"
  done
