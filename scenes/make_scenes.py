#!/usr/bin/env python3
"""Generate the project's own glTF 2.0 scenes.

    python3 scenes/make_scenes.py          (from the repository root)

writes scenes/cornell_box.gltf, scenes/furnace.gltf, scenes/glass_things.gltf
and scenes/chrome_sun.gltf next to this script.
The output is deterministic: running it again gives byte-identical files.
Standard library only (json, struct, base64, math).

The Cornell box geometry is the measured data published by the Cornell
University Program of Computer Graphics ("Cornell Box Data"); see README.md for
the source, the coordinate mapping and the values of the furnace test.
"""

import base64
import json
import math
import os
import struct

HERE = os.path.dirname(os.path.abspath(__file__))

GLTF_FLOAT = 5126
GLTF_USHORT = 5123
GLTF_UINT = 5125
TARGET_ARRAY = 34962
TARGET_ELEMENT_ARRAY = 34963
MODE_TRIANGLES = 4


# --------------------------------------------------------------------------
# Small vector helpers
# --------------------------------------------------------------------------

def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0])


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def normalize(a):
    n = math.sqrt(dot(a, a))
    return (a[0] / n, a[1] / n, a[2] / n)


def f32(x):
    """Round a Python float to the nearest float32 (what the buffer stores)."""
    return struct.unpack('<f', struct.pack('<f', x))[0]


# --------------------------------------------------------------------------
# glTF document builder
# --------------------------------------------------------------------------

class Builder:
    def __init__(self):
        self.blob = bytearray()
        self.buffer_views = []
        self.accessors = []

    def _view(self, data, target):
        while len(self.blob) % 4:
            self.blob.append(0)
        view = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(data),
                "target": target}
        self.blob.extend(data)
        self.buffer_views.append(view)
        return len(self.buffer_views) - 1

    def vec3(self, vectors, with_bounds):
        flat = [f32(c) for v in vectors for c in v]
        data = struct.pack('<%df' % len(flat), *flat)
        acc = {"bufferView": self._view(data, TARGET_ARRAY), "componentType": GLTF_FLOAT,
               "count": len(vectors), "type": "VEC3"}
        if with_bounds:
            # Bounds from the stored float32 values, as the specification requires.
            acc["min"] = [min(flat[i::3]) for i in range(3)]
            acc["max"] = [max(flat[i::3]) for i in range(3)]
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def indices(self, idx):
        big = max(idx) > 65535
        data = struct.pack('<%d%s' % (len(idx), 'I' if big else 'H'), *idx)
        acc = {"bufferView": self._view(data, TARGET_ELEMENT_ARRAY),
               "componentType": GLTF_UINT if big else GLTF_USHORT,
               "count": len(idx), "type": "SCALAR",
               "min": [min(idx)], "max": [max(idx)]}
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def primitive(self, positions, normals, idx, material):
        return {"attributes": {"POSITION": self.vec3(positions, True),
                               "NORMAL": self.vec3(normals, False)},
                "indices": self.indices(idx),
                "material": material,
                "mode": MODE_TRIANGLES}

    def finish(self, doc):
        while len(self.blob) % 4:
            self.blob.append(0)
        doc["accessors"] = self.accessors
        doc["bufferViews"] = self.buffer_views
        doc["buffers"] = [{
            "byteLength": len(self.blob),
            "uri": "data:application/octet-stream;base64,"
                   + base64.b64encode(bytes(self.blob)).decode('ascii'),
        }]
        return doc


def write(doc, name):
    text = json.dumps(doc, indent=1, ensure_ascii=True) + "\n"
    with open(os.path.join(HERE, name), "w", encoding="ascii", newline="\n") as f:
        f.write(text)
    print("wrote scenes/%s (%d bytes)" % (name, len(text)))


def lambert(name, rgb, emissive=None, strength=None, double_sided=False):
    """A pure Lambertian material: metallic 0, roughness 1, specularFactor 0."""
    m = {
        "name": name,
        "pbrMetallicRoughness": {
            "baseColorFactor": [rgb[0], rgb[1], rgb[2], 1.0],
            "metallicFactor": 0.0,
            "roughnessFactor": 1.0,
        },
        "extensions": {"KHR_materials_specular": {"specularFactor": 0.0}},
    }
    if emissive is not None:
        m["emissiveFactor"] = list(emissive)
    if strength is not None:
        m["extensions"]["KHR_materials_emissive_strength"] = {"emissiveStrength": strength}
    if double_sided:
        m["doubleSided"] = True
    return m


