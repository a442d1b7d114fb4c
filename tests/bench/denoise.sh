#!/usr/bin/env bash
# denoise.sh - the denoiser against more samples, and its cost.
#
#   tests/bench/denoise.sh BIN_DIR [REPS]
#
# Part 1, quality (needs a ptworker that writes the denoiser's passes,
# `--passes albedo,normal,depth,halves`; skipped with a note otherwise): for
# each scene, a reference of REF_SPP samples with another seed, a LOW_SPP
# render with the passes denoised by ptdenoise, and a HIGH_SPP raw render;
# relMSE of each against the reference (`ptbench error`, the denoised layer
# with --layer denoised), the mean of the denoised image against the raw
# one's, and whether the denoised LOW_SPP image beats the raw HIGH_SPP one.
# Also the share of relMSE the worst 0.1 % of pixels carry (denoised LOW_SPP /
# raw HIGH_SPP): a large one is fireflies or glints, not noise spread evenly.
# Part 2, cost: ptdenoise on a 1920x1080 EXR with every pass
# (ptpasses-exr: the synthetic render of the tests; the denoiser's work does
# not depend on the picture) on THREADS threads, REPS times: median wall and
# CPU seconds. With HD_RENDER=1 and the passes, also a LOW_SPP 1920x1080
# render of the first scene, for the denoiser's share of it.
# Part 3 (CURVE=1), relMSE against time: for each scene and each sample
# count of CURVE_SPP, a render with the passes (raw) and its denoised layer,
# scored against the reference; time is CPU seconds (the render's, scene
# load included; the denoised point adds ptdenoise's), which a machine
# shared with other work does not inflate as it does wall time. Writes
# OUT/NAME-curve.csv (label raw or denoised) and OUT/NAME-curve.png
# (ptbench plot --y relmse).
#
# Environment (defaults in brackets):
#   SCENES   "SCENE[@ENV]" entries [the Cornell box; DamagedHelmet in the studio]
#   RES      image size [256x256]      THREADS  threads [2]
#   LOW_SPP  [64]   HIGH_SPP [1024]    REF_SPP  reference spp [16384]
#   OUT      folder [/tmp/ptfarm-denoise]; a reference already there,
#            NAME-refN-RES.exr, is reused: of several, the one of most samples
#            (a longer one rendered elsewhere may be dropped in), whose N the
#            table shows
#   WORKER   the ptworker that renders [BIN_DIR/ptworker]: another build's, with
#            the passes, while this one has none
#   QUALITY  0: no part 1 [1]          COST     0: no part 2 [1]
#   CURVE    1: part 3 [0]
#   CURVE_SPP  [4,16,64,256]
set -euo pipefail

