#!/usr/bin/env bash
# guiding.sh - time to equal relMSE with path guiding on against a base build.
#
#   tests/bench/guiding.sh BIN_DIR BASE_BIN_DIR [REPS]
#
# For each scene of SCENES: renders a reference with BIN_DIR's ptworker
# (REF_SPP samples, unguided, another seed), then REPS times, alternating so
# that a change of machine load hits both alike, each sample count of SPP
# with the base build's ptworker as a user runs it (BASE_ARGS, by default
# nothing: guiding off) and with this build's (NEW_ARGS, by default
# --guiding on). Each repetition has its own seed, so the relMSE of a row is
# the mean over REPS images (fireflies make one image's error a poor
# estimate); its time is the median CPU time of the renders (user + system of
# the whole process, less the median CPU time of a 1-spp run of the same
# build: the scene's load and BVH, which a longer render does not repeat).
# CPU time counts the work on a shared machine, where wall time counts the
# waits for a core too. The worst-0.1 % share is the part of relMSE's sum
# that the worst 0.1 % of pixels hold (ptbench error), at the largest spp.
#
# For each base row, the new build's time to the same relMSE is interpolated
# log-log between its rows around it; the ratio base / new (above 1: the new
# build is faster) is printed per level with its median, and each scene's
# relMSE against CPU time is drawn, both builds, as PLOTS/guiding_NAME.svg.
# The machine's load (the 1-minute load average) after each render is kept in
# OUT/loadavg.csv, for the note that reports the run.
#
# Environment (defaults in brackets):
#   SCENES    names from the table below [cornell toycar transmission glass
#             lamp helmet]
#   RES       image size [128x128]       THREADS  render threads [2]
#   REF_SPP   reference spp [4096]       SPP      list [16,32,64,128,256]
#   BASE_SPP  the base build's list [SPP]: where the new build reaches in
#             16 spp an error the base takes hundreds for (--bdpt), its rows
#             must span the new ones' errors; the k-th of each alternate
#   NEW_ARGS  [--guiding on; set but empty: nothing, the defaults]
#   BASE_ARGS [""]
#   BASE_SCENES  the scene the base build renders for each of SCENES, in
#             order [SCENES]: another file of the same picture, as the
#             window room without its portal (window) for window_portal
#   SEED0     repetition r renders with seed SEED0 + r [0]: another run
#             with other seeds adds repetitions (concatenate the CSVs)
#   OUT       folder for references, images and CSV [/tmp/ptfarm-guiding];
#             a reference already there (same scene, size, spp) is reused
#   REFS      folder for the references [OUT]: another run (other NEW_ARGS,
#             another OUT) can share them
#   PLOTS     folder for the SVG plots [OUT]
set -euo pipefail