# --------------------------------------------------------------------------
# Cornell box
# --------------------------------------------------------------------------

# Cornell University Program of Computer Graphics, "Cornell Box Data".
# Millimetres, in the data's own frame: y up, the camera at z = -800 looking
# toward +z, the box opening at z = 0, the back wall at z = 559.2.
# Each surface is a list of quads (4 vertices each, as listed in the data).

CB_FLOOR = [[(552.8, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 559.2), (549.6, 0.0, 559.2)]]

CB_LIGHT = [[(343.0, 548.8, 227.0), (343.0, 548.8, 332.0),
             (213.0, 548.8, 332.0), (213.0, 548.8, 227.0)]]

CB_CEILING = [[(556.0, 548.8, 0.0), (556.0, 548.8, 559.2),
               (0.0, 548.8, 559.2), (0.0, 548.8, 0.0)]]

CB_BACK_WALL = [[(549.6, 0.0, 559.2), (0.0, 0.0, 559.2),
                 (0.0, 548.8, 559.2), (556.0, 548.8, 559.2)]]

CB_RIGHT_WALL = [[(0.0, 0.0, 559.2), (0.0, 0.0, 0.0),
                  (0.0, 548.8, 0.0), (0.0, 548.8, 559.2)]]   # green

CB_LEFT_WALL = [[(552.8, 0.0, 0.0), (549.6, 0.0, 559.2),
                 (556.0, 548.8, 559.2), (556.0, 548.8, 0.0)]]  # red

CB_SHORT_BLOCK = [
    [(130.0, 165.0, 65.0), (82.0, 165.0, 225.0), (240.0, 165.0, 272.0), (290.0, 165.0, 114.0)],
    [(290.0, 0.0, 114.0), (290.0, 165.0, 114.0), (240.0, 165.0, 272.0), (240.0, 0.0, 272.0)],
    [(130.0, 0.0, 65.0), (130.0, 165.0, 65.0), (290.0, 165.0, 114.0), (290.0, 0.0, 114.0)],
    [(82.0, 0.0, 225.0), (82.0, 165.0, 225.0), (130.0, 165.0, 65.0), (130.0, 0.0, 65.0)],
    [(240.0, 0.0, 272.0), (240.0, 165.0, 272.0), (82.0, 165.0, 225.0), (82.0, 0.0, 225.0)],
]

CB_TALL_BLOCK = [
    [(423.0, 330.0, 247.0), (265.0, 330.0, 296.0), (314.0, 330.0, 456.0), (472.0, 330.0, 406.0)],
    [(423.0, 0.0, 247.0), (423.0, 330.0, 247.0), (472.0, 330.0, 406.0), (472.0, 0.0, 406.0)],
    [(472.0, 0.0, 406.0), (472.0, 330.0, 406.0), (314.0, 330.0, 456.0), (314.0, 0.0, 456.0)],
    [(314.0, 0.0, 456.0), (314.0, 330.0, 456.0), (265.0, 330.0, 296.0), (265.0, 0.0, 296.0)],
    [(265.0, 0.0, 296.0), (265.0, 330.0, 296.0), (423.0, 330.0, 247.0), (423.0, 0.0, 247.0)],
]

CB_CAMERA_POS = (278.0, 273.0, -800.0)
CB_FOCAL = 0.035   # m
CB_FILM = 0.025    # m, square film

# The light is lowered this much below the ceiling so the two never coincide.
CB_LIGHT_DROP = 0.5  # mm

MM = 0.001


def cb_map(p):
    """Data frame (mm) -> glTF (m): a rotation by 180 degrees about y.

    x -> -x, z -> -z keeps the frame right-handed, keeps y up, makes the
    published camera (looking toward data +z) look down glTF -Z, and keeps
    the published left/right arrangement as seen from that camera.
    """
    # (+ 0.0 turns the -0.0 of a zero coordinate into 0.0.)
    return (-p[0] * MM + 0.0, p[1] * MM, -p[2] * MM + 0.0)


