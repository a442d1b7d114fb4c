#!/usr/bin/env bash
# crops.sh - a montage of crops of rendered images, for before/after figures.
#
#   tests/bench/crops.sh OUT.png SCALE COLS GEOM:IMAGE...
#
# Cuts GEOM (oiiotool's WxH+X+Y, in the image's pixels) out of each IMAGE
# (ptworker's sRGB PNG preview, or any image oiiotool reads; an EXR is
# written as its linear values, clamped), enlarges it SCALE times without
# filtering (each pixel a SCALE x SCALE block, so noise stays visible as
# noise), and lays the crops out COLS to a row, left to right then top to
# bottom, with a 4-pixel black gap. All crops should share one size. The PNG
# carries no text chunks (no command line, no folders of the machine that
# made it). Needs oiiotool (Debian's openimageio-tools).
#
# Example: the base build's and the new build's renders at equal CPU time,
# a 64x64 corner of each at 4x, side by side:
#   tests/bench/crops.sh pair.png 4 2 64x64+10+40:base.png 64x64+10+40:new.png
set -euo pipefail

if [[ $# -lt 4 ]]; then
    echo "usage: $0 OUT.png SCALE COLS GEOM:IMAGE...   (GEOM: WxH+X+Y)" >&2
    exit 2
fi
if ! command -v oiiotool >/dev/null; then
    echo "crops.sh: needs oiiotool (apt-get install openimageio-tools)" >&2
    exit 2
fi
out=$1 scale=$2 cols=$3
shift 3
if [[ ! $scale =~ ^[1-9][0-9]?$ || ! $cols =~ ^[1-9][0-9]?$ ]]; then
    echo "crops.sh: SCALE and COLS are whole numbers from 1 to 99" >&2
    exit 2
fi
n=$#
rows=$(((n + cols - 1) / cols))
if ((n < cols)); then
    cols=$n
fi
args=()
for spec in "$@"; do
    geom=${spec%%:*}
    img=${spec#*:}
    if [[ ! $geom =~ ^([0-9]+)x([0-9]+)\+([0-9]+)\+([0-9]+)$ || $img == "$spec" ]]; then
        echo "crops.sh: '$spec' is not GEOM:IMAGE with GEOM as WxH+X+Y" >&2
        exit 2
    fi
    if [[ ! -f $img ]]; then
        echo "crops.sh: no image '$img'" >&2
        exit 2
    fi
    w=$((BASH_REMATCH[1] * scale))
    h=$((BASH_REMATCH[2] * scale))
    args+=("$img" --ch "R,G,B" --cut "$geom" --resample:interp=0 "${w}x${h}")
done
oiiotool --nosoftwareattrib "${args[@]}" --mosaic:pad=4 "${cols}x${rows}" \
    --eraseattrib '.*' -d uint8 -o "$out"
echo "$out: $n crops, $cols x $rows"
