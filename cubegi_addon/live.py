"""Updates of a baked scene on its kept capture: no probe is drawn again.

| what changed | what runs |
|---|---|
| a light's power or colour, the world's colour | a weighted sum of the kept sources (``settle=False``: that alone, and only the direct, indirect, total and lit layers are written: the instant path of Live editing); then the energy balance of the new mix and every layer |
| a light moved, turned, resized, its cone or shadow setting; a new light | that light's direct light (its shadow map), then one solve of every bounce |
| a light removed | it leaves the sum, then the balance |
| a material's colour or emission (``materials=True``: reads the meshes' materials) | the bounce operator is rebuilt for the new albedo; emitters projected again |
| geometry (a mesh moved or edited, in Edit Mode too, a modifier, an object added or deleted) | :func:`update` refuses and names the objects (Bake again); Live bakes again once edits pause and the scene is in Object Mode, and the bake re-captures only the probes the moved objects concern |
| undo, redo | the kept bake is used while the restored file holds its light (the file's ``bake_id``), else dropped; Live then brings the light up to date with the restored scene |

The engine side is :class:`cubegi_engine.relight.SceneLight`, made from the kept bake on
first use and kept with it (:mod:`.session`). The attributes are written in place (to the
meshes found by their objects' ``session_uid``: renaming changes nothing), the probe light
on the grid objects and the kept probe field follow.
"""

import time
from dataclasses import dataclass, field, replace
from enum import StrEnum

import bpy
import numpy as np

from ..cubegi_engine import relight
from ..cubegi_engine.errors import BakeError
from ..cubegi_engine.records import Route
from . import attributes, dynamic, grid_objects, interrupts, light_groups, probe_view, session, updates
from .gpu_capture import GpuRenderer
from .updates import geometry_changes


@dataclass
class Update:
    """What an update did: its ``route`` (:class:`~cubegi_engine.records.Route`), what
    ``changed`` (one phrase each) and its ``seconds`` by stage."""

    route: Route = Route.NONE
    changed: list = field(default_factory=list)
    seconds: dict = field(default_factory=dict)

    def line(self):
        total = sum(self.seconds.values())
        what = ", ".join(self.changed) if self.changed else "nothing changed"
        return f"updated ({self.route}) in {1000 * total:.1f} ms: {what}"


def _kept(context):
    kept = session.kept(context.scene)
    if kept is None:
        raise BakeError("nothing to update: bake first (a file load, Clear, or an undo past the bake drops what a bake keeps)")
    return kept


def state_of(context):
    """The kept bake of the context's scene with its SceneLight (made now if needed)."""
    kept = _kept(context)
    _scene_light(kept)
    return kept


def _scene_light(kept):
    """The kept bake's SceneLight, per source, made from the bake on first use."""
    bake, live = kept.bake, kept.live
    if live.light is None:
        live.light = relight.solved_light(bake.result, bake.arrays, bake.settings, lambda: _renderer(kept),
                                          live.shadows if live.moving else None)
    return live.light


def _renderer(kept):
    """The kept bake's renderer for shadow maps, made on first use (GPU batches of the
    static scene, freed with the kept bake)."""
    live, arrays = kept.live, kept.bake.arrays
    if live.renderer is None:
        live.renderer = GpuRenderer(arrays.points, arrays.triangles, sheet=arrays.sheet_triangles())
    return live.renderer


def update(context, materials=False, write=True, settle=True, bounce_layers=True, geometry=True, rendered=False):
    """Bring the baked light up to date with the scene's lights, world (and with
    ``materials``, the materials' colours and emission): :func:`.updates.plan`, then applied
    here. Returns an :class:`Update`. Refuses (BakeError, nothing written) what the plan
    refuses (the static geometry changed since the bake; ``geometry=False``: not checked).

    ``settle=False``: a power or colour edit is applied as a weighted sum alone, with the
    energy balance's factors as they were and the bounce layers left for the next settled
    update (the one-shot bake's numbers come back then). ``bounce_layers=False``: the
    per-bounce layers are not written (an animation's frames cache direct and indirect light
    only). ``rendered``: the geometry is also checked as a render evaluates it (an animation's
    frames: a modifier enabled for renders alone)."""
    kept = _kept(context)
    t = time.perf_counter()
    plan = updates.plan(context, kept, materials, geometry, settle, rendered)
    report = Update(plan.route, plan.changed, {"read": time.perf_counter() - t})
    live = kept.live
    if plan.regroup:
        live.groups = plan.groups
    if plan.moving is not None:
        live.moving = plan.moving
    if plan.needs_light or plan.route not in (Route.NONE, Route.DYNAMIC) or live.light is not None:
        t = time.perf_counter()
        state = _scene_light(kept)  # made on the first light or material edit (its operator)
        report.seconds["prepare"] = time.perf_counter() - t
        t = time.perf_counter()
        _apply_lights(state, plan.edits)
        if plan.materials is not None:
            _apply_materials(kept, state, plan.materials)
        report.seconds["lights"] = time.perf_counter() - t
    live.lights, live.sky = list(plan.lights), plan.sky
    if plan.route == Route.NONE:
        return report
    if plan.route == Route.DYNAMIC:
        t = time.perf_counter()
        if write:
            dynamic.write_moving(kept)
        report.seconds["dynamic"] = time.perf_counter() - t
        return report
    state = _scene_light(kept)
    if not plan.instant:
        t = time.perf_counter()
        state.solve()
        report.seconds["solve"] = time.perf_counter() - t
    live.unsettled = plan.instant
    if write:
        t = time.perf_counter()
        write_light(context, kept, bounces=bounce_layers and not plan.instant, field=not plan.instant)
        report.seconds["write"] = time.perf_counter() - t
    return report


