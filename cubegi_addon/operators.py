"""Operators: bake (``cubegi.bake``), clear (``cubegi.clear``), add a probe grid."""

import json

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, IntVectorProperty, StringProperty
from bpy_extras.io_utils import ExportHelper

from ..cubegi_engine import working
from ..cubegi_engine.errors import BakeError
from ..cubegi_engine.settings import OPTIONS
from . import animation, attributes, display, export, files, grid_objects, live, materials, pipeline, prefs, probe_view, props, session

# Seconds between the modal bake's steps: often enough to feel live, rarely enough that
# Blender's own events get through (the same pace as Blender's extension manager).
MODAL_STEP_SECONDS = 0.05


def _settings_from(op, scene):
    """The settings a bake operator (one with every bake option as a property:
    props.with_bake_options) was called with where the call set them, else the scene's
    (props.bake_settings)."""
    given = {name: getattr(op, name) for name in (*(o.name for o in OPTIONS), "quality") if op.properties.is_property_set(name)}
    return props.bake_settings(scene, given)


class StepJob:
    """A generator of Progress driven a step at a time: by a modal operator's timer, or by
    tests. :meth:`cancel` closes it (the generator undoes what it must, and the threads its
    steps started stop: :class:`~cubegi_engine.working.Driven`)."""

    def __init__(self, steps):
        self.steps = working.Driven(steps)
        self.report_path = None
        self.last = None
        self.report = None

    def step(self):
        """Run one step; True when the bake is done (the report is in ``self.report``)."""
        try:
            self.last = self.steps.next()
        except StopIteration as stop:
            self.report = stop.value
            return True
        return False

    def cancel(self):
        self.steps.close()


class BakeJob(StepJob):
    """One bake, a step at a time. The light so far is on the meshes after every step;
    :meth:`cancel` (or a failure) puts every mesh back as it was."""

    def __init__(self, context, settings, resolution=None, lit="NONE", reference_samples=None, progressive=True, only=None):
        super().__init__(pipeline.bake_steps(
            context, settings, resolution, lit=lit, reference_samples=reference_samples,
            progressive=progressive, only=only,
        ))


class _ModalJob:
    """A job operator: ``execute`` drains the job (background runs, scripts); ``invoke`` steps
    it from a timer with the progress bar and status text, and Esc cancels. Subclasses give
    ``_job(context, progressive)`` and ``_finish(context, job)``."""

    CANCELLED_MESSAGE = "CubeGI: bake cancelled; nothing was changed"

    def execute(self, context):
        try:
            job = self._job(context, progressive=False)
            while not job.step():
                pass
            return self._finish(context, job)
        except BakeError as exc:
            self.report({"ERROR"}, f"CubeGI: {exc}")
            return {"CANCELLED"}

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        self._start(context)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _start(self, context):
        """Start the job, the timer that steps it, the progress bar and status text."""
        self._view = display.view_state()
        self._bake = self._job(context, progressive=True)
        wm = context.window_manager
        wm.progress_begin(0, 100)
        self._timer = wm.event_timer_add(MODAL_STEP_SECONDS, window=context.window)
        context.workspace.status_text_set("CubeGI: starting (Esc to cancel)")

    def modal(self, context, event):
        if event.type == "ESC":
            self.cancel(context)
            self.report({"WARNING"}, self.CANCELLED_MESSAGE)
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            done = self._bake.step()
        except Exception as exc:  # the job has put the meshes back; end the modal state too
            self._end(context)
            display.restore_views(self._view)
            self.report({"ERROR"}, f"CubeGI: {exc}" if isinstance(exc, BakeError) else f"CubeGI: the bake failed: {exc!r}")
            return {"CANCELLED"}
        if done:
            self._end(context)
            try:
                return self._finish(context, self._bake)
            except BakeError as exc:
                self.report({"ERROR"}, f"CubeGI: {exc}")
                return {"CANCELLED"}
        step = self._bake.last
        context.window_manager.progress_update(int(100 * step.done / max(step.total, 1)))
        context.workspace.status_text_set(f"CubeGI [{step.done}/{step.total}]: {step.message} (Esc to cancel)")
        if step.light is not None:
            display.show(context.scene)
        for area in context.screen.areas if context.screen else ():
            if area.type == "VIEW_3D":
                area.tag_redraw()
        return {"RUNNING_MODAL"}

    def cancel(self, context):
        """Esc, or the window manager ending the job (a file load)."""
        self._bake.cancel()
        self._end(context)
        display.restore_views(self._view)

    def _end(self, context):
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        context.workspace.status_text_set(None)


