#!/usr/bin/env bash
# ptbench-paths (tests/bench/paths.c), the firefly finder: it renders the
# samples ptworker --guiding off renders, or --guiding on's with --guiding on
# (its relMSE against a reference is ptbench error's for ptworker's image of
# the same seed), logs the paths of
# the worst pixels' largest samples through the renderer's own code
# (common/render/path_trace.h), and the renderer that users run has none of
# that log compiled in. glass_things.gltf under a uniform background: a
# glass ball on a floor, whose caustic the summary must find among paths
# that reach the light through a smooth bounce after a rough one, and
# split by what the rough vertex has on its camera side.
#
# Environment (set by ctest): PT_BIN (the build's bin folder), PT_SOURCE_DIR.
set -euo pipefail
BIN=${PT_BIN:?}
SRC=${PT_SOURCE_DIR:?}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
scene=$SRC/scenes/glass_things.gltf
common=(--res 32x24 --background "1,1,1" --guiding off --threads 1 -q)

"$BIN/ptworker" --scene "$scene" "${common[@]}" --spp 256 --seed 7 -o "$tmp/ref.exr" >/dev/null 2>&1
"$BIN/ptworker" --scene "$scene" "${common[@]}" --spp 8 --seed 1 -o "$tmp/img.exr" >/dev/null 2>&1
want=$("$BIN/ptbench" error "$tmp/img.exr" "$tmp/ref.exr" | awk '/^relMSE/ { print $2 }')
"$BIN/ptbench-paths" "$scene" --reference "$tmp/ref.exr" --res 32x24 --background 1,1,1 \
    --spp 8 --seed 1 --worst 0.05 --top 2 >"$tmp/out.txt" 2>"$tmp/err.txt"
head -3 "$tmp/out.txt"
tail -12 "$tmp/out.txt"
got=$(awk '/^relMSE/ { sub(",", "", $2); print $2 }' "$tmp/out.txt")
# The same samples: equal to the printed digits (ptbench prints 7, this 6).
awk -v a="$got" -v b="$want" 'BEGIN { d = a - b; if (d < 0) d = -d; exit !(d <= 1e-5 * b) }' ||
    { echo "FAIL: ptbench-paths relMSE $got, ptworker's image $want"; exit 1; }

# Every path logged: bounces with their lobes, light samples, hits.
for what in ' bounce  floor ' ' dielectric ' ' nee ' ' env hit ' 'unblocked, adds'; do
    grep -q -- "$what" "$tmp/out.txt" || { echo "FAIL: no '$what' in the log"; exit 1; }
done
# The summary's shares are parts of the worst pixels' share.
awk '/^relMSE/ { worst = $(NF - 2) + 0 }
     /^by technique/ {
        gsub(",", "")
        s = $4 + $7 + $NF
        if (!(s >= 0 && s <= worst + 1e-4 && $NF > 0)) { print "FAIL: " $0; bad = 1 }
        found = 1
     }
     END { exit bad || !found }' "$tmp/out.txt" ||
    { echo "FAIL: the summary's shares"; exit 1; }
# The BSDF hits without a rough bounce are part of the BSDF hits' share;
# the caustics by their smooth bounces to the light add up to the caustics'.
awk '/^by technique/ { gsub(",", ""); hit = $7 + 0; caustic = $NF + 0 }
     /^BSDF hits with no rough bounce/ { gsub(",", ""); cam = $(NF - 5) + $NF; c1 = 1 }
     /^caustics by the smooth bounces/ {
        gsub(",", ""); chain = $(NF - 4) + $(NF - 2) + $NF; c2 = 1
     }
     END {
        d = chain - caustic; if (d < 0) d = -d
        exit !(c1 && c2 && cam >= 0 && cam <= hit + 1e-4 && d <= 1e-3 && chain > 0)
     }' "$tmp/out.txt" ||
    { echo "FAIL: the BSDF hits' and the caustics' splits"; exit 1; }
# The caustics by their rough vertex's camera side add up to the caustics'
# too; the floor's caustic under the ball, seen by the camera itself, is
# light tracing's.
awk '/^by technique/ { gsub(",", ""); caustic = $NF + 0 }
     /^caustics by their last rough vertex/ {
        gsub(",", ""); n = 0
        for (i = 1; i <= NF; i++) if ($i ~ /^[0-9.]+$/) { v[n++] = $i + 0; s += $i }
        cam = v[0]; found = n == 3
     }
     END {
        d = s - caustic; if (d < 0) d = -d
        exit !(found && d <= 1e-3 && cam > 0)
     }' "$tmp/out.txt" ||
    { echo "FAIL: the caustics' split by their rough vertex's camera side"; exit 1; }
