#!/usr/bin/env bash
# adaptive.sh - time to reach a given RMSE with and without adaptive sampling.
#
#   tests/bench/adaptive.sh BIN_DIR [REPS]
#
# For each scene: renders a converged reference with ptworker (REF_SPP samples,
# another seed), then, REPS times and alternating so that a change of machine
# load hits both alike, a uniform series (ptbench --spp) and an adaptive series
# (ptbench --target-error, the rule of ptworker and ptserve) timed in-process
# (scene load and BVH build excluded). Rows are the median time over REPS; the
# images are the same bits every repetition. For each uniform row whose RMSE the
# adaptive series spans, the adaptive time to the same RMSE is interpolated
# log-log between the two adaptive rows around it, and the ratio
# uniform / adaptive is printed with the median over those levels.
#
# Environment (defaults in brackets):
#   SCENES      space-separated scene paths [Cornell box, EmissiveStrengthTest]
#   RES         image size [256x256]       TILE     tile side [16]
#   REF_SPP     reference spp [4096]       THREADS  render threads [2]
#   UNIFORM     uniform spp list [16,32,64,128,256,512]
#   TARGETS     adaptive target errors [0.3,0.2,0.14,0.1,0.07,0.05,0.035]
#   MIN_SPP     adaptive --min-spp [16]    MAX_SPP  adaptive cap [2048]
#   CHUNK       adaptive --chunk [16]
#   OUT         folder for references and CSVs [/tmp/ptfarm-adaptive]; a
#               reference already there (same scene, size, spp) is reused.
set -euo pipefail

