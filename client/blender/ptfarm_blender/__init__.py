"""ptfarm for Blender: render the open scene on a ptfarm render farm.

A panel in Properties > Render holds the coordinator's address, the token
file, samples, seed, priority and the render passes (checkboxes as in
Cycles' View Layer > Passes; passes.py); the resolution and the frame range
are the scene's. "Render frame on ptfarm" and "Render animation on ptfarm"
export the scene with Blender's glTF exporter (scene_export.py), submit it
with ptctl and follow the job in a thread (farm.py); a timer on the main
thread shows the progress in the status bar and loads each image that
comes back: a still as an Image, a range as an image sequence. Without a
user interface (blender -b) the operators wait for the job instead, so a
script gets the images when the operator returns.

Threads: Blender calls everything here on its main thread; only
farm.FarmJob.run works in another.
"""

import json
import os

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, PointerProperty, StringProperty

from . import farm, passes, scene_export

bl_info = {
    "name": "ptfarm",
    "author": "ptfarm",
    "version": (1, 1, 0),
    "blender": (3, 4, 0),
    "location": "Properties > Render > ptfarm",
    "description": "Render the scene on a ptfarm render farm and load the images back",
    "category": "Render",
}

# The job being followed (one at a time) and what it is for.
_active = {"job": None, "scene": None, "export": None, "loaded": set()}


class PtfarmPreferences(bpy.types.AddonPreferences):
    bl_idname = __name__

    ptctl_path: StringProperty(
        name="ptctl", subtype="FILE_PATH", default="",
        description="The ptctl program (empty: ptctl on PATH)")

    def draw(self, context):
        self.layout.prop(self, "ptctl_path")


class PtfarmSettings(bpy.types.PropertyGroup):
    server: StringProperty(name="Coordinator", default="127.0.0.1:7878",
                           description="The ptserve queue's HOST:PORT")
    token_file: StringProperty(name="Token file", subtype="FILE_PATH", default="",
                               description="Your token (mode 0600); empty for a "
                               "coordinator that requires none")
    spp: IntProperty(name="Samples", default=64, min=1, max=65536,
                     description="Samples per pixel")
    integrator: EnumProperty(
        name="Integrator", default="AUTO",
        items=[("AUTO", "Automatic", "Bidirectional where the scene's emissive surfaces light "
                "pockets (a lamp under the ceiling, inside a fitting), else path tracing; "
                "the coordinator decides and logs why (ptctl submit's default)"),
               ("PATH", "Path Tracing", "Unidirectional path tracing with light sampling, "
                "as Cycles (--bdpt=off)"),
               ("BDPT", "Bidirectional", "Each sample also traces a path from the lights and "
                "joins the two (--bdpt): light that reaches the picture indirectly converges "
                "sooner; opaque materials only")],
        description="How each sample finds the light")
    seed: IntProperty(name="Seed", default=0, min=0, description="Same seed, same image")
    priority: IntProperty(name="Priority", default=0,
                          description="Higher runs first; ties in submission order")
    use_denoise: BoolProperty(name="Denoise", default=False,
                              description="The coordinator denoises the finished image "
                              "(NFOR, as ptworker --denoise): the layer denoised (R, G, B) "
                              "beside the untouched beauty (Combined), pick it in the Image "
                              "Editor's pass menu; the Denoising Data passes it reads come "
                              "back too. Needs at least 2 samples")
    use_bounce_cap: BoolProperty(name="Cycles' bounce cap", default=True,
                                 description="Cap paths at Cycles' Max Bounces, as Cycles "
                                 "does (off: the farm's unbiased default)")
    job_name: StringProperty(name="Job name", default="",
                             description="The job's name on the farm (empty: the scene's)")
    output_dir: StringProperty(name="Output", subtype="DIR_PATH", default="//ptfarm/",
                               description="Where the exported scene and the images go "
                               "(// is the .blend's folder; Blender's temporary folder for "
                               "an unsaved file)")
    # What the panel shows of the last job.
    status: StringProperty(name="Status", default="")
    error: StringProperty(name="Error", default="")
    warnings: StringProperty(name="Warnings", default="")
    progress: bpy.props.FloatProperty(name="Progress", default=0.0, min=0.0, max=1.0,
                                      subtype="FACTOR")
    last_job: IntProperty(name="Job", default=0)
    last_image: StringProperty(name="Image", default="")


def _linked_update(prop):
    """An update callback: the checkbox that stands for the same farm pass
    follows this one."""
    other = passes.LINKED[prop]

    def update(self, _context):
        if getattr(self, other) != getattr(self, prop):
            setattr(self, other, getattr(self, prop))
    return update


# One checkbox per pass the panel offers, and no other way to name a pass.
for _prop, _label, _heading, _names, _tip in passes.PASSES:
    PtfarmSettings.__annotations__[_prop] = BoolProperty(
        name=_label, default=False, description=_tip,
        update=_linked_update(_prop) if _prop in passes.LINKED else None)


