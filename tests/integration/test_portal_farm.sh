#!/usr/bin/env bash
# Environment portals travel in the scene: every worker reads them from the
# glTF file and samples the environment through them alike, so a farm's
# image of the window room with its window marked (scenes/window_portal.gltf)
# is the standalone render's, bit for bit, with 1 and 3 local workers: under
# a uniform background, and under the park map turned so that its sun is
# behind the room (a map with a sun that cannot shine in: the portals are
# used), which needs ../shared (skipped without it, unless CI=true).
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
shared=${PT_SHARED_SCENES:?}/..
tmp=$(mktemp -d /tmp/pt_portal_farm_XXXXXX)
trap 'rm -rf "$tmp"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
scene=$src/scenes/window_portal.gltf
listed=$("$bin/ptworker" --list "$scene")
[[ $listed == *"environment portals: 2 triangles"* ]] ||
    fail "ptworker --list does not count the window's portal: $listed"
# its front faces +z, into the room (the window is in the wall z = -2.5)
[[ $listed == *"front towards (0, 0, 1): 2 triangles"* ]] ||
    fail "ptworker --list does not say which way the portal faces: $listed"
park=$shared/envs/rooitou_park_1k.hdr
lights=("--background 0.8,0.9,1")
if [[ -f $park ]]; then
    lights+=("--env $park --env-rotate 180")
elif [[ ${CI:-} == true ]]; then
    fail "$park is missing (CI=true)"
else
    echo "note: $park is missing; the park map's run is skipped"
fi
common=(--res 40x32 --spp 32 --tile 16 -q)
k=0
for light in "${lights[@]}"; do
    k=$((k + 1))
    read -r -a l <<< "$light"
    "$bin/ptworker" --scene "$scene" "${l[@]}" "${common[@]}" --threads 2 -o "$tmp/ref$k.exr"
    for n in 1 3; do
        "$bin/ptserve" --local "$n" --worker-threads 1 "${l[@]}" "${common[@]}" \
            -o "$tmp/farm$k-$n.exr" "$scene" 2> "$tmp/serve.log" ||
            fail "ptserve --local $n ($light): $(cat "$tmp/serve.log")"
        "$bin/ptexr-diff" "$tmp/ref$k.exr" "$tmp/farm$k-$n.exr" > "$tmp/diff" ||
            fail "$light, the farm with $n workers: $(cat "$tmp/diff")"
    done
done
echo "PASS"