if [[ $# -lt 1 || $# -gt 2 || ! -x "$1/ptbench" || ! -x "$1/ptworker" ]]; then
    echo "usage: $0 BIN_DIR [REPS]   (BIN_DIR holds ptbench and ptworker)" >&2
    exit 2
fi
BIN=$1
REPS=${2:-3}
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
SCENES=${SCENES:-"$ROOT/scenes/cornell_box.gltf $ROOT/../shared/scenes/EmissiveStrengthTest/EmissiveStrengthTest.glb"}
RES=${RES:-256x256}
TILE=${TILE:-16}
REF_SPP=${REF_SPP:-4096}
THREADS=${THREADS:-2}
UNIFORM=${UNIFORM:-16,32,64,128,256,512}
TARGETS=${TARGETS:-0.3,0.2,0.14,0.1,0.07,0.05,0.035}
MIN_SPP=${MIN_SPP:-16}
MAX_SPP=${MAX_SPP:-2048}
CHUNK=${CHUNK:-16}
OUT=${OUT:-/tmp/ptfarm-adaptive}
mkdir -p "$OUT"

# median.awk: CSV rows of REPS runs -> one row per key (spp or target) with
# the median seconds; rmse, relmse and mean_spp are the same every run.
median_rows() { # KEYCOL FILES...
    local key=$1
    shift
    awk -F, -v key="$key" '
        FNR == 1 { for (i = 1; i <= NF; i++) col[$i] = i; next }
        {
            k = $col[key]
            if (!(k in n)) { order[++nk] = k }
            t[k, ++n[k]] = $col["seconds"]
            rmse[k] = $col["rmse"]; rel[k] = $col["relmse"]; spp[k] = $col["mean_spp"]
        }
        END {
            for (j = 1; j <= nk; j++) {
                k = order[j]; m = n[k]
                for (a = 1; a <= m; a++) v[a] = t[k, a]
                for (a = 2; a <= m; a++) { x = v[a]; for (b = a - 1; b >= 1 && v[b] > x; b--) v[b + 1] = v[b]; v[b + 1] = x }
                med = m % 2 ? v[(m + 1) / 2] : 0.5 * (v[m / 2] + v[m / 2 + 1])
                printf "%s %.6g %.6e %.6e %.6g\n", k, med, rmse[k], rel[k], spp[k]
            }
        }' "$@"
}

# Uniform rows (spp seconds rmse relmse mean_spp) against adaptive rows: the
# adaptive time to each uniform row's error (column COL: 3 RMSE, 4 relMSE),
# log-log interpolated; rows outside the adaptive series' range get "-".
compare() { # COL UNIFORM_TABLE ADAPTIVE_TABLE
    awk -v c="$1" '
        NR == FNR { us[++nu] = $1; ut[nu] = $2; ur[nu] = $c; next }
        { at[++na] = $2; ar[na] = $c; atg[na] = $1; asp[na] = $5 }
        END {
            printf "%10s %8s %10s %10s %9s %7s\n", c == 3 ? "RMSE" : "relMSE", "uni spp", "uniform s", "adaptive s", "ad. spp", "ratio"
            nr = 0
            for (i = 1; i <= nu; i++) {
                L = ur[i]; found = 0
                # adaptive rows come in decreasing target order: RMSE falls, time grows
                for (j = 1; j < na; j++) {
                    if (ar[j] >= L && ar[j + 1] <= L && ar[j] > ar[j + 1]) {
                        f = (log(L) - log(ar[j])) / (log(ar[j + 1]) - log(ar[j]))
                        ta = exp(log(at[j]) + f * (log(at[j + 1]) - log(at[j])))
                        sa = exp(log(asp[j]) + f * (log(asp[j + 1]) - log(asp[j])))
                        found = 1; break
                    }
                }
                if (!found) { printf "%10.4e %8s %10.4f %10s %9s %7s\n", L, us[i], ut[i], "-", "-", "-"; continue }
                r = ut[i] / ta; ratios[++nr] = r
                printf "%10.4e %8s %10.4f %10.4f %9.1f %6.2fx\n", L, us[i], ut[i], ta, sa, r
            }
            if (nr) {
                for (a = 2; a <= nr; a++) { x = ratios[a]; for (b = a - 1; b >= 1 && ratios[b] > x; b--) ratios[b + 1] = ratios[b]; ratios[b + 1] = x }
                med = nr % 2 ? ratios[(nr + 1) / 2] : 0.5 * (ratios[nr / 2] + ratios[nr / 2 + 1])
                printf "median ratio uniform/adaptive at equal %s: %.2fx over %d levels\n", c == 3 ? "RMSE" : "relMSE", med, nr
            } else {
                print "no RMSE level reached by both series: widen TARGETS or UNIFORM"
            }
        }' "$2" "$3"
}

echo "adaptive.sh: $RES, tile $TILE, $THREADS threads, reference $REF_SPP spp (seed 1), $REPS reps"
echo "adaptive.sh: uniform spp $UNIFORM; adaptive targets $TARGETS, min spp $MIN_SPP, chunk $CHUNK, cap $MAX_SPP"
for scene in $SCENES; do
    name=$(basename "$scene")
    name=${name%.*}
    ref="$OUT/$name-$RES-$REF_SPP.exr"
    if [[ ! -f $ref ]]; then
        echo "== $name: reference ($REF_SPP spp)"
        "$BIN/ptworker" --scene "$scene" -o "$ref" --spp "$REF_SPP" --res "$RES" --seed 1 \
            --threads "$THREADS" 2>&1 | grep -v '%' || true
        [[ -f $ref ]] || { echo "adaptive.sh: no reference for $scene" >&2; exit 1; }
    fi
    common=("$scene" --reference "$ref" --threads "$THREADS" --tile "$TILE")
    rm -f "$OUT/$name"-uniform-*.csv "$OUT/$name"-adaptive-*.csv
    for ((k = 1; k <= REPS; k++)); do
        echo "== $name: repetition $k of $REPS"
        "$BIN/ptbench" "${common[@]}" --spp "$UNIFORM" --label uniform \
            --csv "$OUT/$name-uniform-$k.csv" | tail -n +4
        "$BIN/ptbench" "${common[@]}" --target-error "$TARGETS" --min-spp "$MIN_SPP" \
            --max-spp "$MAX_SPP" --chunk "$CHUNK" --label adaptive \
            --csv "$OUT/$name-adaptive-$k.csv" | tail -n +5
    done
    median_rows spp "$OUT/$name"-uniform-*.csv >"$OUT/$name-uniform.txt"
    median_rows target_error "$OUT/$name"-adaptive-*.csv >"$OUT/$name-adaptive.txt"
    echo "== $name: medians over $REPS reps (spp/target seconds RMSE relMSE mean_spp)"
    sed 's/^/uniform  /' "$OUT/$name-uniform.txt"
    sed 's/^/adaptive /' "$OUT/$name-adaptive.txt"
    echo "== $name: time to equal RMSE"
    compare 3 "$OUT/$name-uniform.txt" "$OUT/$name-adaptive.txt"
    echo "== $name: time to equal relMSE"
    compare 4 "$OUT/$name-uniform.txt" "$OUT/$name-adaptive.txt"
done