def _output_folder(scene):
    s = scene.ptfarm
    folder = s.output_dir or "//ptfarm/"
    if folder.startswith("//") and not bpy.data.filepath:
        folder = os.path.join(bpy.app.tempdir or "/tmp", "ptfarm", folder[2:])
    return os.path.abspath(bpy.path.abspath(folder))


def _status_bar(text):
    wm = bpy.context.window_manager
    for window in wm.windows if wm else []:
        if window.workspace is not None:
            window.workspace.status_text_set(text)


def _redraw():
    wm = bpy.context.window_manager
    for window in wm.windows if wm else []:
        for area in window.screen.areas:
            if area.type in ("PROPERTIES", "IMAGE_EDITOR"):
                area.tag_redraw()


def _read(path):
    """An Image of path. Blender reads a file when something first asks for
    its pixels, and only then knows an EXR with layers for a MULTILAYER
    Image. Headless, the file is read now (asking for the size reads it),
    so the script that waited for the job gets the Image as it will stay.
    With a window, reading now would freeze Blender when the job ends
    (1920 x 1080 with Denoising Data: 1.7 s); the Image Editor or the
    compositor reads it when the user first looks at it, as Blender does
    for any image it loads."""
    img = bpy.data.images.load(path, check_existing=False)
    if bpy.app.background:
        img.size[0]
    return img


def _load(scene, job_id, fetched, frames):
    """Loads what came back: a still as one Image, a range as an image
    sequence of its first frame's file (of type MULTILAYER when the EXRs
    have passes' layers). Returns the Image or None."""
    new = [(f, p) for f, p in fetched if p not in _active["loaded"]]
    if not new:
        return None
    _active["loaded"].update(p for _, p in new)
    if frames is None:
        path = new[-1][1]
        img = _read(path)
        img.name = "ptfarm %s job %d" % (scene.name, job_id)
    else:
        name = "ptfarm %s job %d" % (scene.name, job_id)
        img = bpy.data.images.get(name)
        if img is None:
            img = _read(fetched[0][1])
            img.name = name
            img.source = "SEQUENCE"
        else:
            img.reload()
    scene.ptfarm.last_image = img.name
    return img


def _finish(scene, job, exp):
    """Main thread: the job's outcome into the panel and the images."""
    s = job.snapshot()
    settings = scene.ptfarm
    settings.last_job = s["job"] or 0
    settings.progress = s["progress"]
    try:
        img = _load(scene, s["job"] or 0, s["fetched"], exp.frames)
    except (RuntimeError, OSError) as e:  # an EXR Blender cannot read
        img = None
        if not s["error"]:
            s["error"] = "Blender cannot load the image: %s" % str(e).strip()
    if s["done"]:
        settings.error = s["error"] or ""
        if s["error"]:
            settings.status = "failed: " + s["error"]
        else:
            n = len(s["fetched"])
            settings.status = "job %d done: %s" % (s["job"], "%d frames" % n if exp.frames
                                                   else os.path.basename(s["fetched"][-1][1]))
    else:
        settings.status = s["message"]
    return s, img


def _poll_timer():
    """bpy.app.timers callback: the running job's progress, images as they
    come; stops when the job is over."""
    job, scene, exp = _active["job"], _active["scene"], _active["export"]
    if job is None:
        return None
    try:
        scene.name  # the scene may have been deleted meanwhile
    except ReferenceError:
        _active["job"] = None
        return None
    s, _ = _finish(scene, job, exp)
    if s["done"]:
        _status_bar(None)
        _active["job"] = None
        if s["error"]:
            def draw(menu, _context):
                menu.layout.label(text=s["error"])
            bpy.context.window_manager.popup_menu(draw, title="ptfarm", icon="ERROR")
        _redraw()
        return None
    _status_bar("ptfarm: %s" % s["message"])
    _redraw()
    return 0.25


