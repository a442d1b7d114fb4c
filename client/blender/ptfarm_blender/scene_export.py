"""The open Blender scene as a ptfarm job: a .glb from Blender's own glTF
exporter and the ptctl submit options that go with it.

What ptfarm renders is what Blender's exporter writes, so this module picks
the exporter's settings that keep it (cameras, punctual lights, applied
modifiers, renderable objects only, the animation for a range) and adds
on the command line what glTF cannot carry: the active camera, the world
(an Environment Texture becomes --env with its strength and rotation, a
uniform colour --background), film transparency, the bounce cap.

Light units. ptfarm reads a KHR_lights_punctual intensity as a radiometric
value (README, "Light units"): a point or spot light of intensity I gives
irradiance I/d^2, a directional light of intensity E irradiance E. Cycles
gives a point or spot light of power P watts the radiant intensity
P/(4 pi) W/sr (its point light's emission is P/(4 pi) over the light's
projected area) and a sun of strength S the irradiance S W/m^2. The
exporter's "Unitless" lighting mode (COMPAT: convert_lighting_mode in
Blender 3.4 and 3.5, export_import_convert_lighting_mode from 3.6) writes
exactly P/(4 pi) and S, so that mode is used; an exporter without the
option writes lights on its own scale, and the intensities are then
rewritten here from the lights' data (tests/blender/test_light_units.py
checks the match against Cycles).

Threads: Blender's main thread only (bpy).
"""

import json
import math
import os
import struct

import bpy
from mathutils import Vector

from . import passes

# Object types the glTF exporter writes (gather_tree / gather_nodes in
# Blender 3.4's io_scene_gltf2: curves, surfaces and text become meshes).
EXPORTED_TYPES = {"MESH", "CURVE", "SURFACE", "FONT", "EMPTY", "CAMERA", "LIGHT", "ARMATURE"}
# Shader nodes the exporter reads a glTF material from.
EXPORTED_SHADERS = {"BSDF_PRINCIPLED", "EMISSION", "BSDF_TRANSPARENT", "MIX_SHADER",
                    "ADD_SHADER", "GROUP"}


class ExportError(Exception):
    """The scene cannot become a job; str() names what is at fault."""


class Export:
    """The result: path of the .glb, ptctl submit options after the scene,
    the frames of a range (None for a still), the animation's frame rate,
    and warnings (one sentence each) for what the farm will not see."""

    def __init__(self, path, args, frames, fps, warnings, camera):
        self.path = path
        self.args = args
        self.frames = frames
        self.fps = fps
        self.warnings = warnings
        self.camera = camera


def resolution(scene):
    """The render size in pixels, as Blender renders it (percentage applied)."""
    r = scene.render
    w = max(1, int(r.resolution_x * r.resolution_percentage / 100))
    h = max(1, int(r.resolution_y * r.resolution_percentage / 100))
    return w, h


def frame_range(scene):
    """The timeline's frames, in order."""
    return list(range(scene.frame_start, scene.frame_end + 1, max(1, scene.frame_step)))


def _enum_property(names, value):
    """The first of the exporter's properties named in names that offers
    value, or None: options move and get renamed between Blender versions."""
    props = bpy.ops.export_scene.gltf.get_rna_type().properties
    for name in names:
        if name in props.keys() and value in [i.identifier for i in props[name].enum_items]:
            return name
    return None


def _lighting_mode_property():
    # convert_lighting_mode in 3.4 and 3.5, renamed in 3.6.
    return _enum_property(("export_import_convert_lighting_mode", "convert_lighting_mode"),
                          "COMPAT")


def _exporter_properties():
    return set(bpy.ops.export_scene.gltf.get_rna_type().properties.keys())


def _visible(obj, scene):
    return not obj.hide_render and obj.name in scene.objects


def _shader_of(node_tree, socket_name):
    """The node linked to the active output's socket_name, or None."""
    if node_tree is None:
        return None
    outputs = [n for n in node_tree.nodes if n.type in ("OUTPUT_MATERIAL", "OUTPUT_WORLD")]
    active = [n for n in outputs if getattr(n, "is_active_output", False)] or outputs
    if not active:
        return None
    sock = active[0].inputs.get(socket_name)
    if sock is None or not sock.is_linked:
        return None
    return sock.links[0].from_node


def is_portal(light):
    """Whether a Blender light is a Cycles portal (an area light with
    Portal checked), which the farm takes as an environment portal."""
    cycles = getattr(light, "cycles", None)
    return light.type == "AREA" and bool(getattr(cycles, "is_portal", False))