# The operator's limits are soft (the slider's range): a script's out-of-range value is
# refused with the reason by BakeSettings.validate, not silently clamped.


class CUBEGI_OT_bake(_ModalJob, bpy.types.Operator):
    """Bake direct and indirect diffuse light into CubeGI colour attributes on every mesh.
    From the UI it runs in the background of the window: the light appears bounce by bounce,
    Esc cancels and leaves everything as it was"""

    bl_idname = "cubegi.bake"
    bl_description = "Bake direct and indirect diffuse light into CubeGI color attributes on every mesh (Esc cancels)"
    bl_label = "Bake CubeGI"
    # One undo step, and no Adjust Last Operation panel: a tweak there would run the whole bake
    # again, at once (Blender's own bake operators do the same).
    bl_options = {"UNDO"}

    grid: IntVectorProperty(name="Grid", description="Probes along X, Y, Z (default: probe grid objects, or fitted)", size=3, default=(0, 0, 0))
    quality: EnumProperty(
        name="Quality", description="A preset for the grid cells, cube-map size and bounces not given (default: the "
        "scene's settings)", items=props.QUALITY_ITEMS, default="BALANCED",
    )
    reference_samples: IntProperty(
        name="Cycles Reference Samples", description="Also bake a Cycles reference with this many samples (0: none)", default=0, min=0
    )
    lit: EnumProperty(name="Lit Color", description="Also write CubeGI_lit (default: the scene's setting)", items=props.LIT_ITEMS, default="NONE")
    report_path: StringProperty(name="Report", description="Write the bake report (JSON) to this file", default="", subtype="FILE_PATH")
    selected_only: BoolProperty(
        name="Selected Only", description="Bake light into the selected meshes only; the rest light and shadow them and "
        "keep the light they have", default=False, options={"SKIP_SAVE"},
    )

    @classmethod
    def description(cls, context, properties):
        if properties.selected_only:
            return "Bake light into the selected meshes only; every other object lights and shadows them and keeps its light"
        return cls.bl_description

    @classmethod
    def poll(cls, context):
        return _poll(cls, context)

    def _job(self, context, progressive):
        """The bake job, after every check that can be made before it starts."""
        lit = self.lit if self.properties.is_property_set("lit") else context.scene.cubegi.lit
        resolution = tuple(self.grid) if any(self.grid) else None
        report_path = None
        if self.report_path:
            report_path = files.writable_target(bpy.path.abspath(self.report_path), "report", _open_file(bpy.data.filepath))
        only = None
        if self.selected_only:
            only = {ob.session_uid for ob in context.selected_objects if ob.type == "MESH"}
            if not only:
                raise BakeError("select the meshes to bake: Bake Selected bakes the selected meshes only")
        job = BakeJob(context, _settings_from(self, context.scene).validate(), resolution, lit, self.reference_samples or None, progressive,
                      only=only)
        job.report_path = report_path
        return job

    def _finish(self, context, job):
        report = job.report
        if job.report_path:
            text = report.to_json()
            files.write_all([(job.report_path, files.text(text))])
        for warning in report.warnings:
            self.report({"WARNING"}, f"CubeGI: {warning}")
        context.scene.cubegi.last_report = report.to_json(indent=None)
        if animation.detach_cache(context.scene):
            self.report({"INFO"}, "CubeGI: the animation cache is no longer shown (this bake's light replaces it)")
        display.show(context.scene)
        self.report(
            {"INFO"},
            f"CubeGI: baked {len(report.meshes_baked)} meshes, {len(report.bounces)} bounces in "
            f"{report.total_seconds:.2f} s; estimated missing indirect light {100 * report.estimated_remaining_error:.2g}%"
            + (" (added as the tail)" if report.tail.added else ""),
        )
        return {"FINISHED"}


