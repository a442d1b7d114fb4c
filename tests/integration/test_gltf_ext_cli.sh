#!/usr/bin/env bash
# ptworker --scene on glTF extensions, end to end:
# - a file whose extensionsRequired names an unsupported extension exits 1
#   naming it, before rendering; listed in extensionsUsed only, it renders
#   with one warning naming it;
# - EXT_mesh_gpu_instancing: SimpleInstancing loads as 125 instances of
#   one 12-triangle mesh (--list) and renders equal to the same file with
#   its 125 instances written out as child nodes (each instance's
#   TRANSLATION, ROTATION and SCALE as the node's TRS, read from the
#   file's accessors here): not bit for bit, since an instance's hit point
#   is its transform of the mesh's float vertices where a copy's vertices
#   are transformed in double and rounded, but within a paired z-test of
#   the pixel differences (ptexr-diff --z 4); and it differs from its one
#   uninstanced cube by that test;
# - an instance count of 2^31 exits 1 with the cap named, at once;
# - a still of the skinned Fox is bit-identical to --time 0.5 of the same
#   file with an animation that holds every node at its own TRS (STEP keys,
#   the file's values rounded to float in both), and differs from the
#   Fox's own first pose at 0.5 s;
# - every sample asset in ../shared renders with no feature ignored but
#   occlusion textures and the Cornell box's vendor extension.
set -euo pipefail
bin=${PT_BIN:?}
src=${PT_SOURCE_DIR:?}
scenes=${PT_SHARED_SCENES:?}
inst=$scenes/SimpleInstancing/SimpleInstancing.glb
# shellcheck source=tests/integration/lib_shared.sh
. "$(dirname "$0")/lib_shared.sh"
need_shared "$inst"
tmp=$(mktemp -d /tmp/pt_gltf_ext_cli_XXXXXX)
cleanup() { if [ "${failed:-0}" = 0 ]; then rm -rf "$tmp"; else echo "logs kept in $tmp" >&2; fi; }
trap cleanup EXIT
failed=1
fail() { echo "FAIL: $*" >&2; exit 1; }
view=(--res 64x48 --spp 4 --seed 7 --background "0.6,0.7,0.8" -q)

# Required / used extensions, on a copy of the Cornell box.
python3 - "$src/scenes/cornell_box.gltf" "$tmp" <<'PY'
import json, sys
d = json.load(open(sys.argv[1]))
for name, req in (("required", True), ("used", False)):
    e = dict(d)
    e["extensionsUsed"] = d.get("extensionsUsed", []) + ["EXT_made_up"]
    if req:
        e["extensionsRequired"] = ["EXT_made_up"]
    e["materials"] = [dict(m, extensions={"EXT_made_up": {}}) for m in d["materials"]]
    json.dump(e, open(f"{sys.argv[2]}/{name}.gltf", "w"))
PY
set +e
"$bin/ptworker" --scene "$tmp/required.gltf" "${view[@]}" -o "$tmp/required.exr" 2> "$tmp/required.log"
rc=$?
set -e
[ $rc = 1 ] || fail "required: exit $rc: $(cat "$tmp/required.log")"
grep -q "requires extension EXT_made_up (extensionsRequired), which ptfarm does not support" \
  "$tmp/required.log" || fail "required: $(cat "$tmp/required.log")"
[ ! -e "$tmp/required.exr" ] || fail "required: an image was written"
"$bin/ptworker" --scene "$tmp/used.gltf" "${view[@]}" -o "$tmp/used.exr" 2> "$tmp/used.log" ||
  fail "used: $(cat "$tmp/used.log")"
[ "$(grep -c "EXT_made_up" "$tmp/used.log")" = 1 ] || fail "used: $(cat "$tmp/used.log")"

# Instances written out as nodes; the uninstanced cube; a count of 2^31.
python3 - "$inst" "$tmp" <<'PY'
import json, struct, sys
raw = open(sys.argv[1], "rb").read()
jl = struct.unpack_from("<I", raw, 12)[0]
doc = json.loads(raw[20:20 + jl])
bl = struct.unpack_from("<I", raw, 20 + jl)[0]
binc = raw[28 + jl:28 + jl + bl]