def portal_corners(obj):
    """The four corners of a portal light, glTF world space (+Y up), in
    order round the rectangle: the light's size (and size_y for a rectangle
    or an ellipse) in its local XY plane, placed by its world matrix; wound
    so that the quad's front faces where the light points (its local -Z),
    into the room, as ptfarm takes a portal's front (README)."""
    light = obj.data
    sx = light.size
    sy = light.size_y if light.shape in ("RECTANGLE", "ELLIPSE") else light.size
    out = []
    for x, y in ((-0.5, -0.5), (-0.5, 0.5), (0.5, 0.5), (0.5, -0.5)):
        w = obj.matrix_world @ Vector((x * sx, y * sy, 0.0))
        out.append((w.x, w.z, -w.y))  # Blender's Z up to glTF's Y up
    return out


def check_scene(scene):
    """Warnings, one sentence each, for what Blender renders in this scene
    and the export drops."""
    warn = []
    for obj in scene.objects:
        if not _visible(obj, scene):
            continue
        if obj.type not in EXPORTED_TYPES:
            warn.append("object '%s' (%s) is not exported: glTF has no %s objects" % (
                obj.name, obj.type.lower(), obj.type.lower()))
            continue
        if obj.type == "LIGHT":
            light = obj.data
            if is_portal(light):
                if light.shape in ("DISK", "ELLIPSE"):
                    warn.append("light '%s': a round portal goes to the farm as the rectangle "
                                "around it" % obj.name)
            elif light.type == "AREA":
                warn.append("light '%s': area lights are not exported (KHR_lights_punctual has "
                            "point, spot and sun only)" % obj.name)
            elif light.type in ("POINT", "SPOT") and light.shadow_soft_size > 0:
                warn.append("light '%s': its radius (%.3g m) is dropped: the farm renders a "
                            "point, with sharp shadows" % (obj.name, light.shadow_soft_size))
            elif light.type == "SUN" and light.angle > 0:
                warn.append("light '%s': its angle is dropped: the farm's sun casts sharp "
                            "shadows" % obj.name)
            if light.use_nodes and light.node_tree is not None:
                warn.append("light '%s': its node tree is read only for an Emission strength"
                            % obj.name)
        for ps in getattr(obj, "particle_systems", []):
            if ps.settings.type == "HAIR" and ps.settings.render_type == "PATH":
                warn.append("object '%s': hair particles ('%s') are not exported" % (
                    obj.name, ps.name))
        if obj.type in ("MESH", "CURVE", "SURFACE", "FONT"):
            for slot in obj.material_slots:
                mat = slot.material
                if mat is None or not mat.use_nodes:
                    continue
                surface = _shader_of(mat.node_tree, "Surface")
                if surface is not None and surface.type not in EXPORTED_SHADERS:
                    warn.append("material '%s': its %s shader is not exported (the farm "
                                "renders a default material)" % (mat.name, surface.bl_label))
                if _shader_of(mat.node_tree, "Volume") is not None:
                    warn.append("material '%s': its volume is not exported" % mat.name)
                if _shader_of(mat.node_tree, "Displacement") is not None:
                    warn.append("material '%s': its displacement is not exported" % mat.name)
    cam = scene.camera
    if cam is not None and cam.type == "CAMERA":
        if cam.data.type == "PANO":
            warn.append("camera '%s': panoramic cameras are not exported" % cam.name)
        if cam.data.dof.use_dof:
            warn.append("camera '%s': depth of field is not rendered by the farm" % cam.name)
    if scene.render.use_motion_blur:
        warn.append("motion blur is not sent to the farm")
    if scene.render.use_border:
        warn.append("the render region is not sent: the farm renders the whole frame")
    if scene.render.use_multiview:
        warn.append("stereoscopy is not sent: the farm renders the active camera alone")
    cycles = getattr(scene, "cycles", None)
    if cycles is not None and abs(getattr(cycles, "film_exposure", 1.0) - 1.0) > 1e-6:
        warn.append("Film > Exposure (%g) is not applied: the farm's EXR is the scene's "
                    "radiance" % cycles.film_exposure)
    return sorted(set(warn))


