#!/usr/bin/env python3
"""cornell_grid.py - scenes/cornell_box.gltf with its ceiling light cut into
N x N separate square cells (each 80 % of a 1/N-th of the light's side, two
triangles, facing down): many emissive triangles gathered in one small place,
for tests/bench/light_tree.sh (docs/bench/light_tree.md, "A rule by the
lights' spread").

    python3 tests/bench/cornell_grid.py OUT.gltf [N]   (N: 8 by default)
"""
import base64
import json
import os
import struct
import sys


def main():
    if len(sys.argv) not in (2, 3):
        sys.exit("usage: cornell_grid.py OUT.gltf [N]")
    n = int(sys.argv[2]) if len(sys.argv) == 3 else 8
    if not 1 <= n <= 256:
        sys.exit("cornell_grid.py: N from 1 to 256")
    root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
    with open(os.path.join(root, "scenes", "cornell_box.gltf"), encoding="utf-8") as f:
        d = json.load(f)
    buf = bytearray(base64.b64decode(d["buffers"][0]["uri"].split(",", 1)[1]))
    mesh = next(m for m in d["meshes"] if m["name"] == "light")
    prim = mesh["primitives"][0]
    acc = d["accessors"][prim["attributes"]["POSITION"]]
    lo, hi = acc["min"], acc["max"]
    y = lo[1]
    pos, idx = [], []
    for j in range(n):
        for i in range(n):
            x0 = lo[0] + (hi[0] - lo[0]) * i / n
            x1 = lo[0] + (hi[0] - lo[0]) * (i + 0.8) / n
            z0 = lo[2] + (hi[2] - lo[2]) * j / n
            z1 = lo[2] + (hi[2] - lo[2]) * (j + 0.8) / n
            b = len(pos)
            pos += [(x0, y, z0), (x1, y, z0), (x1, y, z1), (x0, y, z1)]
            idx += [b, b + 2, b + 3, b, b + 1, b + 2]  # wound to face -y
    while len(buf) % 4:
        buf.append(0)
    views = []
    for data in (
        b"".join(struct.pack("<3f", *v) for v in pos),
        b"".join(struct.pack("<3f", 0.0, -1.0, 0.0) for _ in pos),
        b"".join(struct.pack("<I", k) for k in idx),
    ):
        views.append({"buffer": 0, "byteOffset": len(buf), "byteLength": len(data)})
        buf += data
    bv, ac = len(d["bufferViews"]), len(d["accessors"])
    d["bufferViews"] += views
    mn = [min(v[k] for v in pos) for k in range(3)]
    mx = [max(v[k] for v in pos) for k in range(3)]
    d["accessors"] += [
        {"bufferView": bv, "componentType": 5126, "count": len(pos), "type": "VEC3",
         "min": mn, "max": mx},
        {"bufferView": bv + 1, "componentType": 5126, "count": len(pos), "type": "VEC3"},
        {"bufferView": bv + 2, "componentType": 5125, "count": len(idx), "type": "SCALAR"},
    ]
    prim["attributes"] = {"POSITION": ac, "NORMAL": ac + 1}
    prim["indices"] = ac + 2
    d["buffers"][0]["byteLength"] = len(buf)
    d["buffers"][0]["uri"] = ("data:application/octet-stream;base64,"
                              + base64.b64encode(bytes(buf)).decode())
    with open(sys.argv[1], "w", encoding="utf-8") as f:
        json.dump(d, f)


if __name__ == "__main__":
    main()
