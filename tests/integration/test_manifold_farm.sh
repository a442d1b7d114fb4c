#!/usr/bin/env bash
# Manifold NEE (common/render/manifold.h) solves each chain from the sample's
# own numbers and the scene: a farm's image of the glass ball with things
# inside under the studio map (refraction chains), and of the same ball under
# a sun (a directional light: refraction chains and reflection chains, whose
# reflector the sample's own numbers pick), and of scenes/chrome_sun.gltf's
# chrome ball under a sun (reflection chains off smooth metal, which keep a
# share of the throughput from vertex to vertex), is the standalone render's,
# bit for bit, with 1 and 3 local workers, and each standalone render did
# connect chains. Needs ../shared's map (skipped without it, unless CI=true).
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
shared=${PT_SHARED_SCENES:?}
tmp=$(mktemp -d /tmp/pt_manifold_farm_XXXXXX)
trap 'rm -rf "$tmp"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
env_map=$shared/../envs/studio_small_03_1k.hdr
if [[ ! -f $env_map ]]; then
    if [[ ${CI:-} == true ]]; then
        fail "$env_map is missing (CI=true)"
    fi
    echo "SKIP: $env_map is missing"
    exit 77
fi
# The ball under a sun instead of the map: glass_things.gltf with a
# directional light (KHR_lights_punctual) from 35 degrees above the floor.
python3 - "$src/scenes/glass_things.gltf" "$tmp/glass_sun.gltf" <<'PY' || fail "could not write the sun's scene"
import json, math, sys
g = json.load(open(sys.argv[1]))
g.setdefault("extensionsUsed", []).append("KHR_lights_punctual")
g.setdefault("extensions", {})["KHR_lights_punctual"] = {
    "lights": [{"type": "directional", "intensity": 3.0, "name": "sun"}]}
a = math.radians(-35.0)
g["nodes"].append({"name": "sun", "rotation": [math.sin(a / 2), 0.0, 0.0, math.cos(a / 2)],
                   "extensions": {"KHR_lights_punctual": {"light": 0}}})
g["scenes"][g.get("scene", 0)]["nodes"].append(len(g["nodes"]) - 1)
json.dump(g, open(sys.argv[2], "w"))
PY

run() { # NAME SCENE ARGS...: the standalone render connects chains; the farm's is it
    local name=$1 scene=$2
    shift 2
    local common=(--res 48x32 --spp 16 --tile 16 "$@")
    "$bin/ptworker" --scene "$scene" "${common[@]}" --threads 2 -o "$tmp/$name.exr" \
        2> "$tmp/$name.log" || fail "ptworker, $name: $(cat "$tmp/$name.log")"
    grep -q 'light paths through or off smooth glass or metal connected' "$tmp/$name.log" ||
        fail "$name: no chain was connected: $(cat "$tmp/$name.log")"
    for n in 1 3; do
        "$bin/ptserve" --local "$n" --worker-threads 1 "${common[@]}" -q \
            -o "$tmp/$name-farm$n.exr" "$scene" 2> "$tmp/$name-serve$n.log" ||
            fail "ptserve --local $n, $name: $(cat "$tmp/$name-serve$n.log")"
        "$bin/ptexr-diff" "$tmp/$name.exr" "$tmp/$name-farm$n.exr" > "$tmp/$name-diff$n" ||
            fail "$name, the farm with $n workers: $(cat "$tmp/$name-diff$n")"
    done
}
run map "$src/scenes/glass_things.gltf" --env "$env_map"
run sun "$tmp/glass_sun.gltf"
run chrome "$src/scenes/chrome_sun.gltf"
echo "PASS"