def floats(ai, n):
    a = doc["accessors"][ai]
    v = doc["bufferViews"][a["bufferView"]]
    assert a["componentType"] == 5126
    off = v.get("byteOffset", 0) + a.get("byteOffset", 0)
    stride = v.get("byteStride", 4 * n)
    return [list(struct.unpack_from(f"<{n}f", binc, off + i * stride)) for i in range(a["count"])]

def write(name, d):
    j = json.dumps(d).encode()
    j += b" " * (-len(j) % 4)
    b = binc + b"\0" * (-len(binc) % 4)
    out = struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(j) + 8 + len(b))
    out += struct.pack("<II", len(j), 0x4E4F534A) + j + struct.pack("<II", len(b), 0x004E4942) + b
    open(f"{sys.argv[2]}/{name}.glb", "wb").write(out)

node = doc["nodes"][0]
at = node["extensions"]["EXT_mesh_gpu_instancing"]["attributes"]
t, r, s = floats(at["TRANSLATION"], 3), floats(at["ROTATION"], 4), floats(at["SCALE"], 3)
copies = json.loads(json.dumps(doc))
n0 = copies["nodes"][0]
del n0["extensions"], n0["mesh"]
n0["children"] = list(range(1, len(t) + 1))
for i in range(len(t)):
    copies["nodes"].append({"mesh": 0, "translation": t[i], "rotation": r[i], "scale": s[i]})
copies["extensionsUsed"] = [e for e in copies.get("extensionsUsed", []) if e != "EXT_mesh_gpu_instancing"]
write("copies", copies)
one = json.loads(json.dumps(doc))
del one["nodes"][0]["extensions"]
one["extensionsUsed"] = []
write("one", one)
huge = json.loads(json.dumps(doc))
huge["accessors"][at["TRANSLATION"]]["count"] = 2 ** 31
write("huge", huge)
PY
"$bin/ptworker" --scene "$inst" "${view[@]}" -o "$tmp/inst.exr" 2> "$tmp/inst.log" ||
  fail "instanced: $(cat "$tmp/inst.log")"
if grep -q "warning" "$tmp/inst.log"; then fail "instanced: $(cat "$tmp/inst.log")"; fi
"$bin/ptworker" --scene "$tmp/copies.glb" "${view[@]}" -o "$tmp/copies.exr" 2> "$tmp/copies.log" ||
  fail "copies: $(cat "$tmp/copies.log")"
"$bin/ptworker" --scene "$tmp/one.glb" "${view[@]}" -o "$tmp/one.exr" 2> "$tmp/one.log" ||
  fail "one: $(cat "$tmp/one.log")"
"$bin/ptworker" --list "$inst" > "$tmp/inst.list" 2>&1 || fail "list: $(cat "$tmp/inst.list")"
grep -q "instances (EXT_mesh_gpu_instancing): 125 of 1 meshes, 1500 triangles once placed" \
  "$tmp/inst.list" || fail "list: $(cat "$tmp/inst.list")"
"$bin/ptexr-diff" --z 4 "$tmp/inst.exr" "$tmp/copies.exr" > "$tmp/z.log" ||
  fail "the instanced file differs from its instances written out: $(cat "$tmp/z.log")"
if "$bin/ptexr-diff" --z 4 "$tmp/inst.exr" "$tmp/one.exr" > /dev/null; then
  fail "the instanced file renders as its one uninstanced cube"
fi
set +e
timeout 20 "$bin/ptworker" --scene "$tmp/huge.glb" "${view[@]}" -o "$tmp/huge.exr" 2> "$tmp/huge.log"
rc=$?
set -e
[ $rc = 1 ] || fail "2^31 instances: exit $rc: $(cat "$tmp/huge.log")"
grep -q "EXT_mesh_gpu_instancing: 2147483648 instances (accessor 3), over the cap" "$tmp/huge.log" ||
  fail "2^31 instances: $(cat "$tmp/huge.log")"

