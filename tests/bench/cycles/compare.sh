#!/bin/sh
# ptfarm (ptworker --scene) against Blender Cycles (CPU, headless) on the same
# glTF scenes: time to reach equal RMSE against a converged reference.
# Results and the method: docs/bench/cycles.md.
#
#   tests/bench/cycles/compare.sh [OUTDIR]
#
# Run from anywhere; paths are relative to the repository. Environment:
#   BUILD    build folder with bin/ptworker and bin/ptbench (default build-cyc)
#   BLENDER  blender binary (default: blender on PATH)
#   RES      image size (default 128x128)      THREADS  (default 2)
#   SERIES   spp series (default "4 16 64 256") REPS     repeats per point (default 3)
#   REF_SPP  spp of the converged references (default 4096)
#   SCENES   "name=path ..." (default: the Cornell box and EmissiveStrengthTest)
#
# Writes OUTDIR/runs.tsv (one line per render), OUTDIR/refs.tsv (reference
# cross-errors) and prints the summary of analyze.py. Each series point runs
# both renderers, alternating which goes first, with a different seed per
# repeat; the references use a seed no series run uses.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../.." && pwd)
cd "$root"
BUILD=${BUILD:-build-cyc}
BLENDER=${BLENDER:-blender}
RES=${RES:-128x128}
THREADS=${THREADS:-2}
SERIES=${SERIES:-"4 16 64 256"}
REPS=${REPS:-3}
REF_SPP=${REF_SPP:-4096}
SCENES=${SCENES:-"cornell=scenes/cornell_box.gltf emissive=../shared/scenes/EmissiveStrengthTest/EmissiveStrengthTest.glb"}
OUT=${1:-$BUILD/cycles-bench}
PTW=$BUILD/bin/ptworker
PTB=$BUILD/bin/ptbench
REF_SEED=1000
mkdir -p "$OUT"

for t in "$PTW" "$PTB"; do
    [ -x "$t" ] || { echo "compare.sh: $t missing; build it (cmake --build $BUILD --target ptworker ptbench)" >&2; exit 1; }
done
command -v "$BLENDER" >/dev/null || { echo "compare.sh: no blender (apt-get install blender python3-numpy)" >&2; exit 1; }

# ptfarm: the render time from `ptbench SCENE --spp N` (whole image, T threads
# pulling tiles; scene load and BVH build excluded), since ptworker's summary
# time is rounded up to its 100 ms progress poll. The image scored is the
# ptworker render with the same seed (ptbench writes no image), the same
# estimator: the image does not depend on how the work is split.
run_pt() { # scene spp seed out -> prints seconds
    "$PTW" --scene "$1" --spp "$2" --res "$RES" --threads "$THREADS" --seed "$3" -o "$4" 2>"$4.log" >/dev/null
    "$PTB" "$1" --reference "$PTREF" --spp "$2" --res "$RES" --threads "$THREADS" --seed "$3" \
        --csv "$4.csv" >>"$4.log" 2>&1
    awk -F, 'NR == 1 { for (i = 1; i <= NF; i++) if ($i == "seconds") c = i } NR == 2 { print $c }' "$4.csv"
}

# Cycles: path-tracing time from Cycles' status lines (Time at "Sample 0/N" to
# "Finished"; scene sync, BVH and image loading excluded, like ptworker), and
# the whole bpy.ops.render.render time.
run_cy() { # scene spp seed out -> prints "trace total"
    "$BLENDER" -b --factory-startup --python "$here/render_cycles.py" -- \
        "$1" "$4" --spp "$2" --res "$RES" --threads "$THREADS" --seed "$3" >"$4.log" 2>&1
    awk '
        function secs(s,  n, p, i, t) { n = split(s, p, ":"); t = 0; for (i = 1; i <= n; i++) t = t * 60 + p[i]; return t }
        /\| Sample 0\// && start == "" { match($0, /Time:[0-9:.]+/); start = secs(substr($0, RSTART + 5, RLENGTH - 5)) }
        /\| Finished/ { match($0, /Time:[0-9:.]+/); end = secs(substr($0, RSTART + 5, RLENGTH - 5)) }
        /^CYCLES_TIME/ { sub(/.*total=/, ""); sub(/ .*/, ""); total = $0 }
        END { if (start == "" || end == "" || total == "") exit 1; printf "%.3f %s\n", end - start, total }
    ' "$4.log"
}

rmse() { # image reference -> prints RMSE
    "$PTB" error "$1" "$2" | awk '$1 == "RMSE" { print $2 }'
}

echo "# scene	renderer	spp	rep	seed	trace_s	total_s	rmse_own	rmse_other" >"$OUT/runs.tsv"
echo "# scene	pt_ref_vs_cy_ref_rmse	cy_ref_vs_pt_ref_rmse	pt_ref_mean	cy_ref_mean" >"$OUT/refs.tsv"
for entry in $SCENES; do
    name=${entry%%=*}
    scene=${entry#*=}
    [ -f "$scene" ] || { echo "compare.sh: $scene missing; skipping $name" >&2; continue; }
    ptref=$OUT/$name-pt-ref.exr
    cyref=$OUT/$name-cy-ref.exr
    # The references are kept between runs of this script (delete to redo).
    PTREF=$ptref
    [ -f "$ptref" ] || {
        "$PTW" --scene "$scene" --spp "$REF_SPP" --res "$RES" --threads "$THREADS" --seed $REF_SEED -o "$ptref" 2>"$ptref.log" >/dev/null
        echo "$name ptfarm reference: $(grep rendered "$ptref.log")" >&2
    }
    [ -f "$cyref" ] || { t=$(run_cy "$scene" "$REF_SPP" $REF_SEED "$cyref"); echo "$name cycles reference: ${REF_SPP} spp, trace/total ${t}s" >&2; }
    a=$("$PTB" error "$ptref" "$cyref")
    b=$("$PTB" error "$cyref" "$ptref")
    printf '%s\t%s\t%s\t%s\t%s\n' "$name" \
        "$(echo "$a" | awk '$1 == "RMSE" { print $2 }')" \
        "$(echo "$b" | awk '$1 == "RMSE" { print $2 }')" \
        "$(echo "$a" | awk '$1 == "mean" { print $2 "," $3 "," $4 }')" \
        "$(echo "$b" | awk '$1 == "mean" { print $2 "," $3 "," $4 }')" >>"$OUT/refs.tsv"
    for spp in $SERIES; do
        rep=1
        while [ "$rep" -le "$REPS" ]; do
            # Alternate which renderer goes first, so drifting machine load hits both.
            if [ $(((rep + spp) % 2)) -eq 0 ]; then order="pt cy"; else order="cy pt"; fi
            for r in $order; do
                img=$OUT/$name-$r-$spp-$rep.exr
                if [ "$r" = pt ]; then
                    t=$(run_pt "$scene" "$spp" "$rep" "$img"); tt="$t $t"; own=$ptref; other=$cyref; rn=ptfarm
                else
                    tt=$(run_cy "$scene" "$spp" "$rep" "$img"); own=$cyref; other=$ptref; rn=cycles
                fi
                printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$name" "$rn" "$spp" "$rep" "$rep" \
                    "${tt% *}" "${tt#* }" "$(rmse "$img" "$own")" "$(rmse "$img" "$other")" >>"$OUT/runs.tsv"
                tail -n 1 "$OUT/runs.tsv" >&2
            done
            rep=$((rep + 1))
        done
    done
done
python3 "$here/analyze.py" "$OUT/runs.tsv" "$OUT/refs.tsv" | tee "$OUT/summary.md"