def world_options(scene, folder, warn):
    """ptctl submit options for the world: --env MAP [--env-strength S]
    [--env-rotate DEG] for an Environment Texture, --background R,G,B for a
    uniform colour, none for black. Appends to warn what is dropped."""
    world = scene.world
    if world is None:
        return []
    if not world.use_nodes:
        c = world.color
        return _background(c, 1.0)
    bg = _shader_of(world.node_tree, "Surface")
    if bg is None:
        return []
    if bg.type != "BACKGROUND":
        warn.append("world: its %s shader is not sent (the farm sees a black world)" %
                    bg.bl_label)
        return []
    strength_in = bg.inputs["Strength"]
    if strength_in.is_linked:
        warn.append("world: a linked Strength is not sent (the farm uses 1)")
        strength = 1.0
    else:
        strength = float(strength_in.default_value)
    color_in = bg.inputs["Color"]
    if not color_in.is_linked:
        return _background(color_in.default_value, strength)
    tex = color_in.links[0].from_node
    if tex.type != "TEX_ENVIRONMENT" or tex.image is None:
        warn.append("world: its %s colour is not sent (only an Environment Texture or a "
                    "colour is)" % tex.bl_label)
        return []
    if tex.projection != "EQUIRECTANGULAR":
        warn.append("world: a %s projection is not sent (only equirectangular)" %
                    tex.projection.lower())
        return []
    rotate = _env_rotation(tex, warn)
    path = _env_file(tex.image, folder)
    # 1e-4 degree is far finer than a texel of any map; it keeps -60, not
    # -59.9999992 from a rotation stored in radians as a float.
    return ["--env", path, "--env-strength", "%.9g" % strength, "--env-rotate",
            "%.9g" % round(rotate, 4)]


def _background(c, strength):
    rgb = [max(0.0, float(c[i]) * strength) for i in range(3)]
    if max(rgb) <= 0.0:
        return []
    return ["--background", "%.9g,%.9g,%.9g" % tuple(rgb)]


def _env_rotation(tex, warn):
    """ptfarm's --env-rotate for Blender's equirectangular lookup.

    Blender looks a world direction (X, Y, Z), Z up, up at
    u = atan2(Y, -X) / (2 pi) + 1/2 (Cycles' direction_to_equirectangular);
    ptfarm at u = 1/2 + (atan2(x, -z) - rotate) / (2 pi) in glTF's axes
    (common/render/env.h), where x = X, y = Z, z = -Y. So atan2(x, -z) =
    atan2(Y, -X) - 90 degrees, and a map with no Mapping node is rotated
    -90 degrees. A Mapping node (type Point) with a rotation theta about Z
    turns the sky the other way, as Cycles renders it: rotate = -theta -
    90 degrees (tests/blender/test_world_env.py compares the farm's image
    with Cycles' for theta = 30 degrees, where theta - 90 is 0.6 off).
    """
    theta = 0.0
    vec = tex.inputs["Vector"]
    if vec.is_linked:
        node = vec.links[0].from_node
        ok = node.type == "MAPPING" and node.vector_type == "POINT"
        if ok:
            loc = node.inputs["Location"]
            rot = node.inputs["Rotation"]
            scale = node.inputs["Scale"]
            ok = not (loc.is_linked or rot.is_linked or scale.is_linked)
        if ok:
            r = rot.default_value
            ok = abs(r[0]) < 1e-6 and abs(r[1]) < 1e-6 and \
                all(abs(float(s) - 1.0) < 1e-6 for s in scale.default_value)
            theta = math.degrees(r[2])
        if not ok:
            warn.append("world: only a Mapping node's rotation about Z is sent (the map's "
                        "other mapping is dropped)")
    return -theta - 90.0


def _env_file(image, folder):
    """A path to the map's file: its own file, or a packed one written out."""
    if image.packed_file is not None:
        ext = os.path.splitext(image.filepath)[1] or (
            ".exr" if image.file_format == "OPEN_EXR" else ".hdr")
        path = os.path.join(folder, "world" + ext)
        with open(path, "wb") as f:
            f.write(image.packed_file.data)
        return path
    path = bpy.path.abspath(image.filepath, library=image.library)
    if not os.path.isfile(path):
        raise ExportError("world: the environment map '%s' is not found" % path)
    return os.path.abspath(path)


def _read_glb_json(path):
    with open(path, "rb") as f:
        data = f.read()
    # GLB: 12-byte header, then a JSON chunk (length, type 'JSON', bytes).
    if len(data) < 20 or data[:4] != b"glTF":
        raise ExportError("the exporter wrote no GLB at %s" % path)
    n, kind = struct.unpack_from("<I4s", data, 12)
    if kind != b"JSON" or 20 + n > len(data):
        raise ExportError("the exporter's GLB at %s has no JSON chunk" % path)
    return json.loads(data[20:20 + n].decode("utf-8")), data, n


