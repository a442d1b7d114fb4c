"""The world's Environment Texture travels as --env with the strength and
the rotation that make the farm see what Cycles sees. A smooth map written
here (R and G the cosine and sine of the longitude, B the cosine of the
polar angle: every direction has its own colour, and a map turned by any
angle, or mirrored, looks different), behind a Mapping node that turns it
30 degrees about Z, at strength 2, is seen directly by a wide camera with
nothing else in view; the farm's image and Cycles' must agree pixel
by pixel. Each pixel's value is a smooth function of the direction, so
the renderers differ only by their pixel filters and lookups (bilinear in
both): the bound is a small fraction of the map's range, far below the
0.3 that 30 degrees off gives (0.6 for the opposite sign of the turn).
A uniform world colour travels as --background: the farm's pixels are that
colour times the strength.
"""
import json
import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bpy  # noqa: E402
import farmtest as t  # noqa: E402

W, H, TURN, STRENGTH = 128, 64, 30.0, 2.0

t.install_addon()
scene = t.empty_scene("world")
# ptfarm refuses a scene without triangles: a small card behind the camera.
t.add_mesh(bpy.ops.mesh.primitive_plane_add, "Card", t.principled("card", (0.5, 0.5, 0.5)),
           size=0.1, location=(-5.0, -5.0, 0.0))
cam = t.add_camera("Wide", (0.0, 0.0, 0.0), (1.0, 1.0, 0.3), lens=12.0)
scene.render.resolution_x, scene.render.resolution_y = 48, 32
scene.render.resolution_percentage = 100
s = scene.ptfarm
s.server, s.token_file, s.output_dir = t.SERVER, t.TOKEN, os.path.join(t.TMP, "world") + "/"
s.spp, s.seed = 16, 2

# The map: Blender's pixel rows go bottom-up; row y is polar angle
# theta = pi (1 - (y + 0.5) / H) from +Z, column x longitude 2 pi (x + 0.5) / W.
img = bpy.data.images.new("sky", W, H, float_buffer=True)
px = []
for y in range(H):
    theta = math.pi * (1.0 - (y + 0.5) / H)
    for x in range(W):
        phi = 2.0 * math.pi * (x + 0.5) / W
        px += [0.5 + 0.4 * math.cos(phi), 0.5 + 0.4 * math.sin(phi),
               0.5 + 0.4 * math.cos(theta), 1.0]
img.pixels.foreach_set(px)
img.filepath_raw = os.path.join(t.TMP, "sky.hdr")
img.file_format = "HDR"
img.save()
img = bpy.data.images.load(os.path.join(t.TMP, "sky.hdr"), check_existing=False)

nodes, links = scene.world.node_tree.nodes, scene.world.node_tree.links
bg = nodes["Background"]
bg.inputs["Strength"].default_value = STRENGTH
env = nodes.new("ShaderNodeTexEnvironment")
env.image = img
env.interpolation = "Linear"
mapping = nodes.new("ShaderNodeMapping")
mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(TURN))
coord = nodes.new("ShaderNodeTexCoord")
links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
links.new(mapping.outputs["Vector"], env.inputs["Vector"])
links.new(env.outputs["Color"], bg.inputs["Color"])

ok, msg = t.call_operator(bpy.ops.ptfarm.render_frame)
t.check(ok, "the farm renders the world (%s)" % (msg or s.status))
farm = t.pixels(bpy.data.images[s.last_image])

job = json.load(open(os.path.join(s.output_dir, "world.job.json")))
a = job["args"]
t.check(a[a.index("--env-rotate") + 1] == "%.9g" % (-TURN - 90.0) and
        a[a.index("--env-strength") + 1] == "2", "sent as --env-strength 2 --env-rotate %g" % (
            -TURN - 90.0))

scene.render.engine = "CYCLES"
c = scene.cycles
c.device, c.samples, c.use_adaptive_sampling, c.use_denoising = "CPU", 16, False, False
c.pixel_filter_type, c.filter_width = "BOX", 1.0
scene.render.image_settings.file_format = "OPEN_EXR"
scene.render.image_settings.color_depth = "32"
scene.render.filepath = os.path.join(t.TMP, "cycles_world.exr")
bpy.ops.render.render(write_still=True)
cyc = t.pixels(bpy.data.images.load(scene.render.filepath, check_existing=False))

worst = max(abs(farm[i] - cyc[i]) for i in range(len(farm)) if i % 4 != 3)
mean_f = sum(farm[i] for i in range(len(farm)) if i % 4 != 3)
mean_c = sum(cyc[i] for i in range(len(cyc)) if i % 4 != 3)
print("note largest pixel difference %.4f (map range %.1f x strength %g); means %.5f %.5f" % (
    worst, 0.8, STRENGTH, mean_f / len(farm) * 4 / 3, mean_c / len(cyc) * 4 / 3))
t.check(worst < 0.05 * STRENGTH, "farm and Cycles see the same sky, pixel by pixel (largest "
        "difference %.4f)" % worst)

# A uniform colour: --background, every pixel that colour x strength.
links.remove(env.outputs["Color"].links[0])
bg.inputs["Color"].default_value = (0.25, 0.5, 0.125, 1.0)
scene.render.engine = "BLENDER_EEVEE"
ok, msg = t.call_operator(bpy.ops.ptfarm.render_frame)
t.check(ok, "the farm renders a uniform world (%s)" % (msg or s.status))
a = json.load(open(os.path.join(s.output_dir, "world.job.json")))["args"]
t.check(a[a.index("--background") + 1] == "0.5,1,0.25" and "--env" not in a,
        "sent as --background 0.5,1,0.25")
m = t.mean_rgb(bpy.data.images[s.last_image])
t.check(max(abs(m[i] - (0.5, 1.0, 0.25)[i]) for i in range(3)) < 1e-6,
        "the farm sees that colour (%s)" % m)
t.finish()
