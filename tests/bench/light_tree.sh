#!/usr/bin/env bash
# light_tree.sh - time to equal relMSE with NEE's light tree against the
# choice of an emissive triangle by power (common/render/light_tree.h).
#
#   tests/bench/light_tree.sh BIN_DIR [REPS]
#
# For each scene: a converged reference by ptworker (REF_SPP samples, seed 99,
# max depth 16 as ptbench renders), then REPS times, alternating so that a
# change of machine load hits both alike, the "old" series (ptbench
# --light-select power, or BASE's ptbench: another build, e.g. main's) and
# the "new" one (ptbench, default selection: the tree for 16 to 256 emissive
# triangles spread over a third of the scene) at each sample count of SPP, timed in-process (scene load and
# BVH build excluded). The images are the same bits every repetition; the
# times are medians over REPS, wall and CPU (all render threads: on a shared
# machine the CPU time counts the work and not the waits for a core).
# Time to equal relMSE: relMSE falls as 1/time for a Monte Carlo estimator,
# so old/new = (relMSE_old x t_old) / (relMSE_new x t_new) per row (> 1: the
# new one is faster), and the median over the rows.
#
# Environment (defaults in brackets):
#   SCENES   space-separated scene paths [EmissiveStrengthTest (60 emissive
#            triangles), StainedGlassLamp (18,982 textured ones), the Cornell
#            box (2) and the NVIDIA CornellBox (12): the last two stay below
#            the tree's threshold and show what the change costs there]
#   RES      image size [128x128]      THREADS  render threads [2]
#   SPP      spp list [16,64,256]      REF_SPP  reference spp [4096]
#   OUT      folder for references and CSVs [/tmp/ptfarm-light-tree]; a
#            reference already there (same scene, size, spp) is reused
#   BASE     another build's BIN_DIR [none]: its ptbench is the old series
#   SELECT   --light-select of the new series, and of the old one too when
#            BASE is set [none: each build's default]; e.g. tree to time
#            the tree past PT_LIGHT_TREE_AUTO_MAX lights
set -euo pipefail

if [[ $# -lt 1 || $# -gt 2 || ! -x "$1/ptbench" || ! -x "$1/ptworker" ]]; then
    echo "usage: $0 BIN_DIR [REPS]   (BIN_DIR holds ptbench and ptworker)" >&2
    exit 2
fi
BIN=$1
REPS=${2:-3}
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
SH=$ROOT/../shared/scenes
SCENES=${SCENES:-"$SH/EmissiveStrengthTest/EmissiveStrengthTest.glb $SH/StainedGlassLamp/StainedGlassLamp.gltf $ROOT/scenes/cornell_box.gltf $SH/CornellBox/cornellBox.gltf"}
RES=${RES:-128x128}
THREADS=${THREADS:-2}
SPP=${SPP:-16,64,256}
REF_SPP=${REF_SPP:-4096}
OUT=${OUT:-/tmp/ptfarm-light-tree}
BASE=${BASE:-}
SELECT=${SELECT:-}
mkdir -p "$OUT"

# median over the CSVs of one series: spp, wall s, CPU s, relMSE
medians() {
    awk -F, '
        FNR == 1 { for (i = 1; i <= NF; i++) col[$i] = i; next }
        {
            k = $(col["spp"]); n[k]++
            w[k, n[k]] = $(col["seconds"]); c[k, n[k]] = $(col["cpu_seconds"])
            r[k] = $(col["relmse"]); if (!(k in seen)) { seen[k] = 1; keys[++nk] = k }
        }
        function med(a, k, m,    i, j, t, v) {
            for (i = 1; i <= m; i++) v[i] = a[k, i]
            for (i = 2; i <= m; i++) for (j = i; j > 1 && v[j] < v[j - 1]; j--) {
                t = v[j]; v[j] = v[j - 1]; v[j - 1] = t
            }
            return m % 2 ? v[(m + 1) / 2] : (v[m / 2] + v[m / 2 + 1]) / 2
        }
        END { for (i = 1; i <= nk; i++) { k = keys[i]; print k, med(w, k, n[k]), med(c, k, n[k]), r[k] } }
    ' "$@"
}

for scene in $SCENES; do
    if [[ ! -f $scene ]]; then
        echo "light_tree.sh: $scene is missing, skipped" >&2
        continue
    fi
    name=$(basename "${scene%.*}")
    ref=$OUT/$name-ref-$RES-$REF_SPP.exr
    if [[ ! -f $ref ]]; then
        "$BIN/ptworker" --scene "$scene" --res "$RES" --spp "$REF_SPP" --seed 99 --max-depth 16 \
            --threads "$THREADS" -o "$ref" >/dev/null 2>&1
    fi
    rm -f "$OUT/$name"-old-*.csv "$OUT/$name"-new-*.csv
    for ((rep = 1; rep <= REPS; rep++)); do
        common=("$scene" --reference "$ref" --res "$RES" --spp "$SPP" --threads "$THREADS")
        select=()
        if [[ -n $SELECT ]]; then
            select=(--light-select "$SELECT")
        fi
        if [[ -n $BASE ]]; then
            "$BASE/ptbench" "${common[@]}" "${select[@]}" --csv "$OUT/$name-old-$rep.csv" >/dev/null
        else
            "$BIN/ptbench" "${common[@]}" --light-select power --csv "$OUT/$name-old-$rep.csv" \
                >/dev/null
        fi
        "$BIN/ptbench" "${common[@]}" "${select[@]}" --csv "$OUT/$name-new-$rep.csv" >/dev/null
    done
    medians "$OUT/$name"-old-*.csv >"$OUT/$name-old.txt"
    medians "$OUT/$name"-new-*.csv >"$OUT/$name-new.txt"
    echo "== $name ($RES, $THREADS threads, medians of $REPS alternating runs; old: ${BASE:-power})"
    paste -d' ' "$OUT/$name-old.txt" "$OUT/$name-new.txt" | awk '
        BEGIN { printf "%6s %9s %9s %11s %11s %9s %9s\n", "spp", "old cpu", "new cpu", "old relMSE", "new relMSE", "wall x", "cpu x" }
        {
            ew = ($4 * $2) / ($8 * $6); ec = ($4 * $3) / ($8 * $7)
            printf "%6d %9.3f %9.3f %11.4e %11.4e %9.3f %9.3f\n", $1, $3, $7, $4, $8, ew, ec
            w[++n] = ew; c[n] = ec
        }
        function med(a, m,    i, j, t) {
            for (i = 2; i <= m; i++) for (j = i; j > 1 && a[j] < a[j - 1]; j--) {
                t = a[j]; a[j] = a[j - 1]; a[j - 1] = t
            }
            return m % 2 ? a[(m + 1) / 2] : (a[m / 2] + a[m / 2 + 1]) / 2
        }
        END { printf "time to equal relMSE, old/new (median over rows): wall %.3fx, CPU %.3fx\n", med(w, n), med(c, n) }'
done
