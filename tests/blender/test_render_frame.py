"""'Render frame on ptfarm' end to end: the add-on installed from its zip,
the issue's scene (a plane, a sphere, a point light, a camera) built here,
the button pressed against a real ptserve queue with a local worker; the
image comes back as a Blender Image of the scene's resolution, bit-identical
to ptworker --scene on the exported glTF with the job's options. The
Integrator menu: Automatic (the default) leaves the choice to the
coordinator, Bidirectional submits --bdpt and gets ptworker --bdpt's image,
Path Tracing --bdpt=off and the first image again.
"""
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bpy  # noqa: E402
import farmtest as t  # noqa: E402

t.install_addon()
scene = t.plane_sphere_scene(res=(128, 96))
scene.render.resolution_percentage = 50  # renders 64 x 48, as Blender would
# A job name over ptctl's 64 bytes, in characters of 2 bytes: cut to fit.
scene.ptfarm.job_name = "Kugel über dem Boden, " * 4
ok, msg = t.call_operator(bpy.ops.ptfarm.render_frame)
t.check(ok, "Render frame on ptfarm finishes (%s)" % (msg or scene.ptfarm.status))
s = scene.ptfarm
img = bpy.data.images.get(s.last_image)
t.check(img is not None, "the image is loaded as '%s'" % s.last_image)
t.check(tuple(img.size) == (64, 48),
        "it has the scene's resolution at 50 %% (%s)" % (tuple(img.size),))
exr = bpy.path.abspath(img.filepath)
t.check(os.path.isfile(exr), "its EXR is on disk: %s" % exr)
base = os.path.splitext(os.path.join(s.output_dir, scene.name + ".glb"))[0]
job = json.load(open(base + ".job.json"))
t.check("--camera" in job["args"] and job["args"][job["args"].index("--camera") + 1] == "Cam",
        "the active camera is the job's camera")
name = job["args"][job["args"].index("--name") + 1]
t.check(len(name.encode()) <= 64 and name.startswith("Kugel über"),
        "the job's name is cut to 64 bytes: '%s'" % name)
ref = os.path.join(t.TMP, "ref.exr")
t.ptworker(job["scene"], job["args"], ref)
t.check(t.same_exr(ref, exr), "the farm's image is bit-identical to ptworker --scene")
m = t.mean_rgb(img)
t.check(m[0] > m[2] > 0.0, "the image shows the red ball in the light (mean %s)" % m)
t.check(not any(a.startswith("--bdpt") for a in job["args"]),
        "Automatic, the default, leaves the choice to the coordinator")

# The Integrator menu: Bidirectional submits --bdpt, and the farm's image is
# ptworker --bdpt's, not the first one.
s.integrator = "BDPT"
ok, msg = t.call_operator(bpy.ops.ptfarm.render_frame)
t.check(ok, "Render frame on ptfarm, Bidirectional, finishes (%s)" % (msg or s.status))
job = json.load(open(base + ".job.json"))
t.check("--bdpt" in job["args"], "Bidirectional submits --bdpt: %s" % job["args"])
exr_bd = bpy.path.abspath(bpy.data.images.get(s.last_image).filepath)
ref_bd = os.path.join(t.TMP, "ref_bdpt.exr")
t.ptworker(job["scene"], job["args"], ref_bd)
t.check(t.same_exr(ref_bd, exr_bd), "the Bidirectional image is ptworker --bdpt's, bit for bit")
t.check(not t.same_exr(ref, ref_bd), "and not the path-traced one")
s.integrator = "PATH"
ok, msg = t.call_operator(bpy.ops.ptfarm.render_frame)
t.check(ok, "Render frame on ptfarm, Path Tracing, finishes (%s)" % (msg or s.status))
job = json.load(open(base + ".job.json"))
t.check("--bdpt=off" in job["args"], "Path Tracing submits --bdpt=off: %s" % job["args"])
t.check(t.same_exr(ref, bpy.path.abspath(bpy.data.images.get(s.last_image).filepath)),
        "the Path Tracing image is the first one, bit for bit")
t.finish()