def convert_lights(doc, scene):
    """Rewrites the file's punctual lights in ptfarm's units from the Blender
    lights' data (for an exporter without the Unitless mode): intensity
    P/(4 pi) for point and spot lights, S for suns; colour as Blender's."""
    lights = doc.get("extensions", {}).get("KHR_lights_punctual", {}).get("lights", [])
    for node in doc.get("nodes", []):
        li = node.get("extensions", {}).get("KHR_lights_punctual", {}).get("light")
        obj = scene.objects.get(node.get("name", ""))
        if li is None or obj is None or obj.type != "LIGHT" or li >= len(lights):
            continue
        light = obj.data
        lights[li]["color"] = [float(c) for c in light.color]
        if light.type == "SUN":
            lights[li]["intensity"] = float(light.energy)
        else:
            lights[li]["intensity"] = float(light.energy) / (4.0 * math.pi)


def add_portals(doc, portals, base):
    """Adds each portal of portals (name, four corners) to the file as a
    node of its own with a two-triangle mesh and extras {"ptfarm_portal":
    true}, which ptfarm reads as an environment portal (README, "Environment
    portals"). base: the length of the binary chunk's data (a
    multiple of 4), where the returned bytes will follow: the positions
    (float32) and indices (uint16) of them all."""
    blob = b""
    if not doc.get("buffers"):
        doc["buffers"] = [{"byteLength": 0}]
    buf = doc["buffers"][0]
    scene = doc["scenes"][doc.get("scene", 0)]
    for name, corners in portals:
        pos = struct.pack("<12f", *[c for p in corners for c in p])
        idx = struct.pack("<6H", 0, 1, 2, 0, 2, 3)
        views = doc.setdefault("bufferViews", [])
        accs = doc.setdefault("accessors", [])
        off = base + len(blob)
        views.append({"buffer": 0, "byteOffset": off, "byteLength": 48})
        views.append({"buffer": 0, "byteOffset": off + 48, "byteLength": 12})
        lo = [min(p[k] for p in corners) for k in range(3)]
        hi = [max(p[k] for p in corners) for k in range(3)]
        accs.append({"bufferView": len(views) - 2, "componentType": 5126, "count": 4,
                     "type": "VEC3", "min": lo, "max": hi})
        accs.append({"bufferView": len(views) - 1, "componentType": 5123, "count": 6,
                     "type": "SCALAR"})
        meshes = doc.setdefault("meshes", [])
        meshes.append({"name": name, "primitives": [
            {"attributes": {"POSITION": len(accs) - 2}, "indices": len(accs) - 1}]})
        nodes = doc.setdefault("nodes", [])
        nodes.append({"name": name, "mesh": len(meshes) - 1, "extras": {"ptfarm_portal": True}})
        scene.setdefault("nodes", []).append(len(nodes) - 1)
        blob += pos + idx
    buf["byteLength"] = base + len(blob)
    return blob


def _glb_binary(data, old_n):
    """The data of a GLB's binary chunk (b"" without one), padded to 4."""
    rest = data[20 + old_n:]
    binary = b""
    if len(rest) >= 8:
        m, kind = struct.unpack_from("<I4s", rest, 0)
        if kind == b"BIN\0":
            binary = rest[8:8 + m]
    return binary + b"\0" * ((4 - len(binary) % 4) % 4)


def _write_glb(path, doc, data, binary):
    """The GLB rewritten with doc as its JSON chunk and binary (no chunk
    when empty) as its binary chunk's data."""
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    text += b" " * ((4 - len(text) % 4) % 4)  # chunks are 4-byte aligned (glTF 2.0, 4.4.3)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text
    if binary:
        chunks += struct.pack("<I4s", len(binary), b"BIN\0") + binary
    with open(path, "wb") as f:
        f.write(data[:4] + struct.pack("<II", 2, 12 + len(chunks)) + chunks)


def fix_up(path, scene, lights):
    """The exported file adjusted for ptfarm: with lights True, the lights'
    units (convert_lights); Cycles portal lights as environment portals
    (add_portals). Materials are kept as exported: a Principled Specular of
    0 comes out as KHR_materials_specular with a black specularColorFactor,
    which ptfarm reads as Cycles does (F0 0, F90 1, the diffuse weighted by
    the coloured Fresnel; tests/blender/test_light_units.py). Rewrites the
    GLB only when something changed."""
    portals = [(obj.name, portal_corners(obj)) for obj in scene.objects
               if obj.type == "LIGHT" and _visible(obj, scene) and is_portal(obj.data)]
    if not lights and not portals:
        return
    doc, data, n = _read_glb_json(path)
    if lights:
        convert_lights(doc, scene)
    binary = _glb_binary(data, n)
    if portals:
        binary += add_portals(doc, portals, len(binary))
    _write_glb(path, doc, data, binary)