def _apply_lights(state, edits):
    """Apply :class:`.updates.LightEdits` to the SceneLight ``state``."""
    for key in edits.removed:
        state.remove(key)
    for key, light in edits.lights.items():
        if key in edits.drawn:
            state.set_light(key, light)
            continue
        if key in edits.weights:
            state.set_weight(key, edits.weights[key])
        state.sources[key].light = light  # its group, name
    if edits.sky is not None:
        if relight.SKY in state.sources:
            state.set_weight(relight.SKY, edits.sky)
        elif np.any(edits.sky > 0):
            state.set_sky(edits.sky)


def _apply_materials(kept, state, edits):
    live = kept.live
    if edits.albedo is not None:
        state.set_albedo(edits.sent)
        live.albedo, live.sent = edits.albedo, edits.sent
    if edits.emission is not None:
        state.set_emission(edits.emission)
        live.emission = edits.emission


def write_light(context, kept, bounces=True, field=True):
    """Write the kept SceneLight's light to the meshes (in place): the direct, indirect,
    total and lit layers, with ``bounces`` the per-bounce ones; with ``field`` the probe
    field, the grid objects' probe light and the dynamic objects lit from it."""
    bake, live = kept.bake, kept.live
    state = live.light
    direct, indirect = state.direct(), state.indirect()
    per_bounce = [state.bounce(k) for k in range(1, state.count + 1)] if bounces else []
    layers = attributes.light_layers(direct, indirect, per_bounce, live.albedo, bake.lit)
    if live.groups is not None:
        layers.update((attributes.group_name(g), v) for g, v in light_groups.layers(state, live.groups, direct + indirect).items())
    attributes.write_targets(bake.targets, session.target_meshes(bake.targets), layers)
    if not field:
        return
    coeffs, source_coeffs = state.field_coeffs()
    live.field = replace(bake.result.field, coeffs=coeffs, source_coeffs=source_coeffs)
    objects = grid_objects.probe_grid_objects(context.scene)
    if objects:
        grid_objects.store_probe_light(objects, live.field.whole())
        probe_view.forget_drawing()
    dynamic.write_moving(kept)


# --- Live: updates as the user edits -----------------------------------------------------------

# Seconds after the last edit before the settled update (energy balance, bounce layers).
SETTLE_SECONDS = 0.25


class Edit(StrEnum):
    """What a depsgraph update touched."""

    LIGHT = "light"
    MATERIALS = "materials"
    DYNAMIC = "dynamic"
    GEOMETRY = "geometry"


@dataclass
class LiveScheduler:
    """Live's pending work: the ``scene`` it is for (None: nothing pending), an ``instant``
    update to run now, a ``settle``d one once edits pause, with the ``materials`` read, or a
    ``rebake`` (static geometry moved); ``writing``: an update is writing (its own depsgraph
    updates are no edit)."""

    scene: object = None
    instant: bool = False
    settle: bool = False
    materials: bool = False
    rebake: bool = False
    writing: bool = False

    def clear(self):
        self.scene, self.instant, self.settle, self.materials, self.rebake = None, False, False, False, False


pending = LiveScheduler()


def _kinds(depsgraph, kept):
    """What a depsgraph update touched: a set of :class:`Edit`. Geometry is judged in Object
    Mode only (an Edit Mode change reaches the mesh when Edit Mode ends, which is an update
    of its own), by the shapes of the objects updated and by which objects render (CubeGI's
    own writes leave both as they were)."""
    kinds, updated = set(), set()
    for u in depsgraph.updates:
        data = u.id
        if isinstance(data, (bpy.types.Light, bpy.types.World)):
            kinds.add(Edit.LIGHT)
        elif isinstance(data, bpy.types.Object):
            if data.type == "LIGHT":
                kinds.add(Edit.LIGHT)
            elif data.type == "MESH" and data.original.cubegi.dynamic and (u.is_updated_transform or u.is_updated_geometry):
                kinds.add(Edit.DYNAMIC)
            elif u.is_updated_transform or u.is_updated_geometry:
                updated.add(data.original.session_uid)
        elif isinstance(data, (bpy.types.Material, bpy.types.ShaderNodeTree)):
            kinds.add(Edit.MATERIALS)
    active = depsgraph.view_layer.objects.active
    if (active is None or active.mode == "OBJECT") and geometry_changes(depsgraph.view_layer, depsgraph, kept, updated):
        kinds.add(Edit.GEOMETRY)
    return kinds