def oriented_quads(quads, facing):
    """Triangulate quads; orient every triangle with facing(a, n) > 0.

    Planar quads share four vertices with one normal; a non-planar quad is
    split into two triangles with their own flat normals.
    """
    pos, nrm, idx = [], [], []
    for quad in quads:
        q = [cb_map(v) for v in quad]
        tris = [(q[0], q[1], q[2]), (q[0], q[2], q[3])]
        oriented = []
        for a, b, c in tris:
            n = cross(sub(b, a), sub(c, a))
            if facing(a, n) < 0:
                b, c = c, b
                n = (-n[0], -n[1], -n[2])
            oriented.append(((a, b, c), normalize(n)))
        (t0, n0), (t1, n1) = oriented
        if dot(n0, n1) > 1.0 - 1e-12:
            # Planar: share four vertices, in the order that gives the facing.
            if t0[1] != q[1]:
                q = [q[0], q[3], q[2], q[1]]
            base = len(pos)
            pos += q
            nrm += [n0] * 4
            idx += [base, base + 1, base + 2, base, base + 2, base + 3]
        else:
            for tri, n in oriented:
                base = len(pos)
                pos += list(tri)
                nrm += [n] * 3
                idx += [base, base + 1, base + 2]
    # Check: every triangle's winding agrees with its normals.
    for t in range(0, len(idx), 3):
        a, b, c = (pos[i] for i in idx[t:t + 3])
        g = cross(sub(b, a), sub(c, a))
        assert dot(g, nrm[idx[t]]) > 0 and facing(a, g) > 0
    return pos, nrm, idx


def meshes_of(b, parts):
    """A mesh and a node of its own for each (name, (positions, normals,
    indices), material) of parts, in order."""
    meshes, nodes = [], []
    for name, (pos, nrm, idx), mat in parts:
        meshes.append({"name": name, "primitives": [b.primitive(pos, nrm, idx, mat)]})
        nodes.append({"name": name, "mesh": len(meshes) - 1})
    return meshes, nodes


