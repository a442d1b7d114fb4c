"""The add-on in Blender's user interface (run by run.sh under Xvfb, not
-b): the panel in the Render properties, "Render frame on ptfarm" pressed
as the button does, and the job followed without blocking: the operator
returns at once with no image yet, the timer's progress reaches the panel,
and the image is loaded when the job ends (with Denoising Data: a MULTILAYER
Image once the Image Editor shows it); then Blender's own screenshot
operator takes the window (the README's picture: PT_SCREENSHOT_OUT names a
copy to keep). Then "Render animation on ptfarm" the same way: 3 frames
come back as an image sequence (PT_CONTACT_SHEET_OUT keeps them side by
side, through ptcontact-sheet). Driven by a timer, as the event loop runs only once this
script has returned; any failure ends Blender with exit status 1.
"""
import os
import subprocess
import sys
import time
import traceback

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bpy  # noqa: E402
import farmtest as t  # noqa: E402

t.install_addon()
scene = t.plane_sphere_scene(res=(320, 240))
scene.ptfarm.spp = 64
scene.ptfarm.use_pass_denoising_data = True  # the still comes back with layers
scene.render.engine = "CYCLES"
state = {"step": 0, "seen": [], "pressed": 0.0}
SHOT = os.path.join(t.TMP, "panel.png")


def areas(kind):
    win = bpy.context.window_manager.windows[0]
    return win, sorted([a for a in win.screen.areas if a.type == kind], key=lambda a: a.x)


def region(area):
    return [r for r in area.regions if r.type == "WINDOW"][0]


def keep_left(img, width, path):
    """Writes the left width columns of img to path as a PNG (the panel and
    the image; the outliner and object properties on the right are cut)."""
    w, h = img.size
    px = [0.0] * (w * h * 4)
    img.pixels.foreach_get(px)
    out = bpy.data.images.new("shot", width, h, alpha=False)
    rows = []
    for y in range(h):
        rows += px[y * w * 4:(y * w + width) * 4]
    out.pixels.foreach_set(rows)
    out.filepath_raw = path
    out.file_format = "PNG"
    scene.render.image_settings.compression = 100
    out.save()


def step():
    try:
        return advance()
    except Exception:
        traceback.print_exc()
        print("FAIL", flush=True)
        os._exit(1)


def advance():
    n = state["step"]
    state["step"] += 1
    s = scene.ptfarm
    if n == 0:
        # The 3D view becomes the panel (left) and an Image Editor (right).
        win, (v3d,) = areas("VIEW_3D")
        with bpy.context.temp_override(window=win, area=v3d, region=region(v3d)):
            bpy.ops.screen.area_split(direction="VERTICAL", factor=0.42)
        return 0.3
    if n == 1:
        win, (left, right) = areas("VIEW_3D")
        left.type, right.type = "PROPERTIES", "IMAGE_EDITOR"
        return 0.3
    if n == 2:
        win, props = areas("PROPERTIES")
        props[0].spaces.active.context = "RENDER"
        with bpy.context.temp_override(window=win, area=props[0]):
            ok = bpy.ops.ptfarm.render_frame()
        t.check("FINISHED" in ok, "the button starts the job")
        t.check(s.last_image == "" and not s.error,
                "the operator returns before the image is back (status '%s')" % s.status)
        state["pressed"] = time.monotonic()
        return 0.1
    if " done: " not in s.status and not s.status.startswith("failed"):
        state["seen"].append(s.status)
        if time.monotonic() - state["pressed"] > 120:
            raise AssertionError("the job did not end within 120 s: %s" % s.status)
        state["step"] = n  # wait here
        return 0.1
    if n < 100:
        state["seen"].append(s.status)
        t.check(not s.error, "the job succeeds (%s)" % s.status)
        progress = [x for x in state["seen"] if x.startswith("job") and "done" not in x]
        t.check(progress, "the panel showed the job's progress: %s" % sorted(set(progress)))
        img = bpy.data.images.get(s.last_image)
        t.check(img is not None, "the timer loaded the image '%s'" % s.last_image)
        win, (editor,) = areas("IMAGE_EDITOR")
        editor.spaces.active.image = img
        with bpy.context.temp_override(window=win, area=editor, region=region(editor)):
            bpy.ops.image.view_all(fit_view=True)
        win, props = areas("PROPERTIES")
        with bpy.context.temp_override(window=win, area=props[0], region=region(props[0])):
            for _ in range(8):  # the ptfarm panel is the last of the Render tab
                bpy.ops.view2d.scroll_down(deltay=400)
        state["step"] = 100
        return 0.5
    if n == 100:
        img = bpy.data.images.get(s.last_image)
        t.check(img.type == "MULTILAYER",
                "the Image Editor shows it as a MULTILAYER Image (its passes' layers)")
        # Once more, now that the panel has drawn its last rows.
        win, props = areas("PROPERTIES")
        with bpy.context.temp_override(window=win, area=props[0], region=region(props[0])):
            for _ in range(8):
                bpy.ops.view2d.scroll_down(deltay=400)
        return 0.5
    if n == 101:
        bpy.ops.screen.screenshot(filepath=SHOT)
        shot = bpy.data.images.load(SHOT)
        t.check(tuple(shot.size) == (1280, 800), "Blender's screenshot operator took the window")
        if os.environ.get("PT_SCREENSHOT_OUT"):
            keep_left(shot, 1057, os.environ["PT_SCREENSHOT_OUT"])
        # Then the other button: the ball rolls over frames 1 to 3.
        ball = scene.objects["Ball"]
        scene.frame_start, scene.frame_end = 1, 3
        for f, x in ((1, -1.2), (2, 0.0), (3, 1.2)):
            ball.location.x = x
            ball.keyframe_insert("location", frame=f)
        scene.frame_set(1)
        s.spp = 16
        s.use_pass_denoising_data = False
        state["first"] = s.last_job
        win, props = areas("PROPERTIES")
        with bpy.context.temp_override(window=win, area=props[0]):
            ok = bpy.ops.ptfarm.render_animation()
        t.check("FINISHED" in ok and s.last_job == state["first"],
                "Render animation returns before the job is back")
        state["pressed"] = time.monotonic()
        return 0.1
    t.check(not s.error, "the animation job succeeds (%s)" % s.status)
    img = bpy.data.images.get(s.last_image)
    t.check(s.last_job != state["first"] and img is not None and img.source == "SEQUENCE",
            "the timer loaded the frames as an image sequence '%s'" % s.last_image)
    frames = [bpy.path.abspath(img.filepath).replace(".0001.", ".%04d." % f) for f in (1, 2, 3)]
    t.check(all(os.path.isfile(f) for f in frames), "its 3 frames are on disk")
    if os.environ.get("PT_CONTACT_SHEET_OUT"):
        subprocess.run([os.path.join(t.BIN, "ptcontact-sheet"), "-o",
                        os.environ["PT_CONTACT_SHEET_OUT"], "--cols", "3", *frames], check=True)
    t.finish()
    bpy.ops.wm.quit_blender()
    return None


bpy.app.timers.register(step, first_interval=0.5)
