#!/usr/bin/env bash
# ptbench --bound on a small render: the bound of the best allocation of
# samples to tiles, in samples and in CPU time, is printed after each --spp row
# for RMSE and relMSE, and obeys what its formulas guarantee:
#   - samples and CPU time at n ~ sqrt(R/c) are >= 1x (Cauchy-Schwarz: uniform
#     sampling is one of the allocations the optimum is taken over);
#   - a floor of --min-spp samples can only cost time: its figure is at most
#     the one without it;
#   - --bound without a reference, or with adaptive rows, is refused.
#
# Environment (set by ctest): PT_BIN (the build's bin folder), PT_SOURCE_DIR.
set -euo pipefail
BIN=${PT_BIN:?}
SRC=${PT_SOURCE_DIR:?}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
scene=$SRC/scenes/cornell_box.gltf

"$BIN/ptworker" --scene "$scene" -o "$tmp/ref.exr" --spp 64 --res 32x32 --seed 1 --threads 1 \
    -q >/dev/null 2>&1
"$BIN/ptbench" "$scene" --reference "$tmp/ref.exr" --spp 4,16 --tile 8 --threads 2 --bound \
    --min-spp 4 >"$tmp/out.txt"
cat "$tmp/out.txt"
lines=$(grep -c '^bound ' "$tmp/out.txt")
[[ $lines == 4 ]] || { echo "FAIL: $lines bound lines, want 4 (2 rows x RMSE, relMSE)"; exit 1; }
awk '/^bound / {
        cpu = ""
        for (i = 1; i <= NF; i++) {
            if ($i == "CPU" && cpu == "") cpu = $(i + 1) + 0
            if ($i == "(samples") smp = $(i + 1) + 0
            if ($i == "with" && $(i + 1) == ">=") floor_ = $(i - 1) + 0
        }
        if (!(cpu >= 0.995 && smp >= 0.995 && floor_ <= cpu + 0.01)) {
            print "FAIL: " $0; bad = 1
        }
    }
    END { exit bad }' "$tmp/out.txt"
grep -q 'tiles without error: [0-9]* of 16, ' "$tmp/out.txt" || { echo "FAIL: no tile count"; exit 1; }

rc=0
"$BIN/ptbench" "$scene" --constant 1 --spp 4 --bound >/dev/null 2>&1 || rc=$?
[[ $rc == 2 ]] || { echo "FAIL: --bound with --constant exited $rc, want 2"; exit 1; }
rc=0
"$BIN/ptbench" "$scene" --reference "$tmp/ref.exr" --min-gain 1e-5 --bound >/dev/null 2>&1 || rc=$?
[[ $rc == 2 ]] || { echo "FAIL: --bound with --min-gain exited $rc, want 2"; exit 1; }
echo "test_bench_bound: ok"