def glb_summary(path):
    """(animation count, node names) of an exported file."""
    doc = _read_glb_json(path)[0]
    return len(doc.get("animations", [])), [n.get("name", "") for n in doc.get("nodes", [])]


def _last_line(text):
    """The sentence that ends a Python traceback, not the traceback."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and
             not ln.strip().startswith(("File ", "Location:", "Traceback"))]
    said = lines[-1] if lines else text.strip()
    if "No module named 'numpy'" in said:
        said += " (Debian's Blender needs the package python3-numpy to export glTF)"
    return said


def _job_name(name):
    """At most 64 bytes of UTF-8 (ptctl submit --name's limit), cut between
    characters."""
    return name.encode("utf-8")[:64].decode("utf-8", "ignore")


def export(scene, folder, animation, settings):
    """Exports scene to folder/NAME.glb and returns an Export.

    animation: False for the current frame, True for the timeline's range;
    settings: the add-on's scene settings (spp, seed, priority, max bounces,
    the passes' checkboxes, denoise).
    Raises ExportError for a scene that cannot render on the farm."""
    cam = scene.camera
    if cam is None or cam.type != "CAMERA":
        raise ExportError("the scene has no active camera (set one in the Scene properties)")
    if not _visible(cam, scene):
        raise ExportError("the active camera '%s' is disabled for rendering" % cam.name)
    os.makedirs(folder, exist_ok=True)
    warn = check_scene(scene)
    path = os.path.join(folder, bpy.path.clean_name(scene.name) + ".glb")

    opts = dict(filepath=path, export_format="GLB", export_cameras=True, export_lights=True,
                export_yup=True, export_apply=True, export_animations=bool(animation),
                export_extras=False)
    have = _exporter_properties()
    # Only what Blender renders: the scene's objects not disabled for rendering.
    for name, value in (("use_renderable", True), ("use_active_scene", True),
                        ("export_frame_range", True), ("export_force_sampling", True),
                        ("export_nla_strips", False), ("export_current_frame", False)):
        if name in have:
            opts[name] = value
    # Every action that plays in the scene, as one glTF animation: 3.4's
    # export_nla_strips False above; later exporters' animation mode SCENE.
    anim_mode = _enum_property(("export_animation_mode",), "SCENE")
    if anim_mode:
        opts[anim_mode] = "SCENE"
    mode = _lighting_mode_property()
    if mode:
        opts[mode] = "COMPAT"

    window = bpy.context.window_manager.windows[0] if bpy.context.window_manager.windows \
        else None
    override = {"scene": scene}
    if window is not None:
        override["window"] = window
    frame = scene.frame_current
    try:
        with bpy.context.temp_override(**override):
            result = bpy.ops.export_scene.gltf(**opts)
    except RuntimeError as e:
        raise ExportError("Blender's glTF exporter failed: %s" % _last_line(str(e)))
    finally:
        if scene.frame_current != frame:
            scene.frame_set(frame)
    if "FINISHED" not in result or not os.path.isfile(path):
        raise ExportError("Blender's glTF exporter wrote nothing")
    fix_up(path, scene, lights=not mode)

    nanim, names = glb_summary(path)
    if cam.name not in names:
        raise ExportError("the active camera '%s' is missing from the export" % cam.name)
    w, h = resolution(scene)
    args = ["--res", "%dx%d" % (w, h), "--spp", str(settings.spp), "--seed", str(settings.seed),
            "--priority", str(settings.priority), "--camera", cam.name,
            "--name", _job_name(settings.job_name or scene.name)]
    cycles = getattr(scene, "cycles", None)
    if settings.use_bounce_cap and cycles is not None:
        args += ["--max-depth", str(int(cycles.max_bounces))]
    if scene.render.film_transparent:
        args += ["--transparent"]
    asked = passes.farm_passes(settings)
    if asked:
        args += ["--passes", ",".join(asked)]
    if settings.use_denoise:
        args += ["--denoise"]
    args += {"PATH": ["--bdpt=off"], "BDPT": ["--bdpt"]}.get(settings.integrator, [])
    args += world_options(scene, folder, warn)
    frames = None
    fps = scene.render.fps
    if animation:
        frames = frame_range(scene)
        step = max(1, scene.frame_step)
        # The exporter times frame F at F / render.fps seconds (its keyframes'
        # seconds ignore fps_base), as ptctl's --frames with --fps does.
        args += ["--frames", "%d-%d:%d" % (frames[0], frames[-1], step), "--fps", str(fps)]
        if nanim > 1:
            args += ["--animation", "all"]
        elif nanim == 0:
            warn.append("the scene has no animation: every frame is the same image")
    return Export(path, args, frames, fps, sorted(set(warn)), cam.name)
