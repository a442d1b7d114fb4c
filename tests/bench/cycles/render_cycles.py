# Render a glTF 2.0 scene with Blender Cycles set up as a plain path tracer, to
# compare with ptworker (see compare.sh and docs/bench/cycles.md).
#
#   blender -b --factory-startup --python render_cycles.py -- \
#       SCENE OUT.exr --spp N --res WxH --threads T --seed S
#
# Prints one line "CYCLES_TIME total=SECONDS spp=N" on stdout: the wall time of
# bpy.ops.render.render (scene sync: BVH, images, shaders, plus path tracing).
# The path-tracing time alone (what ptworker's summary times) is read by
# compare.sh from Cycles' own status lines ("Time:" at "Sample 0/N" and at the
# end), which Blender prints on stdout with 10 ms resolution.
# The image is written afterwards as a linear 32-bit float ZIP EXR.
import argparse
import json
import math
import struct
import sys
import time

import bpy
from mathutils import Matrix, Vector


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="render_cycles.py")
    p.add_argument("scene")
    p.add_argument("out")
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--res", default="128x128")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-bounces", type=int, default=16)
    p.add_argument("--keep-principled", action="store_true",
                   help="do not turn glTF pure-Lambert materials into Diffuse BSDFs")
    a = p.parse_args(argv)
    w, h = (int(v) for v in a.res.lower().split("x"))
    a.width, a.height = w, h
    return a