if [[ $# -lt 1 || $# -gt 2 || ! -x "$1/ptdenoise" || ! -x "$1/ptworker" ]]; then
    echo "usage: $0 BIN_DIR [REPS]   (BIN_DIR holds ptdenoise, ptworker, ptbench, ptpasses-exr)" >&2
    exit 2
fi
BIN=$1
REPS=${2:-3}
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
SHARED=$ROOT/../shared
SCENES=${SCENES:-"$ROOT/scenes/cornell_box.gltf $SHARED/scenes/DamagedHelmet/DamagedHelmet.glb@$SHARED/envs/studio_small_03_1k.hdr"}
RES=${RES:-256x256}
THREADS=${THREADS:-2}
LOW_SPP=${LOW_SPP:-64}
HIGH_SPP=${HIGH_SPP:-1024}
REF_SPP=${REF_SPP:-16384}
OUT=${OUT:-/tmp/ptfarm-denoise}
CURVE_SPP=${CURVE_SPP:-4,16,64,256}
WORKER=${WORKER:-$BIN/ptworker}
mkdir -p "$OUT"

# Median of the numbers on stdin.
median() { sort -g | awk '{ v[NR] = $1 } END { print (NR % 2) ? v[(NR + 1) / 2] : 0.5 * (v[NR / 2] + v[NR / 2 + 1]) }'; }

# Wall and CPU seconds of one command (its stderr to $OUT/last.log): "WALL CPU".
timed() {
    local t0 t1 c0 c1 me=$BASHPID
    t0=$(date +%s.%N)
    c0=$(awk '{ print $14 + $15 + $16 + $17 }' "/proc/$me/stat")
    "$@" 2> "$OUT/last.log"
    t1=$(date +%s.%N)
    # Children's CPU time lands in this shell's cutime/cstime once reaped.
    c1=$(awk '{ print $14 + $15 + $16 + $17 }' "/proc/$me/stat")
    awk -v a="$t0" -v b="$t1" -v c="$c0" -v d="$c1" -v hz="$(getconf CLK_TCK)" \
        'BEGIN { printf "%.3f %.3f\n", b - a, (d - c) / hz }'
}

relmse() { # IMAGE REF [--layer NAME]
    "$BIN/ptbench" error "$@" | awk '$1 == "relMSE" { print $2 }'
}
worst_of() { # IMAGE REF [--layer NAME]: the share of relMSE in the worst 0.1 % of pixels
    "$BIN/ptbench" error "$@" | awk '$1 == "worst0.1%" { print $2 }'
}
# The reference of a scene (NAME SPP ARGS...): the one of most samples in OUT,
# else SPP samples of seed 9001 rendered there; its path in $ref, its samples
# in $ref_spp.
reference() {
    local name=$1 spp=$2 f n
    shift 2
    ref="" ref_spp=0
    for f in "$OUT/$name"-ref*-"$RES".exr; do
        [[ -f $f ]] || continue
        n=${f##*/"$name"-ref}
        n=${n%%-*}
        if [[ $n =~ ^[0-9]+$ ]] && ((n > ref_spp)); then
            ref=$f ref_spp=$n
        fi
    done
    if [[ -z $ref ]]; then
        ref=$OUT/$name-ref$spp-$RES.exr ref_spp=$spp
        "$WORKER" "$@" --spp "$spp" --seed 9001 -o "$ref" 2> /dev/null
    fi
}
mean_of() { # IMAGE REF [--layer NAME]
    "$BIN/ptbench" error "$@" | awk '$1 == "mean" { printf "%.6g", ($2 + $3 + $4) / 3 }'
}

echo "== quality: relMSE against a reference of another seed (ref_spp samples), $RES, $THREADS threads"
# The help text whole, then matched: grep -q closing the pipe early would
# fail the pipeline (pipefail) by the writer's SIGPIPE.
worker_help=$("$WORKER" --help 2>&1 || true)
if [[ $worker_help != *--passes* ]]; then
    echo "skipped: this ptworker writes no passes (--passes); part 2 only"
elif [[ ${QUALITY:-1} == 1 ]]; then
    printf '%-28s %8s %12s %12s %12s %8s %10s %11s\n' scene ref_spp "raw@$LOW_SPP" "dn@$LOW_SPP" \
        "raw@$HIGH_SPP" "dn<raw" "mean dn/raw" "worst0.1%"
    for entry in $SCENES; do
        scene=${entry%@*}
        env=()
        name=$(basename "${scene%.*}")
        if [[ $entry == *@* ]]; then
            env=(--env "${entry#*@}")
            name=$name-$(basename "${entry#*@}" | cut -d_ -f1)
        fi
        if [[ ! -f $scene ]]; then
            echo "$name: $scene is missing" >&2
            continue
        fi
        common=(--scene "$scene" "${env[@]}" --res "$RES" --threads "$THREADS" -q)
        reference "$name" "$REF_SPP" "${common[@]}"
        "$WORKER" "${common[@]}" --spp "$LOW_SPP" --seed 1 \
            --passes albedo,normal,depth,halves -o "$OUT/$name-low.exr" 2> /dev/null
        "$BIN/ptdenoise" "$OUT/$name-low.exr" -o "$OUT/$name-dn.exr" --threads "$THREADS" 2> /dev/null
        "$WORKER" "${common[@]}" --spp "$HIGH_SPP" --seed 1 -o "$OUT/$name-high.exr" 2> /dev/null
        raw_lo=$(relmse "$OUT/$name-dn.exr" "$ref")
        dn_lo=$(relmse "$OUT/$name-dn.exr" "$ref" --layer denoised)
        raw_hi=$(relmse "$OUT/$name-high.exr" "$ref")
        m_raw=$(mean_of "$OUT/$name-dn.exr" "$ref")
        m_dn=$(mean_of "$OUT/$name-dn.exr" "$ref" --layer denoised)
        # the share of each error in the worst 0.1 % of pixels: denoised, raw high
        w_dn=$(worst_of "$OUT/$name-dn.exr" "$ref" --layer denoised)
        w_hi=$(worst_of "$OUT/$name-high.exr" "$ref")
        printf '%-28s %8s %12s %12s %12s %8s %10s %11s\n' "$name" "$ref_spp" "$raw_lo" "$dn_lo" \
            "$raw_hi" "$(awk -v a="$dn_lo" -v b="$raw_hi" 'BEGIN { print (a < b) ? "yes" : "no" }')" \
            "$(awk -v a="$m_dn" -v b="$m_raw" 'BEGIN { printf "%.4f", a / b }')" "$w_dn/$w_hi"
    done
fi

if [[ ${CURVE:-0} == 1 && $worker_help == *--passes* ]]; then
    echo "== relMSE against CPU seconds: raw and denoised, $RES, $THREADS threads"
    for entry in $SCENES; do
        scene=${entry%@*}
        env=()
        name=$(basename "${scene%.*}")
        if [[ $entry == *@* ]]; then
            env=(--env "${entry#*@}")
            name=$name-$(basename "${entry#*@}" | cut -d_ -f1)
        fi
        reference "$name" "$REF_SPP" --scene "$scene" "${env[@]}" --res "$RES" \
            --threads "$THREADS" -q
        csv=$OUT/$name-curve.csv
        echo "label,scene,spp,seconds,relmse" > "$csv"
        for spp in ${CURVE_SPP//,/ }; do
            img=$OUT/$name-c$spp.exr
            read -r _ c_render < <(timed "$WORKER" --scene "$scene" "${env[@]}" --res "$RES" \
                --threads "$THREADS" -q --spp "$spp" --seed 1 \
                --passes albedo,normal,depth,halves -o "$img")
            read -r _ c_dn < <(timed "$BIN/ptdenoise" "$img" -o "$OUT/$name-c$spp-dn.exr" \
                --threads "$THREADS" --no-preview)
            e_raw=$(relmse "$img" "$ref")
            e_dn=$(relmse "$OUT/$name-c$spp-dn.exr" "$ref" --layer denoised)
            echo "raw,$name,$spp,$c_render,$e_raw" >> "$csv"
            echo "denoised,$name,$spp,$(awk -v a="$c_render" -v b="$c_dn" 'BEGIN { print a + b }'),$e_dn" >> "$csv"
            echo "$name $spp spp: raw $e_raw ($c_render s), denoised $e_dn (+$c_dn s)"
        done
        "$BIN/ptbench" plot "$OUT/$name-curve.png" --y relmse --title "$name: RELMSE AGAINST CPU SECONDS" "$csv"
    done
fi

if [[ ${COST:-1} == 0 ]]; then
    exit 0
fi
echo "== cost: ptdenoise on 1920x1080 with every pass, $THREADS threads, median of $REPS"
hd=$OUT/hd-passes.exr
[[ -f $hd ]] || "$BIN/ptpasses-exr" "$hd" 1920 1080 0.1 1
walls=() cpus=()
for ((i = 0; i < REPS; i++)); do
    read -r w c < <(timed "$BIN/ptdenoise" "$hd" -o "$OUT/hd-dn.exr" --threads "$THREADS" --no-preview)
    walls+=("$w")
    cpus+=("$c")
done
dn_wall=$(printf '%s\n' "${walls[@]}" | median)
dn_cpu=$(printf '%s\n' "${cpus[@]}" | median)
echo "ptdenoise 1920x1080 (read, denoise, write): wall $dn_wall s, CPU $dn_cpu s (runs: ${walls[*]})"
grep -o 'denoised in [0-9.]* s' "$OUT/last.log" | sed 's/^/last run: /'

if [[ ${HD_RENDER:-0} == 1 && $worker_help == *--passes* ]]; then
    first=${SCENES%% *}
    scene=${first%@*}
    env=()
    [[ $first == *@* ]] && env=(--env "${first#*@}")
    read -r w c < <(timed "$WORKER" --scene "$scene" "${env[@]}" --res 1920x1080 \
        --spp "$LOW_SPP" --threads "$THREADS" -q --passes albedo,normal,depth,halves \
        -o "$OUT/hd-render.exr")
    echo "render $(basename "$scene") 1920x1080 at $LOW_SPP spp: wall $w s, CPU $c s;" \
        "denoising adds $(awk -v a="$dn_wall" -v b="$w" 'BEGIN { printf "%.1f", 100 * a / b }') % of it"
fi
