#!/usr/bin/env bash
# ptbench-throughput on a small render: it reports the renderer's rates, the
# bare Embree rate on the same rays and their ratio (a fraction, in wall and
# CPU time), the variant chosen for the Cornell box (lambert-untextured) and
# its speed against each less specialised variant; where the renderer shades
# in SIMD lanes, also against per-path shading. Only the report's shape is
# checked: speeds are for benchmarks, never for pass/fail.
#
# Environment (set by ctest): PT_BIN (the build's bin folder), PT_SOURCE_DIR.
set -euo pipefail
BIN=${PT_BIN:?}
SRC=${PT_SOURCE_DIR:?}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

"$BIN/ptbench-throughput" "$SRC/scenes/cornell_box.gltf" --res 32x32 --spp 2 --reps 1 \
    --threads 2 >"$tmp/out.txt"
cat "$tmp/out.txt"
fail() { echo "FAIL: $*"; exit 1; }
for want in '^renderer +[0-9.e+]+ samples/s, [0-9.e+]+ rays/s$' \
    '^bare ray queries [0-9.e+]+ rays/s \([0-9]+ rays replayed' \
    '^ratio +[0-9.]+ of the ray-query ceiling$' \
    '^ratio \(CPU time\) [0-9.]+ of the ray-query ceiling' \
    '^variant +lambert-untextured' \
    '^  against lambert ' '^  against untextured ' '^  against general '; do
    grep -Eq "$want" "$tmp/out.txt" || fail "no line matching '$want'"
done
ratio=$(awk '/^ratio +[0-9]/ {print $2}' "$tmp/out.txt")
# A positive number: its size is a speed, which the load of the machine sets.
awk -v r="$ratio" 'BEGIN { exit !(r > 0) }' || fail "ratio $ratio is not a positive number"
# The lanes line comes exactly when the variant says it shades in lanes.
if grep -q '^variant .*(SIMD lanes)' "$tmp/out.txt"; then
    grep -q '^  against per-path shading ' "$tmp/out.txt" || fail "lanes without the per-path line"
else
    ! grep -q 'per-path shading' "$tmp/out.txt" || fail "per-path line without lanes"
fi
rc=0
"$BIN/ptbench-throughput" >/dev/null 2>&1 || rc=$?
[[ $rc == 2 ]] || fail "no scene exited $rc, want 2"
echo "test_bench_throughput: ok"