def on_depsgraph_update(scene, depsgraph):
    """With Live on: schedule the cheapest update for what the user changed."""
    if pending.writing or not getattr(scene, "cubegi", None) or not scene.cubegi.live:
        return
    kept = session.kept(scene)
    if kept is None:
        return
    kinds = _kinds(depsgraph, kept)
    if not kinds:
        return
    pending.scene, pending.settle = scene, True
    if Edit.GEOMETRY in kinds:  # a static mesh moved: bake again once edits pause, redrawing the probes it concerns
        pending.instant, pending.rebake = False, True
        _schedule(SETTLE_SECONDS)
        return
    pending.instant |= Edit.LIGHT in kinds
    pending.materials |= Edit.MATERIALS in kinds
    _schedule(0.0)


def on_undo(*_):
    """After an undo or redo: keep what the restored file still holds the light of
    (:func:`.session.after_undo`); with Live on, bring that light up to date with the
    restored scene (bake again if its geometry is another), or say why Live stopped."""
    still_kept = {scene.session_uid for scene, _ in session.after_undo()}
    scene = bpy.context.scene
    if scene is None or not getattr(scene, "cubegi", None) or not scene.cubegi.live:
        return
    if scene.session_uid not in still_kept:
        stop()
        scene.cubegi.last_update = "Live is waiting: undo or redo went back to light another bake made; Bake again"
        return
    rebake = bool(geometry_changes(bpy.context.view_layer, bpy.context.evaluated_depsgraph_get(), session.kept(scene)))
    pending.scene, pending.instant, pending.settle, pending.materials, pending.rebake = scene, False, True, True, rebake
    _schedule(0.0)


def live_frame(scene):
    """With Live on, every frame's lights are applied (playback, scrubbing): True if Live
    took the frame (the one frame handler, :func:`.animation.on_frame_change`, asks)."""
    if not (getattr(scene, "cubegi", None) and scene.cubegi.live and session.kept(scene) is not None):
        return False
    pending.scene, pending.instant, pending.settle = scene, False, True
    run_pending()
    return True


def _schedule(delay):
    if not bpy.app.timers.is_registered(_tick):
        bpy.app.timers.register(_tick, first_interval=delay)


def _tick():
    return run_pending()


def run_pending():
    """Run what is pending: the instant update now, the settled one once edits pause.
    Returns the seconds until it wants to run again (None: nothing left), as a timer does."""
    scene = pending.scene
    if scene is None or not pending.settle:
        return None
    context = bpy.context
    if context.scene != scene:
        pending.clear()
        return None
    pending.writing = True
    try:
        if pending.instant:
            pending.instant = False
            scene.cubegi.last_update = update(context, settle=False, geometry=False).line()
            return SETTLE_SECONDS
        materials, rebake = pending.materials, pending.rebake
        pending.clear()
        if rebake:
            scene.cubegi.last_update = _rebake(context, "geometry moved")
        else:
            try:
                scene.cubegi.last_update = update(context, materials=materials, geometry=False).line()
            except updates.TablesChanged:
                scene.cubegi.last_update = _rebake(context, "a surface across a covered gap started or stopped emitting")
    except BakeError as exc:
        scene.cubegi.last_update = f"not updated: {exc}"
    finally:
        pending.writing = False
    return None


def _rebake(context, why):
    """Bake again with the kept settings, for ``why``: static geometry moved (the kept
    capture is patched: only the probes the moved objects concern are drawn again), or
    the tables changed (the cube maps are kept)."""
    from . import pipeline

    bake = session.kept(context.scene).bake
    t = time.perf_counter()
    report = pipeline.bake(context, bake.settings, bake.resolution, lit=bake.lit, only=bake.only)
    drawn = report.probes_recaptured if report.probes_recaptured is not None else report.grid.probes
    return f"baked again in {1000 * (time.perf_counter() - t):.0f} ms: {why}, {drawn} of {report.grid.probes} probes re-captured"


def stop():
    """Forget what is pending (Live turned off, unregister)."""
    pending.clear()
    if bpy.app.timers.is_registered(_tick):
        bpy.app.timers.unregister(_tick)


def on_live_toggle(settings, context):
    if not settings.live:
        stop()


def register():
    bpy.app.handlers.depsgraph_update_post.append(_persistent_update)
    bpy.app.handlers.undo_post.append(_persistent_undo)
    bpy.app.handlers.redo_post.append(_persistent_undo)


def unregister():
    stop()
    for handlers, fn in ((bpy.app.handlers.depsgraph_update_post, _persistent_update), (bpy.app.handlers.undo_post, _persistent_undo),
                         (bpy.app.handlers.redo_post, _persistent_undo)):
        if fn in handlers:
            handlers.remove(fn)


def _persistent(fn):
    return bpy.app.handlers.persistent(interrupts.blender_callback(fn))


_persistent_update = _persistent(on_depsgraph_update)
_persistent_undo = _persistent(on_undo)
