"""Shared by the Blender tests (run by tests/blender/run.sh inside
`blender -b --factory-startup`): the arguments run.sh passes, installing
the add-on as a user does (a zip through Preferences > Add-ons > Install),
a small scene built in Python, reading images, running ptworker and
ptexr-diff, and checks that print 'ok ...' or raise.
"""

import math
import os
import subprocess
import sys
import zipfile

import bpy

argv = sys.argv[sys.argv.index("--") + 1:]
SERVER, TOKEN, TMP, BIN, SRC = argv[:5]


def check(cond, what):
    if not cond:
        raise AssertionError(what)
    print("ok", what, flush=True)


def install_addon():
    """Zips client/blender/ptfarm_blender, installs and enables it."""
    pkg = os.path.join(SRC, "client", "blender", "ptfarm_blender")
    zpath = os.path.join(TMP, "ptfarm_blender.zip")
    with zipfile.ZipFile(zpath, "w") as z:
        for name in sorted(os.listdir(pkg)):
            if name.endswith(".py"):
                z.write(os.path.join(pkg, name), "ptfarm_blender/" + name)
    bpy.ops.preferences.addon_install(filepath=zpath, overwrite=True)
    bpy.ops.preferences.addon_enable(module="ptfarm_blender")
    check(hasattr(bpy.types.Scene, "ptfarm"), "the add-on installs and registers its settings")
    check(hasattr(bpy.types, "RENDER_PT_ptfarm"), "its panel is in the Render properties")


def empty_scene(name="farmtest"):
    """A scene with nothing in it and a black world."""
    scene = bpy.context.scene
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    scene.name = name
    world = bpy.data.worlds.new("black")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0, 0, 0, 1)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    scene.world = world
    return scene


def principled(name, rgb, roughness=0.5, specular=0.5):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*rgb, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Specular"].default_value = specular
    return mat


def add_mesh(op, name, mat, **kw):
    op(**kw)
    obj = bpy.context.active_object
    obj.name = name
    obj.data.materials.append(mat)
    return obj


def add_light(kind, name, energy, location, radius=0.0):
    data = bpy.data.lights.new(name, kind)
    data.energy = energy
    if kind in ("POINT", "SPOT"):
        data.shadow_soft_size = radius
    obj = bpy.data.objects.new(name, data)
    obj.location = location
    bpy.context.scene.collection.objects.link(obj)
    return obj


def add_camera(name, location, look_at, lens=35.0):
    import mathutils
    data = bpy.data.cameras.new(name)
    data.lens = lens
    obj = bpy.data.objects.new(name, data)
    obj.location = location
    d = mathutils.Vector(look_at) - mathutils.Vector(location)
    obj.rotation_euler = d.to_track_quat("-Z", "Y").to_euler()
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.scene.camera = obj
    return obj


def plane_sphere_scene(res=(64, 48)):
    """The issue's scene: a plane, a sphere, a point light and a camera."""
    scene = empty_scene()
    add_mesh(bpy.ops.mesh.primitive_plane_add, "Floor", principled("floor", (0.7, 0.7, 0.7)),
             size=6.0)
    add_mesh(bpy.ops.mesh.primitive_uv_sphere_add, "Ball", principled("ball", (0.8, 0.2, 0.1)),
             radius=0.7, location=(0, 0, 0.7), segments=32, ring_count=16)
    bpy.ops.object.shade_smooth()
    add_light("POINT", "Lamp", 300.0, (1.5, -1.0, 3.0))
    add_camera("Cam", (4.0, -4.0, 3.0), (0, 0, 0.5))
    scene.render.resolution_x, scene.render.resolution_y = res
    scene.render.resolution_percentage = 100
    s = scene.ptfarm
    s.server, s.token_file, s.output_dir = SERVER, TOKEN, os.path.join(TMP, "blend_out") + "/"
    s.spp, s.seed = 16, 5
    return scene


def pixels(img):
    """An Image's float RGBA pixels, rows bottom-up, as a list."""
    n = img.size[0] * img.size[1] * 4
    buf = [0.0] * n
    img.pixels.foreach_get(buf)
    return buf


def mean_rgb(img, box=None):
    """Mean R, G, B of an Image, or of the pixels x0 <= x < x1, y0 <= y < y1
    for box (x0, x1, y0, y1)."""
    p = pixels(img)
    w, h = img.size
    x0, x1, y0, y1 = box or (0, w, 0, h)
    acc, n = [0.0, 0.0, 0.0], 0
    for y in range(y0, y1):
        for x in range(x0, x1):
            i = (y * w + x) * 4
            for c in range(3):
                acc[c] += p[i + c]
            n += 1
    return [a / n for a in acc]


def ptworker(scene, args, out, extra=()):
    """ptworker --scene with a job's ptctl submit options (those ptworker
    takes), the queue's tile and chunk."""
    keep, skip = [], {"--priority", "--name", "--frames", "--fps"}
    i = 0
    while i < len(args):
        if args[i] in skip:
            i += 2
            continue
        if args[i] in ("--transparent", "--denoise") or args[i].startswith("--bdpt"):
            keep.append(args[i])
            i += 1
            continue
        keep += args[i:i + 2]
        i += 2
    cmd = [os.path.join(BIN, "ptworker"), "--scene", scene, *keep, "--tile", "16", "--chunk",
           "8", "-q", "-o", out, *extra]
    subprocess.run(cmd, check=True)


def same_exr(a, b):
    """True when ptexr-diff finds the two EXRs bit-identical."""
    p = subprocess.run([os.path.join(BIN, "ptexr-diff"), a, b], stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT, text=True)
    if p.returncode != 0:
        print("note ptexr-diff:", p.stdout.strip()[-300:])
    return p.returncode == 0


def call_operator(op):
    """Runs an operator as the panel's button does; returns (ok, message):
    the error Blender reports, without Python's traceback."""
    try:
        op()
        return True, ""
    except RuntimeError as e:
        return False, str(e)


def finish():
    print("PASS", flush=True)


__all__ = ["math"]