def cornell_box():
    white = (0.725, 0.71, 0.68)
    red = (0.63, 0.065, 0.05)
    green = (0.14, 0.45, 0.091)
    materials = [
        lambert("white", white),
        lambert("red", red),
        lambert("green", green),
        lambert("light", (0.78, 0.78, 0.78), emissive=(1.0, 0.706, 0.235), strength=17.0),
    ]
    WHITE, RED, GREEN, LIGHT = range(4)

    # Interior reference point (data frame), mapped: walls face it.
    inside = cb_map((278.0, 274.4, 279.6))

    def toward_inside(a, n):
        return dot(n, sub(inside, a))

    def away_from(center):
        c = cb_map(center)
        return lambda a, n: dot(n, sub(a, c))

    def facing_down(a, n):
        return -n[1]

    light = [[(x, y - CB_LIGHT_DROP, z) for (x, y, z) in q] for q in CB_LIGHT]
    short_c = (186.0, 82.5, 168.5)
    tall_c = (368.5, 165.0, 351.5)

    surfaces = [
        ("floor", CB_FLOOR, toward_inside, WHITE),
        ("ceiling", CB_CEILING, toward_inside, WHITE),
        ("back_wall", CB_BACK_WALL, toward_inside, WHITE),
        ("right_wall_green", CB_RIGHT_WALL, toward_inside, GREEN),
        ("left_wall_red", CB_LEFT_WALL, toward_inside, RED),
        ("light", light, facing_down, LIGHT),
        ("short_block", CB_SHORT_BLOCK, away_from(short_c), WHITE),
        ("tall_block", CB_TALL_BLOCK, away_from(tall_c), WHITE),
    ]

    b = Builder()
    meshes, nodes = meshes_of(b, [(name, oriented_quads(quads, facing), mat)
                                  for name, quads, facing, mat in surfaces])

    yfov = 2.0 * math.atan(0.5 * CB_FILM / CB_FOCAL)
    nodes.append({"name": "Camera", "camera": 0,
                  "translation": list(cb_map(CB_CAMERA_POS))})
    doc = {
        "asset": {"version": "2.0", "generator": "ptfarm scenes/make_scenes.py",
                  "copyright": "Geometry: Cornell University Program of Computer Graphics, "
                               "Cornell Box Data"},
        "extensionsUsed": ["KHR_materials_emissive_strength", "KHR_materials_specular"],
        "scene": 0,
        "scenes": [{"name": "cornell_box", "nodes": list(range(len(nodes))),
                    "extras": {"source": "Cornell University Program of Computer Graphics, "
                                         "Cornell Box Data (measured geometry, millimetres)",
                               "units": "metres (data x 0.001)",
                               "mapping": "glTF (x, y, z) = 0.001 * (-x, y, -z) of the data"}}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "cameras": [{"name": "Camera", "type": "perspective",
                     "perspective": {"yfov": yfov, "aspectRatio": 1.0, "znear": 0.01}}],
    }
    write(b.finish(doc), "cornell_box.gltf")


# --------------------------------------------------------------------------
# White furnace
# --------------------------------------------------------------------------

FURNACE_ALBEDO = 0.5
FURNACE_EMISSION = 0.5


def furnace():
    """Closed UV sphere, radius 1, inward normals and inward-facing winding."""
    n_lon, n_lat = 64, 32
    pos = [(0.0, 1.0, 0.0)]
    for i in range(1, n_lat):
        theta = math.pi * i / n_lat
        y, r = math.cos(theta), math.sin(theta)
        for j in range(n_lon):
            phi = 2.0 * math.pi * j / n_lon
            pos.append((r * math.cos(phi), y, -r * math.sin(phi)))
    pos.append((0.0, -1.0, 0.0))
    south = len(pos) - 1

    def ring(i, j):  # i in 1..n_lat-1
        return 1 + (i - 1) * n_lon + (j % n_lon)

    tris = []
    for j in range(n_lon):
        tris.append((0, ring(1, j), ring(1, j + 1)))
        tris.append((south, ring(n_lat - 1, j + 1), ring(n_lat - 1, j)))
    for i in range(1, n_lat - 1):
        for j in range(n_lon):
            a, b = ring(i, j), ring(i, j + 1)
            c, d = ring(i + 1, j), ring(i + 1, j + 1)
            tris.append((a, c, d))
            tris.append((a, d, b))

    # Make the inside the front side: counter-clockwise seen from the centre.
    idx = []
    for t in tris:
        a, b, c = (pos[k] for k in t)
        g = cross(sub(b, a), sub(c, a))
        if dot(g, a) > 0:  # points outward: flip
            t = (t[0], t[2], t[1])
        idx += list(t)
    for k in range(0, len(idx), 3):
        a, b, c = (pos[m] for m in idx[k:k + 3])
        assert dot(cross(sub(b, a), sub(c, a)), a) < 0
    nrm = [(-p[0], -p[1], -p[2]) for p in pos]

    b = Builder()
    e = FURNACE_EMISSION
    mat = lambert("furnace", (FURNACE_ALBEDO,) * 3, emissive=(e, e, e), double_sided=True)
    doc = {
        "asset": {"version": "2.0", "generator": "ptfarm scenes/make_scenes.py"},
        "extensionsUsed": ["KHR_materials_specular"],
        "scene": 0,
        "scenes": [{"name": "furnace", "nodes": [0, 1],
                    "extras": {"furnace": {"albedo": FURNACE_ALBEDO,
                                           "emission": FURNACE_EMISSION,
                                           "expected": FURNACE_EMISSION
                                           / (1.0 - FURNACE_ALBEDO)}}}],
        "nodes": [{"name": "sphere", "mesh": 0},
                  {"name": "Camera", "camera": 0}],
        "meshes": [{"name": "sphere", "primitives": [b.primitive(pos, nrm, idx, 0)]}],
        "materials": [mat],
        "cameras": [{"name": "Camera", "type": "perspective",
                     "perspective": {"yfov": 1.0, "aspectRatio": 1.0, "znear": 0.01}}],
    }
    write(b.finish(doc), "furnace.gltf")


# --------------------------------------------------------------------------
# Glass with things inside
# --------------------------------------------------------------------------

def uv_sphere(centre, radius, n_lon=48, n_lat=24):
    """Closed UV sphere, outward normals, counter-clockwise from outside."""
    pos = [(0.0, 1.0, 0.0)]
    for i in range(1, n_lat):
        theta = math.pi * i / n_lat
        for j in range(n_lon):
            phi = 2.0 * math.pi * j / n_lon
            pos.append((math.sin(theta) * math.cos(phi), math.cos(theta),
                        -math.sin(theta) * math.sin(phi)))
    pos.append((0.0, -1.0, 0.0))
    south = len(pos) - 1

    def ring(i, j):
        return 1 + (i - 1) * n_lon + (j % n_lon)

    tris = []
    for j in range(n_lon):
        tris.append((0, ring(1, j), ring(1, j + 1)))
        tris.append((south, ring(n_lat - 1, j + 1), ring(n_lat - 1, j)))
    for i in range(1, n_lat - 1):
        for j in range(n_lon):
            a, b = ring(i, j), ring(i, j + 1)
            c, d = ring(i + 1, j), ring(i + 1, j + 1)
            tris += [(a, c, d), (a, d, b)]
    idx = []
    for t in tris:
        a, b, c = (pos[k] for k in t)
        if dot(cross(sub(b, a), sub(c, a)), a) < 0:  # points inward: flip
            t = (t[0], t[2], t[1])
        idx += list(t)
    world = [(centre[0] + radius * p[0], centre[1] + radius * p[1], centre[2] + radius * p[2])
             for p in pos]
    return world, list(pos), idx


def balls_on_floor(b, balls):
    """A 6 x 6 floor (material 0) and UV spheres (name, centre, radius,
    material) on it: the meshes of glass_things and chrome_sun."""
    floor = [(-3.0, 0.0, -3.0), (-3.0, 0.0, 3.0), (3.0, 0.0, 3.0), (3.0, 0.0, -3.0)]
    up = [(0.0, 1.0, 0.0)] * 4
    meshes = [{"name": "floor", "primitives": [b.primitive(floor, up, [0, 1, 2, 0, 2, 3], 0)]}]
    for name, centre, radius, mat in balls:
        pos, nrm, idx = uv_sphere(centre, radius)
        meshes.append({"name": name, "primitives": [b.primitive(pos, nrm, idx, mat)]})
    return meshes


def balls_doc(name, extensions, nodes, meshes, materials, camera_at):
    """glass_things' and chrome_sun's document: nodes, then a camera at
    camera_at looking a little down (yfov 0.6)."""
    return {
        "asset": {"version": "2.0", "generator": "ptfarm scenes/make_scenes.py"},
        "extensionsUsed": extensions,
        "scene": 0,
        "scenes": [{"name": name, "nodes": list(range(len(nodes) + 1))}],
        "nodes": nodes + [{"name": "Camera", "camera": 0, "translation": camera_at,
                           "rotation": [-0.0998334, 0.0, 0.0, 0.9950042]}],
        "meshes": meshes,
        "materials": materials,
        "cameras": [{"name": "Camera", "type": "perspective",
                     "perspective": {"yfov": 0.6, "aspectRatio": 1.0, "znear": 0.01}}],
    }


def glass_things():
    """A solid glass ball on a floor with a metal ball and a matte ball inside
    it, for an environment map to light (path guiding's benchmark: light
    that reaches what is inside only through glass)."""
    b = Builder()
    meshes = balls_on_floor(b, (("glass", (0.0, 0.6, 0.0), 0.6, 1),
                                ("metal", (-0.2, 0.45, 0.1), 0.2, 2),
                                ("matte", (0.22, 0.55, -0.1), 0.16, 3)))
    materials = [
        lambert("floor", (0.6, 0.6, 0.6)),
        {"name": "glass",
         "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0],
                                  "metallicFactor": 0.0, "roughnessFactor": 0.0},
         "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1.0},
                        "KHR_materials_volume": {"thicknessFactor": 1.2}}},
        {"name": "gold",
         "pbrMetallicRoughness": {"baseColorFactor": [1.0, 0.78, 0.34, 1.0],
                                  "metallicFactor": 1.0, "roughnessFactor": 0.25}},
        lambert("matte", (0.8, 0.15, 0.1)),
    ]
    doc = balls_doc("glass_things", ["KHR_materials_specular", "KHR_materials_transmission",
                                     "KHR_materials_volume"],
                    [{"name": "floor", "mesh": 0}, {"name": "glass", "mesh": 1},
                     {"name": "metal", "mesh": 2}, {"name": "matte", "mesh": 3}],
                    meshes, materials, [0.0, 1.3, 3.6])
    write(b.finish(doc), "glass_things.gltf")


