#!/usr/bin/env bash
# adaptive.sh - time to reach a given RMSE with and without adaptive sampling.
#
#   tests/bench/adaptive.sh BIN_DIR [REPS]
#
# For each scene: renders a converged reference with ptworker (REF_SPP samples,
# another seed), then, REPS times and alternating so that a change of machine
# load hits all alike, a uniform series (ptbench --spp) and an adaptive series
# per rule of RULES (ptbench --target-error, the equal-error rule; ptbench
# --min-gain, the minimum-mean-error rule; both as ptworker and ptserve apply
# them) timed in-process
# (scene load and BVH build excluded). Rows are the median time over REPS; the
# images are the same bits every repetition. Wall time and the CPU time of all
# render threads are both recorded: on a shared machine the CPU time counts the
# work and not the waits for a core. For each uniform row whose RMSE (then
# relMSE) the adaptive series spans, the adaptive time to the same error is
# interpolated log-log between the two adaptive rows around it, and the ratios
# uniform / adaptive are printed with their median over those levels.
#
# Environment (defaults in brackets):
#   SCENES      space-separated scene paths [Cornell box, EmissiveStrengthTest]
#   RES         image size [256x256]       TILE     tile side [16]
#   REF_SPP     reference spp [4096]       THREADS  render threads [2]
#   UNIFORM     uniform spp list [16,32,64,128,256,512]
#   RULES       adaptive series to run, "target" and/or "gain" [target gain]
#   TARGETS     --target-error values [0.3,0.2,0.14,0.1,0.07,0.05,0.035]
#   GAINS       --min-gain values, decreasing [3e-5,1e-5,3e-6,1e-6,3e-7,1e-7]
#   MIN_SPP     adaptive --min-spp [16]    MAX_SPP  adaptive cap [2048]
#   CHUNK       --chunk of the target series [16]
#   GAIN_CHUNK  --chunk of the gain series [8]: the rule decides from the
#               second chunk on, so 8 gives it the same 16-spp minimum
#   OUT         folder for references and CSVs [/tmp/ptfarm-adaptive]; a
#               reference already there (same scene, size, spp) is reused.
#   BASE        another build's BIN_DIR (e.g. the main branch's) [none]: its
#               ptbench runs every adaptive series too, in the same
#               repetitions, reported as "RULE-base" against the same uniform
#               rows, so that two builds compare side by side.
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
RULES=${RULES:-target gain}
TARGETS=${TARGETS:-0.3,0.2,0.14,0.1,0.07,0.05,0.035}
GAINS=${GAINS:-3e-5,1e-5,3e-6,1e-6,3e-7,1e-7}
GAIN_CHUNK=${GAIN_CHUNK:-8}
MIN_SPP=${MIN_SPP:-16}
MAX_SPP=${MAX_SPP:-2048}
CHUNK=${CHUNK:-16}
OUT=${OUT:-/tmp/ptfarm-adaptive}
BASE=${BASE:-}
mkdir -p "$OUT"

# CSV rows of REPS runs -> one row per key (spp or target): key, median wall
# seconds, RMSE, relMSE, mean spp, median CPU seconds (the errors and spp are
# the same bits every run).
median_rows() { # KEYCOL FILES...
    local key=$1
    shift
    awk -F, -v key="$key" '
        function med(arr, m,    a, b, x, v) {
            for (a = 1; a <= m; a++) v[a] = arr[a]
            for (a = 2; a <= m; a++) { x = v[a]; for (b = a - 1; b >= 1 && v[b] > x; b--) v[b + 1] = v[b]; v[b + 1] = x }
            return m % 2 ? v[(m + 1) / 2] : 0.5 * (v[m / 2] + v[m / 2 + 1])
        }
        FNR == 1 { for (i = 1; i <= NF; i++) col[$i] = i; next }
        {
            k = $col[key]
            if (!(k in n)) { order[++nk] = k }
            n[k]++
            t[k, n[k]] = $col["seconds"]; c[k, n[k]] = $col["cpu_seconds"]
            rmse[k] = $col["rmse"]; rel[k] = $col["relmse"]; spp[k] = $col["mean_spp"]
        }
        END {
            for (j = 1; j <= nk; j++) {
                k = order[j]; m = n[k]
                delete tv; delete cv
                for (a = 1; a <= m; a++) { tv[a] = t[k, a]; cv[a] = c[k, a] }
                printf "%s %.6g %.6e %.6e %.6g %.6g\n", k, med(tv, m), rmse[k], rel[k], spp[k], med(cv, m)
            }
        }' "$@"
}

