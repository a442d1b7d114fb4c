#!/usr/bin/env python3
"""merge_gltf.py ROOM.gltf ASSET.gltf OUT_DIR NAME --at X,Y,Z [--rotate-y DEG]

Writes OUT_DIR/NAME.gltf: ROOM.gltf's scene with ASSET.gltf's default scene
placed in it under one more node (translated to X,Y,Z, turned about +Y by
DEG), and copies the files both reference into OUT_DIR, so that the loader,
which opens nothing outside a scene's own folder, finds them. For the
benchmarks of scenes a room holds (tests/bench/guiding.sh: the window room
with SheenChair in it). Both files must be .gltf with external buffers;
indices of the asset's nodes, meshes, accessors, views, buffers, materials,
textures, images and samplers are shifted past the room's, and its
KHR_materials_variants names are kept."""
import argparse
import json
import math
import os
import shutil
import sys


def load(path):
    with open(path) as f:
        return json.load(f)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("room")
    ap.add_argument("asset")
    ap.add_argument("out_dir")
    ap.add_argument("name")
    ap.add_argument("--at", required=True)
    ap.add_argument("--rotate-y", type=float, default=0.0)
    a = ap.parse_args()
    room, asset = load(a.room), load(a.asset)
    os.makedirs(a.out_dir, exist_ok=True)
    for doc, src in ((room, a.room), (asset, a.asset)):
        for b in doc.get("buffers", []) + doc.get("images", []):
            uri = b.get("uri")
            if uri is None or uri.startswith("data:"):
                continue
            uri = uri[2:] if uri.startswith("./") else uri
            if "/" in uri or ".." in uri:
                sys.exit("merge_gltf.py: %s: only files beside the scene (%s)" % (src, uri))
            shutil.copyfile(os.path.join(os.path.dirname(src), uri),
                            os.path.join(a.out_dir, uri))
    # The room's buffer is renamed if the asset's has its name.
    names = {b.get("uri") for b in asset.get("buffers", [])}
    for b in room.get("buffers", []):
        if b.get("uri") in names:
            sys.exit("merge_gltf.py: both scenes have a buffer %s" % b["uri"])

    def off(key):
        return len(room.get(key, []))

    shift = {k: off(k) for k in ("nodes", "meshes", "accessors", "bufferViews", "buffers",
                                 "materials", "textures", "images", "samplers")}
    for n in asset.get("nodes", []):
        if "mesh" in n:
            n["mesh"] += shift["meshes"]
        if "children" in n:
            n["children"] = [c + shift["nodes"] for c in n["children"]]
        for k in ("camera", "skin"):
            if k in n:
                sys.exit("merge_gltf.py: the asset's nodes may not hold a %s" % k)
    for m in asset.get("meshes", []):
        for p in m["primitives"]:
            p["attributes"] = {k: v + shift["accessors"] for k, v in p["attributes"].items()}
            if "indices" in p:
                p["indices"] += shift["accessors"]
            if "material" in p:
                p["material"] += shift["materials"]
            for t in p.get("targets", []):
                for k in t:
                    t[k] += shift["accessors"]
            var = p.get("extensions", {}).get("KHR_materials_variants")
            for mp in (var or {}).get("mappings", []):
                mp["material"] += shift["materials"]
    for acc in asset.get("accessors", []):
        if "bufferView" in acc:
            acc["bufferView"] += shift["bufferViews"]
        if "sparse" in acc:
            sys.exit("merge_gltf.py: sparse accessors are not merged")
    for v in asset.get("bufferViews", []):
        v["buffer"] += shift["buffers"]
    for t in asset.get("textures", []):
        if "source" in t:
            t["source"] += shift["images"]
        if "sampler" in t:
            t["sampler"] += shift["samplers"]
    for im in asset.get("images", []):
        if "bufferView" in im:
            im["bufferView"] += shift["bufferViews"]

    def retexture(o):  # a material's texture infos: the objects with an "index"
        if isinstance(o, dict):
            for v in o.values():
                if isinstance(v, dict) and isinstance(v.get("index"), int):
                    v["index"] += shift["textures"]
                retexture(v)
        elif isinstance(o, list):
            for v in o:
                retexture(v)

    for m in asset.get("materials", []):
        retexture(m)
    for k in shift:
        room.setdefault(k, []).extend(asset.get(k, []))
    roots = asset["scenes"][asset.get("scene", 0)]["nodes"]
    x, y, z = (float(c) for c in a.at.split(","))
    h = math.radians(a.rotate_y) / 2.0
    room["nodes"].append({"name": "placed " + os.path.basename(a.asset),
                          "translation": [x, y, z],
                          "rotation": [0.0, math.sin(h), 0.0, math.cos(h)],
                          "children": [r + shift["nodes"] for r in roots]})
    room["scenes"][room.get("scene", 0)]["nodes"].append(len(room["nodes"]) - 1)
    for k in ("extensionsUsed", "extensionsRequired"):
        merged = sorted(set(room.get(k, [])) | set(asset.get(k, [])))
        if merged:
            room[k] = merged
    if "extensions" in asset:
        room.setdefault("extensions", {}).update(asset["extensions"])
    with open(os.path.join(a.out_dir, a.name + ".gltf"), "w") as f:
        json.dump(room, f)


if __name__ == "__main__":
    main()