props.with_bake_options(CUBEGI_OT_bake, operator=True)


class CUBEGI_OT_bake_animation(_ModalJob, bpy.types.Operator):
    """Bake every frame of the scene's range: the first in full, the rest by the cheapest
    update (lights, world, materials, dynamic objects), into a cache folder beside the .blend
    file; changing the frame then shows each frame's light. Esc stops: the frames baked so
    far stay in the cache"""

    bl_idname = "cubegi.bake_animation"
    bl_description = "Bake every frame of the scene's range into a cache folder beside the .blend file (Esc stops)"
    bl_label = "Bake Animation"
    bl_options = {"REGISTER"}
    CANCELLED_MESSAGE = "CubeGI: animation bake stopped; the frames baked so far are in the cache"

    @classmethod
    def poll(cls, context):
        return _poll(cls, context, lambda c: None if bpy.data.filepath else "Save the file first: the cache goes beside it")

    def _job(self, context, progressive):
        scene = context.scene
        folder = animation.cache_folder(bpy.data.filepath)
        animation.check_cache_folder(folder, "move it away")
        settings = props.bake_settings(scene, {}).validate()  # the scene's: Bake Animation has no options of its own
        lit = attributes.LitMode.of(scene.cubegi.lit)
        frames = range(scene.frame_start, scene.frame_end + 1)
        self._folder = folder
        return StepJob(animation.bake_animation_steps(context, settings, frames, folder, None, lit))

    def cancel(self, context):
        super().cancel(context)
        context.scene.cubegi.animation_cache = animation.cache_link(self._folder)

    def _finish(self, context, job):
        result = job.report
        context.scene.cubegi.animation_cache = animation.cache_link(result.cache)
        self.report({"INFO"}, f"CubeGI: baked {len(result.frames)} frames in {result.seconds:.2f} s into {result.cache}")
        return {"FINISHED"}


def _open_file(path):
    """The open .blend as a path a report must not overwrite (none for an unsaved file)."""
    return [(path, "open .blend file")] if path else []


def _poll(cls, context, refusal=None):
    """Every operator's poll: a scene, Object Mode, and then ``refusal(context)`` (a reason
    to refuse, or None). The reason becomes the greyed-out button's tooltip."""
    if context.scene is None:
        reason = "No scene"
    elif context.mode != "OBJECT":
        reason = "Switch to Object Mode first"
    else:
        reason = refusal(context) if refusal else None
    if reason:
        cls.poll_message_set(reason)
    return not reason


class CUBEGI_OT_clear(bpy.types.Operator):
    """Remove CubeGI's colour attributes from every mesh in the scene, and the probes' stored light"""

    bl_idname = "cubegi.clear"
    bl_description = "Remove CubeGI's color attributes from every mesh in the scene, and the probes' stored light"
    bl_label = "Clear CubeGI"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return _poll(
            cls, context,
            lambda c: None if display.baked_meshes(c.scene) else "Nothing to clear: no mesh in the scene has CubeGI attributes",
        )

    def execute(self, context):
        removed = 0
        for mesh in display.baked_meshes(context.scene):
            removed += len(attributes.clear(mesh, attributes.is_any))
        for ob in grid_objects.probe_grid_objects(context.scene):
            grid_objects.forget_probe_light(ob)
            probe_view.forget_drawing(ob)
        session.forget(context.scene)
        self.report({"INFO"}, f"CubeGI: removed {removed} attributes")
        return {"FINISHED"}