class _RenderOnFarm:
    animation = False

    @classmethod
    def poll(cls, context):
        return context.scene is not None and _active["job"] is None

    def execute(self, context):
        scene = context.scene
        settings = scene.ptfarm
        settings.error = ""
        settings.progress = 0.0
        try:
            ptctl = farm.find_ptctl(context.preferences.addons[__name__].preferences.ptctl_path)
            if settings.token_file:
                token = os.path.abspath(bpy.path.abspath(settings.token_file))
                if not os.path.isfile(token):
                    raise farm.FarmError("the token file '%s' does not exist" % token)
            else:
                token = ""
            if self.animation and scene.frame_start < 0:
                raise scene_export.ExportError("frame %d: the farm numbers frames from 0" %
                                               scene.frame_start)
            folder = _output_folder(scene)
            try:
                os.makedirs(folder, exist_ok=True)
            except OSError as e:
                raise farm.FarmError("cannot create the output folder '%s': %s" % (
                    folder, e.strerror or e))
            exp = scene_export.export(scene, folder, self.animation, settings)
            base = os.path.splitext(exp.path)[0]
            # The exact submit, for whoever wants to reproduce the render.
            with open(base + ".job.json", "w") as f:
                json.dump({"scene": exp.path, "args": exp.args, "frames": exp.frames,
                           "warnings": exp.warnings}, f, indent=1)
        except (farm.FarmError, scene_export.ExportError) as e:
            return self._fail(settings, str(e))
        except OSError as e:
            return self._fail(settings, "cannot write in the output folder: %s" % e)
        settings.warnings = "\n".join(exp.warnings)
        for w in exp.warnings:
            self.report({"WARNING"}, "ptfarm: " + w)

        def out_path(frame):
            job = job_holder.snapshot()["job"]
            if frame is None:
                return "%s_job%d.exr" % (base, job)
            return "%s_job%d.%04d.exr" % (base, job, frame)

        job_holder = farm.FarmJob(ptctl, settings.server, token, exp.path, exp.args, exp.frames,
                                  out_path)
        _active.update(job=job_holder, scene=scene, export=exp, loaded=set())
        if bpy.app.background:
            # No event loop to drive a timer: wait here.
            job_holder.run()
            s, img = _finish(scene, job_holder, exp)
            _active["job"] = None
            if s["error"]:
                return self._fail(settings, s["error"])
            self.report({"INFO"}, "ptfarm: " + settings.status)
            return {"FINISHED"}
        job_holder.start()
        settings.status = "submitting"
        # persistent: a .blend opened meanwhile must not strand the job.
        bpy.app.timers.register(_poll_timer, first_interval=0.1, persistent=True)
        return {"FINISHED"}

    def _fail(self, settings, message):
        settings.error = message
        settings.status = "failed: " + message
        self.report({"ERROR"}, "ptfarm: " + message)
        return {"CANCELLED"}


class PTFARM_OT_render_frame(_RenderOnFarm, bpy.types.Operator):
    """Render the current frame on the ptfarm coordinator and load the image"""
    bl_idname = "ptfarm.render_frame"
    bl_label = "Render frame on ptfarm"
    animation = False


class PTFARM_OT_render_animation(_RenderOnFarm, bpy.types.Operator):
    """Render the timeline's frame range on ptfarm and load it as an image sequence"""
    bl_idname = "ptfarm.render_animation"
    bl_label = "Render animation on ptfarm"
    animation = True


class PTFARM_OT_cancel(bpy.types.Operator):
    """Cancel the job being followed"""
    bl_idname = "ptfarm.cancel"
    bl_label = "Cancel ptfarm job"

    @classmethod
    def poll(cls, context):
        return _active["job"] is not None

    def execute(self, context):
        _active["job"].cancel()
        return {"FINISHED"}


class RENDER_PT_ptfarm(bpy.types.Panel):
    bl_label = "ptfarm"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"

    def draw(self, context):
        scene = context.scene
        s = scene.ptfarm
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        col = layout.column()
        col.prop(s, "server")
        col.prop(s, "token_file")
        col = layout.column()
        col.prop(s, "spp")
        col.prop(s, "integrator")
        col.prop(s, "use_denoise")
        col.prop(s, "seed")
        col.prop(s, "priority")
        col.prop(s, "use_bounce_cap")
        col.prop(s, "job_name")
        col.prop(s, "output_dir")
        # The passes as Cycles' View Layer > Passes shows them: a heading,
        # checkboxes beside it.
        heading = None
        for prop, _label, head, _names, _tip in passes.PASSES:
            if head != heading:
                heading = head
                col = layout.column(heading=head, align=True)
            col.prop(s, prop)
        w, h = scene_export.resolution(scene)
        info = layout.column(align=True)
        info.label(text="Resolution %d x %d (the scene's)" % (w, h))
        info.label(text="Frames %d-%d, step %d, %d fps" % (
            scene.frame_start, scene.frame_end, scene.frame_step, scene.render.fps))
        row = layout.row(align=True)
        row.operator(PTFARM_OT_render_frame.bl_idname, icon="RENDER_STILL")
        row.operator(PTFARM_OT_render_animation.bl_idname, icon="RENDER_ANIMATION")
        if _active["job"] is not None:
            layout.prop(s, "progress", text="Progress")
            layout.operator(PTFARM_OT_cancel.bl_idname, icon="CANCEL")
        if s.status:
            layout.label(text=s.status, icon="ERROR" if s.error else "INFO")
        for w in s.warnings.splitlines():
            layout.label(text=w, icon="ERROR")


classes = (PtfarmPreferences, PtfarmSettings, PTFARM_OT_render_frame,
           PTFARM_OT_render_animation, PTFARM_OT_cancel, RENDER_PT_ptfarm)


def register():
    for c in classes:
        bpy.utils.register_class(c)
    bpy.types.Scene.ptfarm = PointerProperty(type=PtfarmSettings)


def unregister():
    if _active["job"] is not None:
        _active["job"].cancel()
    if bpy.app.timers.is_registered(_poll_timer):
        bpy.app.timers.unregister(_poll_timer)
    del bpy.types.Scene.ptfarm
    for c in reversed(classes):
        bpy.utils.unregister_class(c)
