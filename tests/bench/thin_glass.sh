#!/usr/bin/env bash
# thin_glass.sh - time to equal relMSE with shadow rays through thin smooth
# glass (PT_FEAT_THIN_GLASS) against a base build without them.
#
#   tests/bench/thin_glass.sh BIN_DIR BASE_BIN_DIR [REPS]
#
# guiding.sh's method and report (docs/bench/guiding.md explains them): a
# reference of this build at REF_SPP and another seed, then both builds
# alternating at each sample count, each repetition with its own seed; the
# ratio is the base's CPU time to a relMSE over this build's, and the
# worst-0.1 % share is the part of relMSE's sum the worst 0.1 % of pixels
# hold. Both builds run as a user runs them: nothing is switched on, so
# NEW_ARGS is the default bounce cap (guiding.sh's own default would turn
# path guiding on). The scenes with thin smooth glass, in the studio map:
# ToyCar (its windshield; its first camera, and toycar_cabin: its camera
# Camera008, which looks through a window into the cabin) and
# TransmissionTest (its smooth panels, its own camera).
#
# Environment: as guiding.sh's; SCENES [toycar toycar_cabin transmission], OUT
# [/tmp/ptfarm-thin-glass].
set -euo pipefail

if [[ $# -lt 2 || $# -gt 3 ]]; then
    echo "usage: $0 BIN_DIR BASE_BIN_DIR [REPS]   (BIN_DIR holds ptworker and ptbench)" >&2
    exit 2
fi
SCENES=${SCENES:-"toycar toycar_cabin transmission"}
NEW_ARGS="--max-depth 1024"
OUT=${OUT:-/tmp/ptfarm-thin-glass}
export SCENES NEW_ARGS OUT
exec "$(dirname "$0")/guiding.sh" "$@"
