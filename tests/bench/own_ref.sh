#!/usr/bin/env bash
# own_ref.sh - guiding.sh's base rows scored against the base build's own
# reference.
#
#   tests/bench/own_ref.sh BIN_DIR OUT BASE_REFS
#
# guiding.sh scores both builds against a reference of the new build. Where
# the new build renders another picture (a filtered environment lookup, a
# material extension the base ignored), the base's relMSE carries that
# difference as a floor that no number of samples lowers, and the time ratio
# counts it as the new build's gain. This scores each of OUT's base images
# (OUT/NAME_base_SPP_REP.exr) against BASE_REFS/ref_NAME_RES_REFSPP.exr, a
# reference the base build rendered of the same scene, view, size and seed
# (guiding.sh's reference command with the base's ptworker), and writes
# OUT/guiding_own.csv: guiding.csv with those base rows rescored and the new
# rows as they were, for guiding_report.py. Each build is then measured by
# how fast it converges to its own picture. The picture's change itself is
# `ptbench error` of one reference against the other.
#
# BIN_DIR holds ptbench; BASE_REFS holds one reference a scene,
# ref_NAME_*.exr.
set -euo pipefail

if [[ $# -ne 3 || ! -x "$1/ptbench" || ! -f "$2/guiding.csv" || ! -d "$3" ]]; then
    echo "usage: $0 BIN_DIR OUT BASE_REFS   (OUT: a guiding.sh run's folder)" >&2
    exit 2
fi
bench=$1/ptbench out=$2 refs=$3
csv=$out/guiding.csv
own=$out/guiding_own.csv
head -n 1 "$csv" >"$own"
declare -A ref
while IFS=, read -r scene build spp rep cpu relmse worst; do
    if [[ $scene == scene ]]; then
        continue
    fi
    if [[ $build != base || $spp == 0 ]]; then
        echo "$scene,$build,$spp,$rep,$cpu,$relmse,$worst" >>"$own"
        continue
    fi
    if [[ -z ${ref[$scene]:-} ]]; then
        found=("$refs"/ref_"$scene"_*.exr)
        if [[ ${#found[@]} -ne 1 || ! -f ${found[0]} ]]; then
            echo "own_ref.sh: want one base reference $refs/ref_${scene}_*.exr" >&2
            exit 1
        fi
        ref[$scene]=${found[0]}
    fi
    e=$("$bench" error "$out/${scene}_base_${spp}_${rep}.exr" "${ref[$scene]}" |
        awk '/^relMSE/ { r = $2 } /^worst0/ { w = $2 } END { print r "," w }')
    echo "$scene,$build,$spp,$rep,$cpu,$e" >>"$own"
done <"$csv"
echo "$own"