grep -q 'glass:dielectric(delta) > .*| BSDF hit env' "$tmp/out.txt" ||
    { echo "FAIL: no path through the glass to the background"; exit 1; }

# Guided (--guiding on): the samples ptworker --guiding on renders, pass by
# pass with the guide each pass learned (64 spp: passes of 16, 32 and 16),
# each guided vertex logged with its selection probability and both pdfs,
# and the caustics' shares by the rough vertex they left from summed within
# the caustic share.
"$BIN/ptworker" --scene "$scene" --res 32x24 --background "1,1,1" --guiding on --threads 2 -q \
    --spp 64 --seed 1 -o "$tmp/guided.exr" >/dev/null 2>&1
want=$("$BIN/ptbench" error "$tmp/guided.exr" "$tmp/ref.exr" | awk '/^relMSE/ { print $2 }')
"$BIN/ptbench-paths" "$scene" --reference "$tmp/ref.exr" --res 32x24 --background 1,1,1 \
    --spp 64 --seed 1 --worst 0.05 --top 2 --guiding on >"$tmp/guided.txt" 2>"$tmp/err.txt"
got=$(awk '/^relMSE/ { sub(",", "", $2); print $2 }' "$tmp/guided.txt")
awk -v a="$got" -v b="$want" 'BEGIN { d = a - b; if (d < 0) d = -d; exit !(d <= 1e-5 * b) }' ||
    { echo "FAIL: ptbench-paths --guiding on relMSE $got, ptworker's guided image $want"; exit 1; }
grep -Eq ' guided  floor .* prob 0\.[0-9]+ guide pdf ' "$tmp/guided.txt" ||
    { echo "FAIL: no guided floor vertex in the log"; exit 1; }
grep 'caustics by the rough vertex' "$tmp/guided.txt"
awk '/^by technique/ { gsub(",", ""); caustic = $NF + 0 }
     /^caustics by the rough vertex/ {
        n = split($0, f, ",")
        for (i = 1; i <= n; i++) { k = split(f[i], w, " "); s += w[k] }
        found = 1
     }
     END { exit !(found && s > 0 && s <= caustic + 1e-4) }' "$tmp/guided.txt" ||
    { echo "FAIL: the caustics' shares by guided vertex"; exit 1; }
if grep -q 'caustics by the rough vertex' "$tmp/out.txt"; then
    echo "FAIL: an unguided log has the guided summary"
    exit 1
fi

# The renderer that users run has no path log.
nm "$BIN/ptworker" >"$tmp/worker.nm"
nm "$BIN/ptbench-paths" >"$tmp/paths.nm"
if grep -q pt_trace_event "$tmp/worker.nm"; then
    echo "FAIL: ptworker has the path log compiled in"
    exit 1
fi
grep -q ' T pt_trace_event' "$tmp/paths.nm" || { echo "FAIL: no log in ptbench-paths"; exit 1; }

# Bad input: a clear message and a non-zero exit. expect_fail RC TEXT ARGS...
expect_fail() {
    local want=$1 text=$2 rc=0
    shift 2
    "$BIN/ptbench-paths" "$scene" "$@" >/dev/null 2>"$tmp/e" || rc=$?
    if [[ $rc != "$want" ]] || ! grep -q -- "$text" "$tmp/e"; then
        echo "FAIL: ptbench-paths $* exited $rc, want $want and '$text':"
        cat "$tmp/e"
        exit 1
    fi
}
expect_fail 2 --worst --reference "$tmp/ref.exr" --res 32x24 --worst 2
expect_fail 1 'reference is 32x24' --reference "$tmp/ref.exr" --res 16x16
expect_fail 1 nothing.exr --reference "$tmp/nothing.exr" --res 32x24
expect_fail 2 usage --reference "$tmp/ref.exr" --res 32x24 --background 1,1,1 --env x.hdr
expect_fail 2 'on or off' --reference "$tmp/ref.exr" --res 32x24 --guiding maybe
echo "test_bench_paths: ok"
