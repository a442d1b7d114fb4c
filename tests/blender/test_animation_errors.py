"""'Render animation on ptfarm' and the failures a user meets.

An animation of 3 frames (the ball and the lamp keyframed, each by an
action of its own, frames 1 to 3) comes back as 3 EXRs loaded as one image
sequence, frame F bit-identical to ptworker --frame F on the exported glTF
(so the order is right), and the three frames differ. Then each failure
gives one readable sentence in Blender, as the operator's error report and
in the panel, not a traceback:
a wrong token, no coordinator, a job the queue refuses, no active camera,
no ptctl, an output folder that cannot be made; a job cancelled ends cancelled on the farm;
and a scene feature the export drops is named in a warning.
"""
import json
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bpy  # noqa: E402
import farmtest as t  # noqa: E402

t.install_addon()
scene = t.plane_sphere_scene(res=(48, 32))
ball = scene.objects["Ball"]
scene.frame_start, scene.frame_end, scene.render.fps = 1, 3, 24
lamp = scene.objects["Lamp"]
for f, x in ((1, -1.5), (2, 0.0), (3, 1.5)):
    ball.location.x = x
    ball.keyframe_insert("location", frame=f)
    lamp.location.y = x  # a second object's action: both must play
    lamp.keyframe_insert("location", frame=f)
scene.frame_set(1)
s = scene.ptfarm
s.spp = 8

ok, msg = t.call_operator(bpy.ops.ptfarm.render_animation)
t.check(ok, "Render animation on ptfarm finishes (%s)" % (msg or s.status))
img = bpy.data.images.get(s.last_image)
t.check(img is not None and img.source == "SEQUENCE",
        "the frames are loaded as an image sequence '%s'" % s.last_image)
base = os.path.join(s.output_dir, scene.name)
job = json.load(open(base + ".job.json"))
t.check(job["frames"] == [1, 2, 3], "the job is the timeline's frames 1-3")
t.check("--frames" in job["args"] and job["args"][job["args"].index("--frames") + 1] == "1-3:1",
        "submitted as --frames 1-3:1")
files = ["%s_job%d.%04d.exr" % (base, s.last_job, f) for f in (1, 2, 3)]
t.check(all(os.path.isfile(f) for f in files), "3 EXRs came back: %s" % [
    os.path.basename(f) for f in files])
t.check(bpy.path.abspath(img.filepath) == files[0], "the sequence starts at frame 1's file")
for f, path in zip((1, 2, 3), files):
    ref = os.path.join(t.TMP, "ref.%d.exr" % f)
    t.ptworker(job["scene"], job["args"], ref, extra=("--frame", str(f), "--fps", "24"))
    t.check(t.same_exr(ref, path), "frame %d is ptworker --frame %d, bit for bit" % (f, f))
t.check(not t.same_exr(files[0], files[2]), "frames 1 and 3 differ (the ball moved)")
# The lamp's move shows too: frame 3 against a render where only the ball moved.
only_ball = os.path.join(t.TMP, "only_ball.exr")
lamp.animation_data_clear()
lamp.location.y = -1.0
bpy.ops.ptfarm.render_animation()
still_lamp = "%s_job%d.%04d.exr" % (base, s.last_job, 3)
t.check(not t.same_exr(still_lamp, files[2]), "the lamp's own action played in the range")
for f, x in ((1, -1.5), (2, 0.0), (3, 1.5)):
    lamp.location.y = x
    lamp.keyframe_insert("location", frame=f)

# Failures: one sentence each, no traceback.
good_token, good_server = s.token_file, s.server


def fails(op, words, what):
    ok, msg = t.call_operator(op)
    shown = s.error
    t.check(not ok and all(w in msg for w in words) and "Traceback" not in msg and
            shown and "Traceback" not in shown,
            "%s: '%s'" % (what, shown))


bad = os.path.join(t.TMP, "wrong.token")
with open(bad, "w") as f:
    f.write("this is not the farm's token at all\n")
os.chmod(bad, 0o600)
s.token_file = bad
fails(bpy.ops.ptfarm.render_frame, ["refused the token"], "a wrong token")
s.token_file = good_token

s.server = "127.0.0.1:1"
fails(bpy.ops.ptfarm.render_frame, ["no coordinator answers at 127.0.0.1:1"], "no coordinator")
s.server = good_server

s.spp = 60000  # over run.sh's ptserve --max-spp 4096
fails(bpy.ops.ptfarm.render_frame, ["4096"], "a job the queue refuses")
s.spp = 8

s.token_file = os.path.join(t.TMP, "no_such.token")
fails(bpy.ops.ptfarm.render_frame, ["token file", "does not exist"], "a missing token file")
s.token_file = good_token

out = s.output_dir
s.output_dir = "/proc/ptfarm/"
fails(bpy.ops.ptfarm.render_frame, ["cannot create the output folder '/proc/ptfarm'"],
      "an output folder that cannot be made")
s.output_dir = out

cam = scene.camera
scene.camera = None
fails(bpy.ops.ptfarm.render_frame, ["no active camera"], "no active camera")
scene.camera = cam

prefs = bpy.context.preferences.addons["ptfarm_blender"].preferences
prefs.ptctl_path = os.path.join(t.TMP, "no", "ptctl")
fails(bpy.ops.ptfarm.render_frame, ["ptctl not found at"], "no ptctl")
prefs.ptctl_path = os.path.join(t.BIN, "ptctl")

# Cancel: the job the Cancel button stops (FarmJob.cancel, from another
# thread here) ends cancelled on the farm, and says so.
from ptfarm_blender import farm  # noqa: E402
job = farm.FarmJob(prefs.ptctl_path, s.server, s.token_file, job["scene"],
                   ["--res", "400x300", "--spp", "4096"], None,
                   lambda f: os.path.join(t.TMP, "never.exr"))
job.start()
while job.snapshot()["job"] is None and not job.snapshot()["done"]:
    time.sleep(0.05)
job.cancel()
while not job.snapshot()["done"]:
    time.sleep(0.05)
snap = job.snapshot()
st = subprocess.run([prefs.ptctl_path, "--server", s.server, "--token-file", s.token_file,
                     "status", str(snap["job"]), "--json"], stdout=subprocess.PIPE, text=True)
t.check(snap["error"] == "job %d cancelled" % snap["job"] and
        json.loads(st.stdout)["state"] == "cancelled" and not snap["fetched"],
        "a cancelled job ends cancelled on the farm: '%s'" % snap["error"])

# Features the export drops are named, and the render still goes.
t.add_light("AREA", "Softbox", 50.0, (0.0, 2.0, 2.0))
velvet = bpy.data.materials.new("velvet")
velvet.use_nodes = True
nodes = velvet.node_tree.nodes
nodes.remove(nodes["Principled BSDF"])
diffuse = nodes.new("ShaderNodeBsdfDiffuse")
velvet.node_tree.links.new(diffuse.outputs["BSDF"], nodes["Material Output"].inputs["Surface"])
scene.objects["Floor"].data.materials[0] = velvet
ok, msg = t.call_operator(bpy.ops.ptfarm.render_frame)
t.check(ok and "light 'Softbox': area lights are not exported" in s.warnings,
        "a dropped area light is named: '%s'" % s.warnings.splitlines()[0])
t.check("material 'velvet': its Diffuse BSDF shader is not exported" in s.warnings,
        "a shader the exporter does not read is named: '%s'" % s.warnings.splitlines()[-1])
t.finish()