def chrome_sun():
    """A chrome ball (metallic 1, roughness 0) and a matte ball on a floor
    under a sun (a directional light, KHR_lights_punctual, 35 degrees above
    the horizon): the sun the chrome mirrors onto the floor and the matte
    ball, light that only reflection chains off smooth metal find."""
    b = Builder()
    meshes = balls_on_floor(b, (("chrome", (0.0, 0.6, 0.0), 0.6, 1),
                                ("matte", (1.1, 0.3, 0.5), 0.3, 2)))
    materials = [
        lambert("floor", (0.6, 0.6, 0.6)),
        {"name": "chrome",
         "pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.9, 0.9, 1.0],
                                  "metallicFactor": 1.0, "roughnessFactor": 0.0}},
        lambert("matte", (0.8, 0.15, 0.1)),
    ]
    a = math.radians(-35.0)
    doc = balls_doc("chrome_sun", ["KHR_lights_punctual", "KHR_materials_specular"],
                    [{"name": "floor", "mesh": 0}, {"name": "chrome", "mesh": 1},
                     {"name": "matte", "mesh": 2},
                     {"name": "sun", "rotation": [f32(math.sin(a / 2)), 0.0, 0.0,
                                                  f32(math.cos(a / 2))],
                      "extensions": {"KHR_lights_punctual": {"light": 0}}}],
                    meshes, materials, [0.3, 1.4, 4.8])
    doc["extensions"] = {"KHR_lights_punctual": {"lights": [
        {"name": "sun", "type": "directional", "intensity": 3.0}]}}
    write(b.finish(doc), "chrome_sun.gltf")