if [[ $# -lt 2 || $# -gt 3 || ! -x "$1/ptworker" || ! -x "$1/ptbench" || ! -x "$2/ptworker" ]]; then
    echo "usage: $0 BIN_DIR BASE_BIN_DIR [REPS]   (BIN_DIR holds ptworker and ptbench)" >&2
    exit 2
fi
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
SHARED=$ROOT/../shared
REPS=${3:-3}
SCENES=${SCENES:-"cornell toycar transmission glass lamp helmet"}
RES=${RES:-128x128}
THREADS=${THREADS:-2}
REF_SPP=${REF_SPP:-4096}
SPP=${SPP:-16,32,64,128,256}
NEW_ARGS=${NEW_ARGS---guiding on}
BASE_ARGS=${BASE_ARGS:-}
SEED0=${SEED0:-0}
OUT=${OUT:-/tmp/ptfarm-guiding}
REFS=${REFS:-$OUT}
PLOTS=${PLOTS:-$OUT}
mkdir -p "$OUT/new" "$OUT/base" "$OUT/rooms" "$REFS" "$PLOTS"

# Private copies of the programs: a rebuild during the run cannot touch them.
cp "$1/ptworker" "$1/ptbench" "$OUT/new/"
cp "$2/ptworker" "$OUT/base/"

# OUT/rooms/chair_ROOM.gltf: SheenChair standing in scenes/ROOM.gltf, made
# once; prints its path.
room_with_chair() {
    local out=$OUT/rooms/chair_$1.gltf
    if [[ ! -f $out ]]; then
        python3 "$ROOT/tests/bench/merge_gltf.py" "$ROOT/scenes/$1.gltf" \
            "$SHARED/scenes/SheenChair/SheenChair.gltf" "$OUT/rooms" "chair_$1" \
            --at=-0.3,0,1.0 --rotate-y 40 >&2
    fi
    echo "$out"
}

# The scenes: name -> ptworker arguments (the scene and its light).
scene_args() {
    case $1 in
    cornell) echo "--scene $SHARED/scenes/CornellBox/cornellBox.gltf" ;;
    toycar) echo "--scene $SHARED/scenes/ToyCar/ToyCar.gltf --env $SHARED/envs/studio_small_03_1k.hdr" ;;
    toycar_cabin) echo "--scene $SHARED/scenes/ToyCar/ToyCar.gltf --camera Camera008 --env $SHARED/envs/studio_small_03_1k.hdr" ;;
    transmission) echo "--scene $SHARED/scenes/TransmissionTest/TransmissionTest.glb --env $SHARED/envs/studio_small_03_1k.hdr" ;;
    glass) echo "--scene $ROOT/scenes/glass_things.gltf --env $SHARED/envs/studio_small_03_1k.hdr" ;;
    lamp) echo "--scene $SHARED/scenes/StainedGlassLamp/StainedGlassLamp.gltf" ;;
    helmet) echo "--scene $SHARED/scenes/DamagedHelmet/DamagedHelmet.glb --env $SHARED/envs/rooitou_park_1k.hdr" ;;
    toycar_park) echo "--scene $SHARED/scenes/ToyCar/ToyCar.gltf --env $SHARED/envs/rooitou_park_1k.hdr" ;;
    window) echo "--scene $ROOT/scenes/window_room.gltf --env $SHARED/envs/rooitou_park_1k.hdr" ;;
    window_portal) echo "--scene $ROOT/scenes/window_portal.gltf --env $SHARED/envs/rooitou_park_1k.hdr" ;;
    window_overcast) echo "--scene $ROOT/scenes/window_room.gltf --env $SHARED/envs/potsdamer_platz_1k.hdr" ;;
    window_portal_overcast) echo "--scene $ROOT/scenes/window_portal.gltf --env $SHARED/envs/potsdamer_platz_1k.hdr" ;;
    # the park's map turned so that its sun is behind the room
    window_behind) echo "--scene $ROOT/scenes/window_room.gltf --env $SHARED/envs/rooitou_park_1k.hdr --env-rotate 180" ;;
    window_portal_behind) echo "--scene $ROOT/scenes/window_portal.gltf --env $SHARED/envs/rooitou_park_1k.hdr --env-rotate 180" ;;
    # SheenChair in the window room, with and without the window's portal
    # (merge_gltf.py writes them into OUT/rooms).
    chair_room) echo "--scene $(room_with_chair window_room) --env $SHARED/envs/rooitou_park_1k.hdr" ;;
    chair_portal) echo "--scene $(room_with_chair window_portal) --env $SHARED/envs/rooitou_park_1k.hdr" ;;
    chair_room_overcast) echo "--scene $(room_with_chair window_room) --env $SHARED/envs/potsdamer_platz_1k.hdr" ;;
    chair_portal_overcast) echo "--scene $(room_with_chair window_portal) --env $SHARED/envs/potsdamer_platz_1k.hdr" ;;
    *) return 1 ;;
    esac
}

# The view of a scene without a camera of its own: the one that builds before
# f4e8730 framed (40 degrees high, from the centre of the bounds along
# (0, 0.25, 1), at 1.05 times the distance at which the bounding sphere fills
# a square image). Builds since then fit the bounds' projection to the image,
# closer, so that a base build from before would render another picture than
# the reference. A build that knows --camera-from gets this view explicitly;
# one that does not frames it itself.
scene_view() {
    case $1 in
    lamp) echo "--camera-from 0,0.69003,1.38233 --camera-at 0,0.344448,0 --fov 40" ;;
    helmet) echo "--camera-from -0.002482,1.22456,4.71105 --camera-at -0.002482,0,-0.187155 --fov 40" ;;
    *) echo "" ;;
    esac
}