# Uniform rows against adaptive rows (tables as above): for each uniform row's
# error (column COL: 3 RMSE, 4 relMSE) the adaptive wall and CPU time to the
# same error, log-log interpolated between the adaptive rows around it; rows
# outside the adaptive series' range get "-". Ratios are uniform / adaptive.
compare() { # COL UNIFORM_TABLE ADAPTIVE_TABLE
    awk -v c="$1" '
        function median(arr, m,    a, b, x, v) {
            for (a = 1; a <= m; a++) v[a] = arr[a]
            for (a = 2; a <= m; a++) { x = v[a]; for (b = a - 1; b >= 1 && v[b] > x; b--) v[b + 1] = v[b]; v[b + 1] = x }
            return m % 2 ? v[(m + 1) / 2] : 0.5 * (v[m / 2] + v[m / 2 + 1])
        }
        function lerp(y0, y1) { return exp(log(y0) + f * (log(y1) - log(y0))) }
        NR == FNR { us[++nu] = $1; ut[nu] = $2; ur[nu] = $c; uc[nu] = $6; next }
        { at[++na] = $2; ar[na] = $c; asp[na] = $5; ac[na] = $6 }
        END {
            name = c == 3 ? "RMSE" : "relMSE"
            printf "%10s %7s %9s %9s %7s %9s %9s %7s %8s\n", name, "uni spp", "uni s", "adapt s", "ratio", "uni cpu", "adapt cpu", "ratio", "adapt spp"
            nr = 0
            for (i = 1; i <= nu; i++) {
                L = ur[i]; found = 0
                # adaptive rows come in decreasing target order: error falls, time grows
                for (j = 1; j < na; j++)
                    if (ar[j] >= L && ar[j + 1] <= L && ar[j] > ar[j + 1]) {
                        f = (log(L) - log(ar[j])) / (log(ar[j + 1]) - log(ar[j]))
                        found = 1; break
                    }
                if (!found) { printf "%10.4e %7s %9.3f %9s %7s %9.3f %9s %7s %8s\n", L, us[i], ut[i], "-", "-", uc[i], "-", "-", "-"; continue }
                ta = lerp(at[j], at[j + 1]); ca = lerp(ac[j], ac[j + 1]); sa = lerp(asp[j], asp[j + 1])
                ++nr; rw[nr] = ut[i] / ta; rc[nr] = uc[i] / ca; rs[nr] = us[i] / sa
                printf "%10.4e %7s %9.3f %9.3f %6.2fx %9.3f %9.3f %6.2fx %8.1f\n", L, us[i], ut[i], ta, rw[nr], uc[i], ca, rc[nr], sa
            }
            if (nr)
                printf "median over %d levels, uniform/adaptive at equal %s: wall %.2fx, CPU %.2fx, samples %.2fx\n", nr, name, median(rw, nr), median(rc, nr), median(rs, nr)
            else
                print "no " name " level reached by both series: widen TARGETS or UNIFORM"
        }' "$2" "$3"
}

# Private copies of the programs: a rebuild during the run cannot touch them.
mkdir -p "$OUT/bin"
cp "$BIN/ptbench" "$BIN/ptworker" "$OUT/bin/"
BIN=$OUT/bin
SERIES=$RULES
if [[ -n $BASE ]]; then
    [[ -x $BASE/ptbench ]] || { echo "adaptive.sh: no ptbench in BASE=$BASE" >&2; exit 2; }
    mkdir -p "$OUT/base"
    cp "$BASE/ptbench" "$OUT/base/"
    for rule in $RULES; do SERIES="$SERIES $rule-base"; done
fi

echo "adaptive.sh: $RES, tile $TILE, $THREADS threads, reference $REF_SPP spp (seed 1), $REPS reps"
echo "adaptive.sh: uniform spp $UNIFORM; rules $RULES; min spp $MIN_SPP, cap $MAX_SPP"
echo "adaptive.sh: target errors $TARGETS (chunk $CHUNK); min gains $GAINS (chunk $GAIN_CHUNK)"
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
    rm -f "$OUT/$name"-uniform-*.csv "$OUT/$name"-target*.csv "$OUT/$name"-gain*.csv
    for ((k = 1; k <= REPS; k++)); do
        echo "== $name: repetition $k of $REPS"
        "$BIN/ptbench" "${common[@]}" --spp "$UNIFORM" --label uniform \
            --csv "$OUT/$name-uniform-$k.csv" | tail -n +4
        for series in $SERIES; do
            bench=$BIN/ptbench
            [[ $series == *-base ]] && bench=$OUT/base/ptbench
            case ${series%-base} in
            target) args=(--target-error "$TARGETS" --chunk "$CHUNK") ;;
            gain) args=(--min-gain "$GAINS" --chunk "$GAIN_CHUNK") ;;
            *) echo "adaptive.sh: unknown rule '$series' in RULES" >&2; exit 2 ;;
            esac
            "$bench" "${common[@]}" "${args[@]}" --min-spp "$MIN_SPP" \
                --max-spp "$MAX_SPP" --label "$series" --csv "$OUT/$name-$series-$k.csv" |
                tail -n +5
        done
    done
    median_rows spp "$OUT/$name"-uniform-*.csv >"$OUT/$name-uniform.txt"
    echo "== $name: medians over $REPS reps (spp|target|gain, wall s, RMSE, relMSE, mean spp, CPU s)"
    sed 's/^/uniform  /' "$OUT/$name-uniform.txt"
    for rule in $SERIES; do
        key=$([[ ${rule%-base} == target ]] && echo target_error || echo min_gain)
        median_rows "$key" "$OUT/$name-$rule"-[0-9]*.csv >"$OUT/$name-$rule.txt"
        sed "s/^/$rule /" "$OUT/$name-$rule.txt"
    done
    for rule in $SERIES; do
        echo "== $name, $rule rule: time to equal RMSE"
        compare 3 "$OUT/$name-uniform.txt" "$OUT/$name-$rule.txt"
        echo "== $name, $rule rule: time to equal relMSE"
        compare 4 "$OUT/$name-uniform.txt" "$OUT/$name-$rule.txt"
    done
done