def gltf_json(path):
    """The glTF JSON of a .gltf or .glb (to read what the importer drops)."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:4] == b"glTF":
        n = struct.unpack_from("<I", data, 12)[0]
        return json.loads(data[20:20 + n].decode("utf-8"))
    return json.loads(data.decode("utf-8"))


def pure_lambert_names(doc):
    """Names of glTF materials that ptfarm renders as pure Lambert: metallic 0
    with no metallic-roughness texture and KHR_materials_specular factor 0."""
    out = set()
    for m in doc.get("materials", []):
        pbr = m.get("pbrMetallicRoughness", {})
        spec = m.get("extensions", {}).get("KHR_materials_specular", {})
        if (pbr.get("metallicFactor", 1.0) == 0.0 and "metallicRoughnessTexture" not in pbr
                and spec.get("specularFactor", 1.0) == 0.0):
            out.add(m.get("name", ""))
    return out


def base_name(name):
    # The importer de-duplicates names as NAME.001 ...
    if len(name) > 4 and name[-4] == "." and name[-3:].isdigit():
        return name[:-4]
    return name


def one_sided_emission(mat):
    """glTF emission (and ptfarm's) is one-sided; Cycles emits from both sides.
    Multiply every emission strength by (1 - Backfacing)."""
    nt = mat.node_tree
    geo = None
    for node in list(nt.nodes):
        if node.type == "BSDF_PRINCIPLED":
            sock = node.inputs["Emission Strength"]
        elif node.type == "EMISSION":
            sock = node.inputs["Strength"]
        else:
            continue
        if geo is None:
            geo = nt.nodes.new("ShaderNodeNewGeometry")
        front = nt.nodes.new("ShaderNodeMath")
        front.operation = "SUBTRACT"
        front.inputs[0].default_value = 1.0
        nt.links.new(geo.outputs["Backfacing"], front.inputs[1])
        mul = nt.nodes.new("ShaderNodeMath")
        mul.operation = "MULTIPLY"
        nt.links.new(front.outputs[0], mul.inputs[1])
        if sock.is_linked:
            nt.links.new(sock.links[0].from_socket, mul.inputs[0])
        else:
            mul.inputs[0].default_value = sock.default_value
        nt.links.new(mul.outputs[0], sock)


def to_diffuse(mat):
    """Replace a Principled BSDF by Diffuse BSDF (roughness 0: Lambert) + its
    emission, keeping the base colour and emission inputs as imported."""
    nt = mat.node_tree
    for p in [n for n in nt.nodes if n.type == "BSDF_PRINCIPLED"]:
        outs = [l.to_socket for l in p.outputs["BSDF"].links]
        d = nt.nodes.new("ShaderNodeBsdfDiffuse")
        d.inputs["Roughness"].default_value = 0.0
        bc = p.inputs["Base Color"]
        if bc.is_linked:
            nt.links.new(bc.links[0].from_socket, d.inputs["Color"])
        else:
            d.inputs["Color"].default_value = bc.default_value
        e = nt.nodes.new("ShaderNodeEmission")
        for src, dst in (("Emission", "Color"), ("Emission Strength", "Strength")):
            s = p.inputs[src]
            if s.is_linked:
                nt.links.new(s.links[0].from_socket, e.inputs[dst])
            else:
                e.inputs[dst].default_value = s.default_value
        add = nt.nodes.new("ShaderNodeAddShader")
        nt.links.new(d.outputs[0], add.inputs[0])
        nt.links.new(e.outputs[0], add.inputs[1])
        for t in outs:
            nt.links.new(add.outputs[0], t)
        nt.nodes.remove(p)


def frame_camera(scene, aspect):
    """The view ptfarm takes for a file without a camera (pt_scene_frame_camera
    in common/scene/scene.c), computed in glTF axes and mapped to Blender's."""
    lo = [math.inf] * 3
    hi = [-math.inf] * 3
    for ob in scene.objects:
        if ob.type != "MESH":
            continue
        mw = ob.matrix_world
        for v in ob.data.vertices:
            b = mw @ v.co
            g = (b.x, b.z, -b.y)  # Blender Z-up -> glTF Y-up
            for i in range(3):
                lo[i] = min(lo[i], g[i])
                hi[i] = max(hi[i], g[i])
    centre = [(lo[i] + hi[i]) * 0.5 for i in range(3)]
    radius = 0.5 * math.dist(lo, hi)
    if not radius > 0:
        radius = 1.0
    yfov = math.radians(40.0)
    half = 0.5 * yfov
    if aspect < 1.0:
        half = math.atan(aspect * math.tan(half))
    dist = radius / math.sin(half) * 1.05
    d = Vector((0.0, 0.25, 1.0)).normalized()
    pos = Vector(centre) + d * dist
    fwd = -d
    right = fwd.cross(Vector((0.0, 1.0, 0.0))).normalized()
    up = right.cross(fwd)

    def b(v):  # glTF -> Blender
        return Vector((v.x, -v.z, v.y))

    cam_data = bpy.data.cameras.new("framed")
    cam_data.sensor_fit = "VERTICAL"
    cam_data.angle_y = yfov
    cam_data.clip_start = dist * 1e-4
    cam_data.clip_end = dist * 100.0
    cam = bpy.data.objects.new("framed", cam_data)
    scene.collection.objects.link(cam)
    # A Blender camera looks down its local -Z with +Y up.
    m = Matrix.Identity(4)
    for i, col in enumerate((b(right), b(up), b(-fwd))):
        for r in range(3):
            m[r][i] = col[r]
    m.translation = b(pos)
    cam.matrix_world = m
    return cam


def setup_cycles(scene, a):
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples = a.spp
    c.use_adaptive_sampling = False
    c.use_denoising = False
    if hasattr(c, "use_preview_denoising"):
        c.use_preview_denoising = False
    if hasattr(c, "use_light_tree"):  # Blender >= 3.5
        c.use_light_tree = False
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.light_sampling_threshold = 0.0
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    c.max_bounces = a.max_bounces
    c.diffuse_bounces = a.max_bounces
    c.glossy_bounces = a.max_bounces
    c.transmission_bounces = a.max_bounces
    c.transparent_max_bounces = a.max_bounces
    c.volume_bounces = 0
    c.caustics_reflective = True
    c.caustics_refractive = True
    c.blur_glossy = 0.0  # "Filter Glossy" is a bias; off
    c.seed = a.seed
    c.use_animated_seed = False
    c.film_exposure = 1.0  # a multiplier in Cycles: 1 = unchanged
    if hasattr(c, "time_limit"):
        c.time_limit = 0.0
    scene.render.film_transparent = False
    scene.render.threads_mode = "FIXED"
    scene.render.threads = a.threads
    scene.render.resolution_x = a.width
    scene.render.resolution_y = a.height
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = 1.0
    scene.render.pixel_aspect_y = 1.0
    scene.render.use_border = False
    scene.render.use_persistent_data = False
    scene.render.use_compositing = False
    scene.render.use_sequencer = False
    vs = scene.view_settings
    vs.view_transform = "Standard"
    vs.look = "None"
    vs.exposure = 0.0
    vs.gamma = 1.0
    s = scene.render.image_settings
    s.file_format = "OPEN_EXR"
    s.color_mode = "RGB"
    s.color_depth = "32"
    s.exr_codec = "ZIP"
    # No world light: black, strength 0.
    world = scene.world or bpy.data.worlds.new("black")
    scene.world = world
    world.use_nodes = True
    bg = next((n for n in world.node_tree.nodes if n.type == "BACKGROUND"), None)
    if bg is not None:
        bg.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
        bg.inputs["Strength"].default_value = 0.0
    world.color = (0.0, 0.0, 0.0)


def numpy_compat():
    """Debian 12's Blender 3.4.1 glTF importer uses np.bool, which Debian 12's
    numpy 1.24 removed; give it the builtin it aliased."""
    import numpy
    for name, t in (("bool", bool), ("int", int), ("float", float), ("object", object)):
        if name not in numpy.__dict__:
            setattr(numpy, name, t)


def main():
    a = parse_args()
    numpy_compat()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    bpy.ops.import_scene.gltf(filepath=a.scene)
    scene = bpy.context.scene

    doc = gltf_json(a.scene)
    lambert = set() if a.keep_principled else pure_lambert_names(doc)
    notes = []
    for mat in bpy.data.materials:
        if not mat.use_nodes:
            continue
        if base_name(mat.name) in lambert:
            to_diffuse(mat)
            notes.append("lambert:" + mat.name)
        for n in mat.node_tree.nodes:
            if n.type == "BSDF_PRINCIPLED":
                n.distribution = "GGX"  # single-scattering GGX, like ptfarm
        one_sided_emission(mat)

    # The first camera of the file (glTF order = the importer's creation order
    # is not kept in bpy.data, so use the glTF camera node names), else framed.
    cams = [o for o in scene.objects if o.type == "CAMERA"]
    cam = None
    if cams:
        order = [n.get("name", "") for n in doc.get("nodes", []) if "camera" in n]
        byname = {o.name: o for o in cams}
        for nm in order:
            if nm in byname:
                cam = byname[nm]
                break
        cam = cam or cams[0]
        notes.append("camera:" + cam.name)
    else:
        cam = frame_camera(scene, a.width / a.height)
        notes.append("camera:framed")
    scene.camera = cam
    setup_cycles(scene, a)
    print("CYCLES_SETUP " + " ".join(notes), flush=True)

    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=False)
    t1 = time.perf_counter()
    bpy.data.images["Render Result"].save_render(filepath=a.out, scene=scene)
    print("CYCLES_TIME total=%.4f spp=%d" % (t1 - t0, a.spp), flush=True)


main()
