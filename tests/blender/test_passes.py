"""Render passes and denoising through the add-on: the panel's checkboxes
(Cycles' View Layer > Passes) become `--passes`, its Denoise `--denoise`,
and a frame rendered with them comes back as a MULTILAYER Image whose
passes (as the compositor's Image node lists them) are the farm's layers,
the denoised one too, from which Blender's Cryptomatte node mattes the
ball out by its name, the EXR bit-identical, every layer, to ptworker
--scene on the exported glTF with the same --passes and --denoise. An unknown
pass cannot be asked for: the checkboxes are the only way to name one, and
each of them alone gives a list the farm's parser accepts (which refuses
an unknown name).
"""
import json
import os
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bpy  # noqa: E402
import farmtest as t  # noqa: E402

t.install_addon()
from ptfarm_blender import passes  # noqa: E402

scene = t.plane_sphere_scene(res=(48, 32))
s = scene.ptfarm
s.spp = 8

# The settings have a checkbox per row of the table and no other property
# about passes (nothing a name could be typed into).
rna = type(s).bl_rna.properties
about = sorted(p.identifier for p in rna if "pass" in p.identifier)
t.check(about == sorted(row[0] for row in passes.PASSES)
        and all(rna[p].type == "BOOLEAN" for p in about),
        "the passes are checkboxes only: %s" % about)
t.check(all(rna[row[0]].description == row[4] and len(row[4]) > 40 for row in passes.PASSES),
        "each checkbox's tooltip says what its layers are")


def parser_accepts(names):
    """ptworker's --passes parser on names (a 4x4 render of a tiny scene)."""
    p = subprocess.run([os.path.join(t.BIN, "ptworker"), "--scene",
                        os.path.join(t.SRC, "scenes", "cornell_box.gltf"), "--res", "4x4",
                        "--spp", "1", "--passes", ",".join(names), "-q", "-o",
                        os.path.join(t.TMP, "parse.exr")],
                       stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    return p.returncode == 0


t.check(not parser_accepts(["albedo", "diffuse_color"]), "the farm refuses an unknown pass")
for row in passes.PASSES:
    for other in passes.PASSES:
        setattr(s, other[0], False)
    setattr(s, row[0], True)
    asked = passes.farm_passes(s)
    t.check(asked and parser_accepts(asked), "%s alone asks for %s, which the farm accepts" % (
        row[1], ",".join(asked)))
s.use_pass_cryptomatte_material = False
t.check(not s.use_pass_cryptomatte_object, "Cryptomatte Object and Material tick together")

# A frame with Denoising Data, Emission and Cryptomatte.
s.use_pass_denoising_data = True
s.use_pass_emission = True
s.use_pass_cryptomatte_object = True
t.check(s.use_pass_cryptomatte_material, "ticking Object ticks Material")
s.use_denoise = True
s.spp = 1
ok, msg = t.call_operator(bpy.ops.ptfarm.render_frame)
t.check(not ok and "--denoise needs 2 samples" in s.error and "--help" not in s.error,
        "Denoise with 1 sample says why it is refused: '%s'" % s.error)
s.spp = 8
ok, msg = t.call_operator(bpy.ops.ptfarm.render_frame)
t.check(ok, "Render frame on ptfarm with passes finishes (%s)" % (msg or s.status))
base = os.path.join(s.output_dir, scene.name)
job = json.load(open(base + ".job.json"))
args = job["args"]
t.check("--passes" in args and args[args.index("--passes") + 1] ==
        "albedo,normal,depth,emission,halves,cryptomatte",
        "submitted with --passes albedo,normal,depth,emission,halves,cryptomatte")
t.check("--denoise" in args, "and with --denoise")
img = bpy.data.images.get(s.last_image)
exr = bpy.path.abspath(img.filepath)
t.check(img.type == "MULTILAYER", "the image is loaded as a MULTILAYER Image '%s'" % img.name)
scene.use_nodes = True
node = scene.node_tree.nodes.new("CompositorNodeImage")
node.image = img
seen = [o.name for o in node.outputs]
want = ["Combined", "denoised", "albedo", "N", "depth", "emission", "halfA", "halfB",
        "CryptoObject00", "CryptoObject03", "CryptoMaterial00", "CryptoMaterial03"]
t.check(all(w in seen for w in want), "Blender sees the passes' layers: %s" % seen)
# Blender's own Cryptomatte node reads the layers and the manifest in the
# header: the ball's matte covers part of the frame, not all of it.
tree = scene.node_tree
crypto = tree.nodes.new("CompositorNodeCryptomatteV2")
crypto.source, crypto.image = "IMAGE", img
crypto.layer_name = "CryptoObject"
crypto.matte_id = "Ball"
tree.links.new(node.outputs["Combined"], crypto.inputs["Image"])
tree.links.new(crypto.outputs["Matte"], tree.nodes["Composite"].inputs["Image"])
scene.render.engine = "BLENDER_WORKBENCH"  # the compositor's input is the EXR, not a render
scene.render.image_settings.file_format = "OPEN_EXR"
scene.render.filepath = os.path.join(t.TMP, "matte.exr")
bpy.ops.render.render(write_still=True)
matte = t.pixels(bpy.data.images.load(scene.render.filepath))[0::4]
t.check(0 < sum(matte) < 0.5 * len(matte) and max(matte) == 1.0,
        "Blender's Cryptomatte node mattes the ball out (%.1f of %d pixels)" % (
            sum(matte), len(matte)))
ref = os.path.join(t.TMP, "ref_passes.exr")
t.ptworker(job["scene"], args, ref)
t.check(t.same_exr(ref, exr),
        "every layer is bit-identical to ptworker --scene --passes --denoise")
t.finish()
