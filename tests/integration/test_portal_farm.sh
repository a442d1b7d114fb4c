#!/usr/bin/env bash
# Environment portals travel in the scene: every worker reads them from the
# glTF file and samples the environment through them alike, so a farm's
# image of the window room with its window marked (scenes/window_portal.gltf)
# is the standalone render's, bit for bit, with 1 and 3 local workers: under
# a uniform background, and under the park map turned so that its sun is
# behind the room (a map with a sun that cannot shine in: the portals are
# used), which needs ../shared (skipped without it, unless CI=true). And a
# portal wound the wrong way is named before a render, and kept as its
# job's message on a queue.
set -euo pipefail
# shellcheck source=tests/integration/lib_farm.sh
. "$(dirname "$0")/lib_farm.sh"
farm_init portal_farm
shared=${PT_SHARED_SCENES:?}/..
scene=$src/scenes/window_portal.gltf
listed=$("$bin/ptworker" --list "$scene")
[[ $listed == *"environment portals: 2 triangles"* ]] ||
    fail "ptworker --list does not count the window's portal: $listed"
# its front faces +z, into the room (the window is in the wall z = -2.5)
[[ $listed == *"front towards (0, 0, 1): 2 triangles"* ]] ||
    fail "ptworker --list does not say which way the portal faces: $listed"
# The window's portal wound the wrong way (its node mirrored about the
# wall's plane: the corners stay, and glTF's front face turns clockwise,
# out of the room) is named before the render, by ptworker and by the
# coordinator; the window as it is, not.
# The same with a cabinet moving, rendered with a shutter: moving triangles
# too are probed.
python3 - "$scene" "$tmp/reversed.gltf" "$tmp/moving.gltf" <<'PY'
import base64, json, struct, sys
g = json.load(open(sys.argv[1]))
node = next(n for n in g["nodes"] if n.get("extras", {}).get("ptfarm_portal"))
node["matrix"] = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, -1, 0, 0, 0, -5, 1]  # z -> -5 - z
json.dump(g, open(sys.argv[2], "w"))
data = struct.pack("<8f", 0, 1, 0, 0, 0, 0.3, 0, 0)  # times 0, 1 s; x from 0 to 0.3
g["buffers"].append({"byteLength": 32, "uri": "data:application/octet-stream;base64,"
                     + base64.b64encode(data).decode()})
b, v, a = len(g["buffers"]) - 1, len(g["bufferViews"]), len(g["accessors"])
g["bufferViews"] += [{"buffer": b, "byteOffset": 0, "byteLength": 8},
                     {"buffer": b, "byteOffset": 8, "byteLength": 24}]
g["accessors"] += [{"bufferView": v, "componentType": 5126, "count": 2, "type": "SCALAR",
                    "min": [0], "max": [1]},
                   {"bufferView": v + 1, "componentType": 5126, "count": 2, "type": "VEC3"}]
cab = next(i for i, n in enumerate(g["nodes"]) if n.get("name") == "cabinet_0")
g["animations"] = [{"samplers": [{"input": a, "output": a + 1}],
                    "channels": [{"sampler": 0, "target": {"node": cab, "path": "translation"}}]}]
json.dump(g, open(sys.argv[3], "w"))
PY
warned="2 of 2 portal triangles look wound the wrong way"
listed=$("$bin/ptworker" --list "$tmp/reversed.gltf")
[[ $listed == *"front towards (0, 0, -1): 2 triangles"*"$warned"* ]] ||
    fail "ptworker --list does not name the reversed portal: $listed"
[[ $("$bin/ptworker" --list "$scene") != *"wound the wrong way"* ]] ||
    fail "ptworker --list warns of the window's portal"
tiny=(--background "1,1,1" --res 8x8 --spp 1 -q)
"$bin/ptworker" --scene "$scene" "${tiny[@]}" -o "$tmp/fwd.exr" 2> "$tmp/fwd.log"
[[ $(cat "$tmp/fwd.log") != *"wound the wrong way"* ]] ||
    fail "ptworker warns of the window's portal: $(cat "$tmp/fwd.log")"
"$bin/ptworker" --scene "$tmp/reversed.gltf" "${tiny[@]}" -o "$tmp/rev.exr" 2> "$tmp/rev.log"
[[ $(cat "$tmp/rev.log") == *"$warned"*"(0, 0, -1)"* ]] ||
    fail "ptworker does not name the reversed portal: $(cat "$tmp/rev.log")"
"$bin/ptworker" --scene "$tmp/moving.gltf" "${tiny[@]}" --shutter 0,0.5 -o "$tmp/mov.exr" \
    2> "$tmp/mov.log" || fail "ptworker, moving: $(cat "$tmp/mov.log")"
[[ $(cat "$tmp/mov.log") == *"$warned"* && $(cat "$tmp/mov.log") != *"--shutter"* ]] ||
    fail "ptworker does not name the reversed portal among moving triangles: $(cat "$tmp/mov.log")"
"$bin/ptserve" --local 1 "${tiny[@]}" -o "$tmp/rev_farm.exr" "$tmp/reversed.gltf" \
    2> "$tmp/serve.log" || fail "ptserve --local 1, reversed: $(cat "$tmp/serve.log")"
[[ $(cat "$tmp/serve.log") == *"$warned"* ]] ||
    fail "ptserve does not name the reversed portal: $(cat "$tmp/serve.log")"
# Submitted to a queue, the job keeps it as its message: ptctl status shows
# it to the client (no worker needed: the upload check names it).
serve queue.log
id=$("$bin/ptctl" submit "$tmp/reversed.gltf" --background "1,1,1" --res 8x8 --spp 1 \
    2> "$tmp/submit.log")
[[ $(cat "$tmp/submit.log") == "ptctl: job $id: warning: $warned"* ]] ||
    fail "ptctl submit does not print the warning: $(cat "$tmp/submit.log")"
status=$("$bin/ptctl" status "$id")
[[ $status == *"message"*"$warned"* ]] || fail "ptctl status does not show the warning: $status"
id=$("$bin/ptctl" submit "$scene" --background "1,1,1" --res 8x8 --spp 1 2> "$tmp/submit.log")
[[ ! -s $tmp/submit.log ]] || fail "ptctl submit printed: $(cat "$tmp/submit.log")"
status=$("$bin/ptctl" status "$id")
[[ $status != *"wound the wrong way"* ]] || fail "the window's job has the warning: $status"
stop_server
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
failed=0
echo "PASS"