# CPU seconds (user + system) of one ptworker run: BUILD SEED SPP OUT ARGS...
cpu_run() {
    local build=$1 seed=$2 spp=$3 out=$4
    shift 4
    /usr/bin/time -o "$OUT/time.txt" -f "%U %S" "$OUT/$build/ptworker" "$@" --res "$RES" \
        --threads "$THREADS" --spp "$spp" --seed "$seed" -q -o "$out" >/dev/null 2>&1
    awk '{ printf "%.3f\n", $1 + $2 }' "$OUT/time.txt"
}

# cpu_run of BUILD SEED SPP OUT on its scene: the base build's from
# BASE_SCENES (base_words), the new build's the arguments after OUT; then
# the build's own arguments (extra).
scene_run() {
    local build=$1 seed=$2 spp=$3 out=$4
    shift 4
    if [[ $build == base ]]; then
        cpu_run base "$seed" "$spp" "$out" "${base_words[@]}" "${extra[@]}"
    else
        cpu_run new "$seed" "$spp" "$out" "$@" "${extra[@]}"
    fi
}

# extra: a build's own ptworker arguments (NEW_ARGS or BASE_ARGS, then the
# scene's view where the build takes it), as words.
build_args() {
    local words
    if [[ $1 == new ]]; then
        words="$NEW_ARGS"
    else
        words="$BASE_ARGS"
    fi
    if [[ $1 == new || $base_views == 1 ]]; then
        words="$words $view"
    fi
    read -r -a extra <<<"$words"
}
base_views=0
if "$OUT/base/ptworker" --help 2>&1 | grep -q -- --camera-from; then
    base_views=1
fi

CSV=$OUT/guiding.csv
echo "scene,build,spp,rep,cpu,relmse,worst" >"$CSV"
LOADS=$OUT/loadavg.csv
echo "scene,build,spp,rep,load1" >"$LOADS"
IFS=, read -r -a spps <<<"$SPP"
IFS=, read -r -a base_spps <<<"${BASE_SPP:-$SPP}"
nrows=${#spps[@]}
if ((${#base_spps[@]} > nrows)); then nrows=${#base_spps[@]}; fi
read -r -a base_scenes <<<"${BASE_SCENES:-$SCENES}"
scene_no=0
for name in $SCENES; do
    args=$(scene_args "$name") || { echo "guiding.sh: no scene '$name'" >&2; exit 2; }
    base_name=${base_scenes[scene_no]:-$name}
    scene_no=$((scene_no + 1))
    base_args=$(scene_args "$base_name") || { echo "guiding.sh: no scene '$base_name'" >&2; exit 2; }
    read -r -a base_words <<<"$base_args"
    # shellcheck disable=SC2086 # the arguments are words
    set -- $args
    view=$(scene_view "$name")
    ref=$REFS/ref_${name}_${RES}_${REF_SPP}.exr
    if [[ ! -f $ref ]]; then
        echo "$name: reference, $REF_SPP spp" >&2
        NEW_ARGS="" build_args new
        "$OUT/new/ptworker" "$@" "${extra[@]}" --res "$RES" --threads "$THREADS" \
            --spp "$REF_SPP" --seed 90001 -q -o "$ref" >/dev/null 2>&1
    fi
    for build in base new; do
        build_args "$build"
        for rep in $(seq 1 "$REPS"); do
            c=$(scene_run "$build" $((SEED0 + rep)) 1 "$OUT/load.exr" "$@")
            echo "$name,$build,0,$rep,$c,0,0" >>"$CSV"
        done
    done
    for rep in $(seq 1 "$REPS"); do
        for ((row = 0; row < nrows; row++)); do
            for build in base new; do
                if [[ $build == base ]]; then spp=${base_spps[row]:-}; else spp=${spps[row]:-}; fi
                [[ -n $spp ]] || continue
                build_args "$build"
                img=$OUT/${name}_${build}_${spp}_${rep}.exr
                c=$(scene_run "$build" $((SEED0 + rep)) "$spp" "$img" "$@")
                e=$("$OUT/new/ptbench" error "$img" "$ref" |
                    awk '/^relMSE/ { r = $2 } /^worst0/ { w = $2 } END { print r "," w }')
                echo "$name,$build,$spp,$rep,$c,$e" >>"$CSV"
                echo "$name,$build,$spp,$rep,$(cut -d' ' -f1 /proc/loadavg)" >>"$LOADS"
                echo "$name $build $spp spp rep $rep: cpu $c s, relMSE,worst $e" >&2
            done
        done
    done
done

python3 "$ROOT/tests/bench/guiding_report.py" "$CSV" "$PLOTS"