class CUBEGI_OT_export_gltf(bpy.types.Operator, ExportHelper):
    """Export the scene as glTF binary with the baked light kept above 1 (float vertex attributes)"""

    bl_idname = "cubegi.export_gltf"
    bl_description = "Export the scene as glTF binary with the baked light kept above 1"
    bl_label = "CubeGI Light (.glb)"
    bl_options = {"REGISTER"}
    filename_ext = ".glb"
    filter_glob: StringProperty(default="*.glb", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        return _poll(cls, context, lambda c: None if export.baked_meshes(c.scene) else "Nothing to export: bake first")

    def execute(self, context):
        exposure = []
        try:
            path = files.writable_target(bpy.path.abspath(self.filepath), "export")
            files.write_all([(path, lambda tmp: exposure.append(export.write_glb(context, tmp)))])
        except BakeError as exc:
            self.report({"ERROR"}, f"CubeGI: {exc}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"CubeGI: wrote {path} (COLOR_0 at exposure {exposure[0]:+.2f})")
        return {"FINISHED"}


def menu_export(self, context):
    self.layout.operator(CUBEGI_OT_export_gltf.bl_idname)


class CUBEGI_OT_add_probe_grid(bpy.types.Operator):
    """Add a CubeGI probe grid fitted to the visible geometry. Its box sets the grid's bounds;
    its Resolution sets the probes along each axis"""

    bl_idname = "cubegi.add_probe_grid"
    bl_description = "Add a CubeGI probe grid fitted to the visible geometry"
    bl_label = "CubeGI Probe Grid"
    bl_options = {"REGISTER", "UNDO"}

    resolution: IntVectorProperty(
        name="Resolution", description="Probes along X, Y, Z (default: the preferences' New Grid Resolution)",
        size=3, default=(4, 4, 2), min=1, max=256,
    )

    @classmethod
    def poll(cls, context):
        return _poll(cls, context)

    def execute(self, context):
        if not self.properties.is_property_set("resolution"):
            self.resolution = prefs.get(context).grid_resolution
        bounds = grid_objects.world_bounds([ob for ob in context.visible_objects if ob.type == "MESH"])
        lo, hi = bounds if bounds is not None else ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
        ob = grid_objects.new_probe_grid(context.collection, lo, hi, self.resolution)
        for other in context.selected_objects:
            other.select_set(False)
        ob.select_set(True)
        context.view_layer.objects.active = ob
        return {"FINISHED"}


class CUBEGI_OT_wire_materials(bpy.types.Operator):
    """Show the baked indirect light in EEVEE and Cycles renders: add it to every material of
    the scene's meshes as emission (base colour x CubeGI). Nothing else in the materials changes"""

    bl_idname = "cubegi.wire_materials"
    bl_description = "Show the baked indirect light in EEVEE and Cycles renders, as emission in every material"
    bl_label = "Show in Renders"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        def refusal(c):
            if not display.baked_meshes(c.scene):
                return "Bake first: no mesh has CubeGI's light to show"
            if not any(not materials.is_wired(m) and materials.wirable(m) is None for m in materials.scene_materials(c.scene)):
                return "No material left to wire (all wired, linked, or none assigned)"
            return None

        return _poll(cls, context, refusal)

    def execute(self, context):
        wired, skipped = 0, []
        for material in materials.scene_materials(context.scene):
            problem = materials.wirable(material)
            if problem:
                skipped.append(problem)
            elif materials.wire(material):
                wired += 1
        for problem in skipped:
            self.report({"WARNING"}, f"CubeGI: {problem}; not wired")
        self.report({"INFO"}, f"CubeGI: wired the baked light into {wired} materials")
        return {"FINISHED"}


class CUBEGI_OT_unwire_materials(bpy.types.Operator):
    """Remove the baked light from the materials again (undo Show in Renders)"""

    bl_idname = "cubegi.unwire_materials"
    bl_description = "Remove the baked light from the materials again"
    bl_label = "Remove from Renders"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return _poll(
            cls, context,
            lambda c: None if any(materials.is_wired(m) for m in materials.scene_materials(c.scene))
            else "No material of the scene has CubeGI's light wired in",
        )

    def execute(self, context):
        n = sum(materials.unwire(m) for m in materials.scene_materials(context.scene))
        self.report({"INFO"}, f"CubeGI: removed the baked light from {n} materials")
        return {"FINISHED"}


class CUBEGI_OT_update_light(bpy.types.Operator):
    """Apply edits of lights, the world (and materials) to the baked light on the kept capture:
    no probe is captured again. Geometry edits need Bake"""

    bl_idname = "cubegi.update_light"
    bl_description = "Apply edits of lights, the world and materials to the baked light without a new capture"
    bl_label = "Update Light"
    bl_options = {"REGISTER", "UNDO"}

    materials: BoolProperty(
        name="Materials", description="Also read the materials' colours and emission (reads every mesh)", default=True
    )

    @classmethod
    def poll(cls, context):
        return _poll(
            cls, context,
            lambda c: None if session.kept(c.scene) is not None else "Bake first: nothing is kept to update (a file load drops it)",
        )

    def execute(self, context):
        try:
            report = live.update(context, materials=self.materials)
        except BakeError as exc:
            self.report({"ERROR"}, f"CubeGI: {exc}")
            return {"CANCELLED"}
        context.scene.cubegi.last_update = report.line()
        self.report({"INFO"}, f"CubeGI: {report.line()}")
        return {"FINISHED"}


def menu_add(self, context):
    self.layout.operator(CUBEGI_OT_add_probe_grid.bl_idname, icon="LIGHTPROBE_VOLUME")


class CUBEGI_OT_open_report(bpy.types.Operator):
    """The last bake's whole report, in a text (Text Editor) of its own"""

    bl_idname = "cubegi.open_report"
    bl_label = "Open Report"
    bl_description = "Put the last bake's whole report into the text 'CubeGI Report' and show it in a Text Editor"
    bl_options = {"REGISTER"}

    TEXT = "CubeGI Report"

    @classmethod
    def poll(cls, context):
        return _poll(cls, context, lambda c: None if c.scene.cubegi.last_report else "Bake first: there is no report yet")

    def execute(self, context):
        report = json.loads(context.scene.cubegi.last_report)
        text = bpy.data.texts.get(self.TEXT) or bpy.data.texts.new(self.TEXT)
        text.from_string(json.dumps(report, indent=2) + "\n")
        shown = False
        for area in (context.screen.areas if context.screen else ()):
            if area.type == "TEXT_EDITOR":
                area.spaces.active.text = text
                shown = True
                break
        self.report({"INFO"}, f"CubeGI: the report is in the text {self.TEXT!r}"
                    + ("" if shown else " (open it in a Text Editor)"))
        return {"FINISHED"}


classes = (
    CUBEGI_OT_bake, CUBEGI_OT_clear, CUBEGI_OT_add_probe_grid, CUBEGI_OT_wire_materials, CUBEGI_OT_unwire_materials,
    CUBEGI_OT_update_light, CUBEGI_OT_bake_animation, CUBEGI_OT_export_gltf, CUBEGI_OT_open_report,
)
_register, _unregister = bpy.utils.register_classes_factory(classes)


def register():
    _register()
    bpy.types.VIEW3D_MT_add.append(menu_add)
    bpy.types.TOPBAR_MT_file_export.append(menu_export)


def unregister():
    bpy.types.TOPBAR_MT_file_export.remove(menu_export)
    bpy.types.VIEW3D_MT_add.remove(menu_add)
    _unregister()
