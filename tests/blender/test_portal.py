"""Cycles portal lights become environment portals: an area light with
Portal checked (a rectangle 2 x 1 m, standing upright over the floor)
goes into the exported file as a node with a two-triangle mesh whose
extras say "ptfarm_portal": true, at the light's corners in glTF's +Y-up
space; ptworker --list counts it; the export warns for no area light, and
a round portal is named in a warning. The portal is an opening, not a
surface: the floor under a white background renders the same with a 6 x 4 m
portal 1 m over it as without it (the means of two renders of the same seed
agree within 2 %, where a surface there would shade most of the view).
"""
import json
import os
import struct
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bpy  # noqa: E402
import farmtest as t  # noqa: E402

t.install_addon()
from ptfarm_blender import scene_export  # noqa: E402

scene = t.empty_scene("portal")
t.add_mesh(bpy.ops.mesh.primitive_plane_add, "Floor", t.principled("floor", (0.7, 0.7, 0.7)),
           size=8.0)
t.add_camera("Cam", (0.0, -6.0, 4.0), (0.0, 0.0, 0.0))
world = scene.world
world.node_tree.nodes["Background"].inputs["Color"].default_value = (1, 1, 1, 1)
world.node_tree.nodes["Background"].inputs["Strength"].default_value = 1.0
scene.render.resolution_x = scene.render.resolution_y = 32
scene.render.resolution_percentage = 100
s = scene.ptfarm
s.server, s.token_file, s.output_dir = t.SERVER, t.TOKEN, os.path.join(t.TMP, "portal") + "/"
s.spp, s.seed = 64, 3
folder = os.path.join(t.TMP, "portal_export")


def export():
    exp = scene_export.export(scene, folder, False, s)
    with open(exp.path, "rb") as f:
        data = f.read()
    n = struct.unpack_from("<I", data, 12)[0]
    return exp, json.loads(data[20:20 + n].decode("utf-8"))


def render(exp, name):
    out = os.path.join(t.TMP, name + ".exr")
    t.ptworker(exp.path, exp.args, out)
    stats = subprocess.run([os.path.join(t.BIN, "ptbench"), "error", out, "--constant", "0"],
                           stdout=subprocess.PIPE, text=True, check=True).stdout
    mean = [float(v) for v in next(ln for ln in stats.splitlines()
                                   if ln.startswith("mean")).split()[1:4]]
    return sum(mean) / 3.0


plain, _ = export()
without = render(plain, "without")

# The portal: 2 m along X, 1 m along its local Y, turned 90 degrees about X
# (upright, shining towards +Y: its local -Z), centred at (1, 2, 3).
data = bpy.data.lights.new("Window", "AREA")
data.shape = "RECTANGLE"
data.size, data.size_y = 2.0, 1.0
data.cycles.is_portal = True
obj = bpy.data.objects.new("Window", data)
obj.location = (1.0, 2.0, 3.0)
obj.rotation_euler = (1.5707963267948966, 0.0, 0.0)
scene.collection.objects.link(obj)
bpy.context.view_layer.update()

exp, doc = export()
nodes = [nd for nd in doc["nodes"] if nd.get("extras", {}).get("ptfarm_portal") is True]
t.check(len(nodes) == 1 and nodes[0]["name"] == "Window",
        "the portal light is a node with extras ptfarm_portal (%d such nodes)" % len(nodes))
acc = doc["accessors"][doc["meshes"][nodes[0]["mesh"]]["primitives"][0]["attributes"]["POSITION"]]
# Local (x, y, 0), x in [-1, 1], y in [-0.5, 0.5], turned about X: (x, 0, y)
# about (1, 2, 3); in glTF's (X, Z, -Y): X 0..2, Y 2.5..3.5, Z -2.
want_lo, want_hi = [0.0, 2.5, -2.0], [2.0, 3.5, -2.0]
t.check(all(abs(a - b) < 1e-5 for a, b in zip(acc["min"] + acc["max"], want_lo + want_hi)),
        "its corners span %s to %s (want %s to %s)" % (acc["min"], acc["max"], want_lo, want_hi))
# Its front faces where the light shines: +Y in Blender, -Z in glTF.
with open(exp.path, "rb") as f:
    glb = f.read()
n_json = struct.unpack_from("<I", glb, 12)[0]
binary = glb[20 + n_json + 8:]
view = doc["bufferViews"][acc["bufferView"]]
c = struct.unpack_from("<9f", binary, view.get("byteOffset", 0))
e1 = [c[3 + k] - c[k] for k in range(3)]
e2 = [c[6 + k] - c[k] for k in range(3)]
normal = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
          e1[0] * e2[1] - e1[1] * e2[0]]
t.check(normal[2] < 0 and abs(normal[0]) < 1e-6 and abs(normal[1]) < 1e-6,
        "its front faces where the light shines (normal %s, want -Z)" % normal)
t.check(not any("area light" in w for w in exp.warnings),
        "no warning that the portal is dropped: %s" % exp.warnings)
listed = subprocess.run([os.path.join(t.BIN, "ptworker"), "--list", exp.path],
                        stdout=subprocess.PIPE, text=True, check=True).stdout
t.check("environment portals: 2 triangles" in listed, "ptworker --list counts its two triangles")

# Flat and wide over the floor (6 x 4 m, 1 m up): as a surface it would
# shade most of the view.
obj.location = (0.0, 0.0, 1.0)
obj.rotation_euler = (0.0, 0.0, 0.0)
data.size, data.size_y = 6.0, 4.0
bpy.context.view_layer.update()
exp, _ = export()
with_portal = render(exp, "with")
print("note floor mean without the portal %.5f, with it %.5f" % (without, with_portal))
t.check(abs(with_portal / without - 1.0) < 0.02,
        "the portal casts no shadow: mean %.5f against %.5f" % (with_portal, without))

data.shape = "DISK"
exp, _ = export()
t.check(any("round portal" in w for w in exp.warnings), "a round portal is named in a warning")
t.finish()