# The Fox: still against its rest pose played as an animation.
fox=$scenes/Fox/Fox.glb
python3 - "$fox" "$tmp" <<'PY'
import json, struct, sys
raw = open(sys.argv[1], "rb").read()
jl = struct.unpack_from("<I", raw, 12)[0]
doc = json.loads(raw[20:20 + jl])
bl = struct.unpack_from("<I", raw, 20 + jl)[0]
binc = bytearray(raw[28 + jl:28 + jl + bl])
f32 = lambda v: struct.unpack("<f", struct.pack("<f", v))[0]
def add(data, ctype, count, typ):
    while len(binc) % 4:
        binc.append(0)
    doc["bufferViews"].append({"buffer": 0, "byteOffset": len(binc), "byteLength": len(data)})
    binc.extend(data)
    doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "componentType": ctype,
                             "count": count, "type": typ})
    return len(doc["accessors"]) - 1
times = add(struct.pack("<2f", 0.0, 1.0), 5126, 2, "SCALAR")
doc["accessors"][times].update({"min": [0.0], "max": [1.0]})
channels, samplers = [], []
for ni, n in enumerate(doc["nodes"]):
    if "matrix" in n:
        continue
    for path, dflt, typ in (("translation", [0, 0, 0], "VEC3"), ("rotation", [0, 0, 0, 1], "VEC4"),
                            ("scale", [1, 1, 1], "VEC3")):
        v = [f32(x) for x in n.get(path, dflt)]
        n[path] = v
        out = add(struct.pack(f"<{2 * len(v)}f", *(v + v)), 5126, 2, typ)
        samplers.append({"input": times, "output": out, "interpolation": "STEP"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": ni, "path": path}})
doc["animations"].append({"name": "Rest", "channels": channels, "samplers": samplers})
doc["buffers"][0]["byteLength"] = len(binc)
j = json.dumps(doc).encode()
j += b" " * (-len(j) % 4)
b = bytes(binc) + b"\0" * (-len(binc) % 4)
out = struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(j) + 8 + len(b))
out += struct.pack("<II", len(j), 0x4E4F534A) + j + struct.pack("<II", len(b), 0x004E4942) + b
open(f"{sys.argv[2]}/fox_rest.glb", "wb").write(out)
PY
"$bin/ptworker" --scene "$tmp/fox_rest.glb" "${view[@]}" -o "$tmp/fox_still.exr" 2> "$tmp/fox_still.log" ||
  fail "fox still: $(cat "$tmp/fox_still.log")"
"$bin/ptworker" --scene "$tmp/fox_rest.glb" "${view[@]}" --time 0.5 --animation Rest \
  -o "$tmp/fox_rest.exr" 2> "$tmp/fox_rest.log" || fail "fox rest: $(cat "$tmp/fox_rest.log")"
"$bin/ptworker" --scene "$tmp/fox_rest.glb" "${view[@]}" --time 0.5 --animation 0 \
  -o "$tmp/fox_anim.exr" 2> "$tmp/fox_anim.log" || fail "fox anim: $(cat "$tmp/fox_anim.log")"
"$bin/ptexr-diff" "$tmp/fox_still.exr" "$tmp/fox_rest.exr" ||
  fail "the Fox's still differs from its rest pose played at 0.5 s"
if "$bin/ptexr-diff" "$tmp/fox_still.exr" "$tmp/fox_anim.exr" > /dev/null; then
  fail "the Fox's still equals its first animation at 0.5 s"
fi

# Every sample asset renders with nothing ignored but occlusion textures
# (a path tracer computes occlusion) and the Cornell box's vendor material
# extension (NV_materials_mdl: optional, named once).
while IFS= read -r f; do
  "$bin/ptworker" --scene "$f" --res 8x8 --spp 1 --threads 1 --background "1,1,1" -o "$tmp/any.exr" \
    2> "$tmp/any.log" ||
    fail "$f: $(cat "$tmp/any.log")"
  left=$(grep -i "ignored\|not supported" "$tmp/any.log" | grep -v "occlusion textures are ignored" |
    grep -v "extension NV_materials_mdl is not supported" || true)
  [ -z "$left" ] || fail "$f: $left"
done < <(find "$scenes" \( -name '*.gltf' -o -name '*.glb' \) | sort)

failed=0
echo "ok: required and used extensions, instancing equals its copies, 2^31 instances refused,"
echo "    the skinned still equals its rest pose animated"