def look_rotation(eye, target):
    """The glTF rotation (x, y, z, w) of a camera at eye looking at target,
    y up (a camera looks down its -Z)."""
    f = normalize(sub(target, eye))
    r = normalize(cross(f, (0.0, 1.0, 0.0)))
    u = cross(r, f)
    z = (-f[0], -f[1], -f[2])
    m = ((r[0], u[0], z[0]), (r[1], u[1], z[1]), (r[2], u[2], z[2]))  # columns r, u, z
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        q = ((m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, 0.25 * s)
    else:
        i = max(range(3), key=lambda k: m[k][k])
        j, k = (i + 1) % 3, (i + 2) % 3
        s = math.sqrt(1.0 + m[i][i] - m[j][j] - m[k][k]) * 2.0
        q = [0.0, 0.0, 0.0, (m[k][j] - m[j][k]) / s]
        q[i] = 0.25 * s
        q[j] = (m[j][i] + m[i][j]) / s
        q[k] = (m[k][i] + m[i][k]) / s
    return [f32(c) for c in q]


def window_room(portal=False):
    """A closed room (4 x 3 x 5 m) with one window in its back wall and a
    cabinet, for an environment map to light through the window: under
    rooitou_park_1k.hdr the low sun falls through it onto the left wall, and
    the rest of the room is lit by that patch and the sky, in bounces (the
    indirect light bidirectional path tracing is for). The camera looks
    into the room, away from the window. With portal, window_portal.gltf:
    the same room with the window marked as an environment portal (a quad
    in its opening whose node's extras say "ptfarm_portal": true)."""
    def quad(corners, normal):
        a, b_, c, d = corners
        if dot(cross(sub(b_, a), sub(c, a)), normal) < 0.0:
            a, b_, c, d = a, d, c, b_
        return [a, b_, c, d], [normal] * 4, [0, 1, 2, 0, 2, 3]

    def box_faces(lo, hi):
        (x0, y0, z0), (x1, y1, z1) = lo, hi
        return [
            ([(x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)], (0.0, 1.0, 0.0)),
            ([(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)], (0.0, 0.0, 1.0)),
            ([(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)], (0.0, 0.0, -1.0)),
            ([(x1, y0, z0), (x1, y0, z1), (x1, y1, z1), (x1, y1, z0)], (1.0, 0.0, 0.0)),
            ([(x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0)], (-1.0, 0.0, 0.0)),
        ]

    X, Y, Z = 2.0, 3.0, 2.5
    wx0, wx1, wy0, wy1 = 0.2, 1.4, 0.9, 2.1  # the window, in the wall z = -Z
    walls = [
        ("floor", [(-X, 0.0, -Z), (X, 0.0, -Z), (X, 0.0, Z), (-X, 0.0, Z)], (0.0, 1.0, 0.0), 1),
        ("ceiling", [(-X, Y, -Z), (X, Y, -Z), (X, Y, Z), (-X, Y, Z)], (0.0, -1.0, 0.0), 0),
        ("front", [(-X, 0.0, Z), (X, 0.0, Z), (X, Y, Z), (-X, Y, Z)], (0.0, 0.0, -1.0), 0),
        ("left", [(-X, 0.0, -Z), (-X, 0.0, Z), (-X, Y, Z), (-X, Y, -Z)], (1.0, 0.0, 0.0), 0),
        ("right", [(X, 0.0, -Z), (X, 0.0, Z), (X, Y, Z), (X, Y, -Z)], (-1.0, 0.0, 0.0), 0),
        ("back_a", [(-X, 0.0, -Z), (wx0, 0.0, -Z), (wx0, Y, -Z), (-X, Y, -Z)], (0.0, 0.0, 1.0), 0),
        ("back_b", [(wx1, 0.0, -Z), (X, 0.0, -Z), (X, Y, -Z), (wx1, Y, -Z)], (0.0, 0.0, 1.0), 0),
        ("back_c", [(wx0, 0.0, -Z), (wx1, 0.0, -Z), (wx1, wy0, -Z), (wx0, wy0, -Z)],
         (0.0, 0.0, 1.0), 0),
        ("back_d", [(wx0, wy1, -Z), (wx1, wy1, -Z), (wx1, Y, -Z), (wx0, Y, -Z)],
         (0.0, 0.0, 1.0), 0),
    ]
    walls += [("cabinet_%d" % i, c, n, 2)
              for i, (c, n) in enumerate(box_faces((-1.2, 0.0, -0.6), (0.0, 0.9, 0.4)))]
    if portal:
        walls.append(("window_portal", [(wx0, wy0, -Z), (wx1, wy0, -Z), (wx1, wy1, -Z),
                                        (wx0, wy1, -Z)], (0.0, 0.0, 1.0), 0))
    b = Builder()
    meshes, nodes = meshes_of(b, [(name, quad(corners, normal), mat)
                                  for name, corners, normal, mat in walls])
    if portal:
        nodes[-1]["extras"] = {"ptfarm_portal": True}
    materials = [
        lambert("plaster", (0.75, 0.73, 0.7), double_sided=True),
        lambert("wood", (0.45, 0.3, 0.2), double_sided=True),
        lambert("cabinet", (0.2, 0.35, 0.6), double_sided=True),
    ]
    eye, target = (1.5, 1.4, 2.2), (-1.5, 0.8, -0.5)
    nodes.append({"name": "Camera", "camera": 0, "translation": list(eye),
                  "rotation": look_rotation(eye, target)})
    doc = {
        "asset": {"version": "2.0", "generator": "ptfarm scenes/make_scenes.py"},
        "extensionsUsed": ["KHR_materials_specular"],
        "scene": 0,
        "scenes": [{"name": "window_room", "nodes": list(range(len(nodes)))}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "cameras": [{"name": "Camera", "type": "perspective",
                     "perspective": {"yfov": 1.2, "aspectRatio": 1.0, "znear": 0.01}}],
    }
    write(b.finish(doc), "window_portal.gltf" if portal else "window_room.gltf")


if __name__ == "__main__":
    cornell_box()
    furnace()
    glass_things()
    chrome_sun()
    window_room()
    window_room(portal=True)
