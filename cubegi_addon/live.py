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

import numpy as np

from ..cubegi_engine import relight
from ..cubegi_engine.errors import BakeError
from ..cubegi_engine.lights import light_keys
from ..cubegi_engine.scene import same_sky_map
from . import attributes, dynamic, grid_objects, interrupts, light_groups, probe_view, scene_data, session
from .gpu_capture import GpuRenderer

# Light fields whose change needs the light's direct light drawn again (not its colour).
PLACEMENT = ("kind", "position", "direction", "radius", "spot_size", "spot_blend", "polygon", "area", "casts_shadow", "samples",
             "shadow_size")


@dataclass
class Update:
    """What an update did: ``path`` is "none", "weights" (power and colour only), "lights"
    (a light drawn again), "materials"; ``seconds`` by stage."""

    path: str = "none"
    changed: list = field(default_factory=list)
    seconds: dict = field(default_factory=dict)

    def line(self):
        total = sum(self.seconds.values())
        what = ", ".join(self.changed) if self.changed else "nothing changed"
        return f"updated ({self.path}) in {1000 * total:.1f} ms: {what}"


def _same_place(a, b):
    for name in PLACEMENT:
        x, y = getattr(a, name), getattr(b, name)
        if (x is None) != (y is None):
            return False
        if x is not None and not np.array_equal(np.asarray(x), np.asarray(y)):
            return False
    return True


def state_of(context):
    """The kept bake of the context's scene with its SceneLight (made now if needed)."""
    kept = session.kept(context.scene)
    if kept is None:
        raise BakeError("nothing to update: bake first (a file load, Clear, or an undo past the bake drops what a bake keeps)")
    if kept.light is None:
        kept.light = relight.solved_light(kept.result, kept.arrays, kept.settings, lambda: _renderer(kept), bool(kept.moving))
    return kept


def _renderer(kept):
    """The kept bake's renderer for shadow maps, made on first use (GPU batches of the
    static scene, freed with the kept bake)."""
    if kept.renderer is None:
        kept.renderer = GpuRenderer(kept.arrays.points, kept.arrays.triangles, sheet=kept.arrays.sheet_triangles())
    return kept.renderer


def update(context, materials=False, write=True, settle=True, bounce_layers=True, geometry=True):
    """Bring the baked light up to date with the scene's lights, world (and with
    ``materials``, the materials' colours and emission). Returns an :class:`Update`.
    Refuses (BakeError, nothing written) if the static geometry changed since the bake
    (``geometry=False``: not checked; Live checks each edit as it comes instead).

    ``settle=False``: a power or colour edit is applied as a weighted sum alone, with the
    energy balance's factors as they were and the bounce layers left for the next settled
    update (the one-shot bake's numbers come back then). ``bounce_layers=False``: the
    per-bounce layers are not written (an animation's frames cache direct and indirect light
    only)."""
    report = Update()
    kept = session.kept(context.scene)
    if kept is None:
        state_of(context)  # refuses with the reason
    t = time.perf_counter()
    if geometry:
        changes = geometry_changes(context.view_layer, context.evaluated_depsgraph_get(), kept)
        if changes:
            raise BakeError(f"the geometry changed since the bake ({', '.join(changes)}): Bake again (an update keeps "
                            "the capture, which only a bake redraws)")
    lights, sky, pattern, _ = scene_data.scene_lights(context)
    report.seconds["read"] = time.perf_counter() - t
    if not same_sky_map(kept.arrays.sky_map, pattern):
        raise BakeError("the world's environment image changed: Bake again (the probes' tables hold its directions)")
    groups = light_groups.read(context, replace(kept.arrays, lights=lights), [])
    if (groups and groups.names) != (kept.groups and kept.groups.names):
        raise BakeError("the view layer's light groups changed since the bake: Bake again (each group is a layer of its own)")
    if groups != kept.groups:
        kept.groups = groups
        report.changed.append("light groups")
    drawn = False
    if kept.light is not None or materials or not _same_lights(kept.arrays, lights, sky):
        t = time.perf_counter()
        state = state_of(context).light  # made on the first light or material edit (its operator)
        report.seconds["prepare"] = time.perf_counter() - t
        t = time.perf_counter()
        drawn = _update_lights(state, lights, sky, report)
        if materials:
            drawn |= _update_materials(context, kept, report)
        report.seconds["lights"] = time.perf_counter() - t
    moved = _moved_objects(context, kept) if kept.moving else []
    if report.changed or (settle and kept.unsettled) or moved:
        if moved and not (report.changed or kept.unsettled):
            report.path = "dynamic"
            report.changed += [f"{name} moved" for name in moved]
            t = time.perf_counter()
            if write:
                dynamic.write_moving(context, kept)
            report.seconds["dynamic"] = time.perf_counter() - t
            return report
        report.path = "materials" if materials and any(c.startswith("material") for c in report.changed) else (
            "lights" if drawn else "weights" if report.changed else "settle")
        report.changed += [f"{name} moved" for name in moved]
        instant = not settle and report.path == "weights"
        state = state_of(context).light
        if not instant:
            t = time.perf_counter()
            state.solve()
            report.seconds["solve"] = time.perf_counter() - t
        kept.unsettled = instant
        kept.arrays.lights = list(lights)
        kept.arrays.sky = np.asarray(sky, dtype=np.float64)
        if write:
            t = time.perf_counter()
            write_light(context, kept, bounces=bounce_layers and not instant, field=not instant)
            report.seconds["write"] = time.perf_counter() - t
    return report


def geometry_changes(view_layer, depsgraph, kept, only=None):
    """How the static geometry differs from the kept bake's, one phrase per object ("Block
    moved or edited", "Table deleted", "Chair added"); empty if alike. With ``only`` (a set
    of ``session_uid``) only those objects' shapes are compared (and every object's
    membership)."""
    now = scene_data.static_shapes(view_layer, depsgraph, only)
    before = kept.shapes or {}
    changes = [f"{name} deleted or hidden from renders" for uid, (name, _) in before.items() if uid not in now]
    changes += [f"{name} added" for uid, (name, _) in now.items() if uid not in before]
    changes += [f"{name} moved or edited" for uid, (name, digest) in now.items()
                if uid in before and digest is not None and digest != before[uid][1]]
    return changes


def _same_lights(arrays, lights, sky):
    """True if ``lights`` and ``sky`` are what the kept bake was made (or last updated) with."""
    before = arrays.lights
    if len(before) != len(lights) or not np.array_equal(np.asarray(arrays.sky), np.asarray(sky)):
        return False
    return all(a.key == b.key and _same_place(a, b) and np.array_equal(a.colour, b.colour) and a.group == b.group
               for a, b in zip(before, lights))


def _update_lights(state, lights, sky, report):
    """Apply the lights and sky to ``state``; returns whether a light was drawn again."""
    drawn = False
    wanted = dict(zip(light_keys(lights), lights))
    for key in [k for k, s in state.sources.items() if s.light is not None and k not in wanted]:
        report.changed.append(f"{state.sources[key].light.name} removed")
        state.remove(key)
    for key, light in wanted.items():
        src = state.sources.get(key)
        colour = np.asarray(light.colour, dtype=np.float64)
        if src is not None and _same_place(src.light, light):
            if not np.array_equal(src.weight, colour):
                state.set_weight(key, colour)
                report.changed.append(f"{light.name} power or colour")
            elif src.light.group != light.group:
                report.changed.append(f"{light.name} light group")
            src.light = light
            continue
        state.set_light(key, light)
        drawn = True
        report.changed.append(f"{light.name} {'placed' if src is None else 'moved or reshaped'}")
    sky = np.asarray(sky, dtype=np.float64)
    src = state.sources.get(relight.SKY)
    if np.any(sky > 0) and src is None:
        state.set_sky(sky)
        report.changed.append("world colour")
    elif src is not None and not np.array_equal(src.weight, sky):
        state.set_weight(relight.SKY, sky)
        report.changed.append("world colour")
    return drawn


def _update_materials(context, kept, report):
    collected = scene_data.collect(context, only=kept.only)
    arrays = collected.arrays
    if not arrays.fingerprint().same_geometry(kept.arrays.fingerprint()):
        raise BakeError("the geometry changed since the bake: Bake again (an update keeps the capture, which only a bake redraws)")
    state = kept.light
    albedo = np.where(arrays.dark[:, None], 0.0, arrays.albedo) if arrays.dark is not None else arrays.albedo
    if not np.array_equal(albedo, state.op.albedo):
        state.set_albedo(albedo)
        kept.arrays.albedo = arrays.albedo
        report.changed.append("material colours")
    if not np.array_equal(arrays.emission, kept.arrays.emission):
        state.set_emission(arrays.emission)
        kept.arrays.emission = arrays.emission
        report.changed.append("material emission")
    return False


def _moved_objects(context, kept):
    """Names of the dynamic objects whose vertices moved since they were last lit; the
    kept arrays are brought up to date."""
    now = scene_data.moving_objects(context, only=kept.only)
    before = {t.object_name: a for a, t in kept.moving}
    moved = [t.object_name for a, t in now if t.object_name not in before or not (
        np.array_equal(a.points, before[t.object_name].points) and np.array_equal(a.normals, before[t.object_name].normals))]
    moved += [name for name in before if name not in {t.object_name for _, t in now}]
    kept.moving = now
    return moved


def write_light(context, kept, bounces=True, field=True):
    """Write the kept SceneLight's light to the meshes (in place): the direct, indirect,
    total and lit layers, with ``bounces`` the per-bounce ones; with ``field`` the probe
    field, the grid objects' probe light and the dynamic objects lit from it."""
    state, arrays = kept.light, kept.arrays
    direct, indirect = state.direct(), state.indirect()
    layers = {attributes.DIRECT: direct, attributes.INDIRECT: indirect, attributes.TOTAL: direct + indirect}
    for k in range(1, state.count + 1 if bounces else 1):
        layers[attributes.bounce_name(k)] = state.bounce(k)
    if kept.lit:
        layers[attributes.LIT] = arrays.albedo * (indirect if kept.lit == "INDIRECT" else direct + indirect)
    if kept.groups is not None:
        layers.update((attributes.group_name(g), v) for g, v in light_groups.layers(state, kept.groups, direct + indirect).items())
    for target, mesh in zip(kept.targets, session.target_meshes(kept.targets)):
        if mesh is None:
            continue
        for name, values in layers.items():
            attributes.put(mesh, name, attributes.vertex_values(target, values))
        mesh.update()
    if not field:
        return
    kept.result.field.coeffs, kept.result.field.source_coeffs = state.field_coeffs()
    objects = grid_objects.probe_grid_objects(context.scene)
    if objects:
        grid_objects.store_probe_light(objects, kept.result.field.whole())
        probe_view.forget_drawing()
    dynamic.write_moving(context, kept)


# --- Live: updates as the user edits -----------------------------------------------------------

# Seconds after the last edit before the settled update (energy balance, bounce layers).
SETTLE_SECONDS = 0.25
_pending = {"scene": None, "instant": False, "settle": False, "materials": False, "rebake": False}
_status = {"writing": False}


def _kinds(depsgraph, kept):
    """What a depsgraph update touched: a subset of {"light", "materials", "dynamic",
    "geometry"}. Geometry is judged in Object Mode only (an Edit Mode change reaches the
    mesh when Edit Mode ends, which is an update of its own), by the shapes of the objects
    updated and by which objects render (CubeGI's own writes leave both as they were)."""
    import bpy

    kinds, updated = set(), set()
    for u in depsgraph.updates:
        data = u.id
        if isinstance(data, (bpy.types.Light, bpy.types.World)):
            kinds.add("light")
        elif isinstance(data, bpy.types.Object):
            if data.type == "LIGHT":
                kinds.add("light")
            elif data.type == "MESH" and data.original.cubegi.dynamic and (u.is_updated_transform or u.is_updated_geometry):
                kinds.add("dynamic")
            elif u.is_updated_transform or u.is_updated_geometry:
                updated.add(data.original.session_uid)
        elif isinstance(data, (bpy.types.Material, bpy.types.ShaderNodeTree)):
            kinds.add("materials")
    active = depsgraph.view_layer.objects.active
    if (active is None or active.mode == "OBJECT") and geometry_changes(depsgraph.view_layer, depsgraph, kept, updated):
        kinds.add("geometry")
    return kinds


def on_depsgraph_update(scene, depsgraph):
    """With Live on: schedule the cheapest update for what the user changed."""
    if _status["writing"] or not getattr(scene, "cubegi", None) or not scene.cubegi.live:
        return
    kept = session.kept(scene)
    if kept is None:
        return
    kinds = _kinds(depsgraph, kept)
    if not kinds:
        return
    if "geometry" in kinds:  # a static mesh moved: bake again once edits pause, redrawing the probes it concerns
        _pending.update(scene=scene, instant=False, settle=True, rebake=True)
        _schedule(SETTLE_SECONDS)
        return
    _pending.update(scene=scene, instant=_pending["instant"] or "light" in kinds, settle=True)
    _pending["materials"] |= "materials" in kinds
    _schedule(0.0)


def on_undo(*_):
    """After an undo or redo: keep what the restored file still holds the light of
    (:func:`.session.after_undo`); with Live on, bring that light up to date with the
    restored scene (bake again if its geometry is another), or say why Live stopped."""
    import bpy

    still_kept = {scene.session_uid for scene, _ in session.after_undo()}
    scene = bpy.context.scene
    if scene is None or not getattr(scene, "cubegi", None) or not scene.cubegi.live:
        return
    if scene.session_uid not in still_kept:
        stop()
        scene.cubegi.last_update = "Live is waiting: undo or redo went back to light another bake made; Bake again"
        return
    view_layer = bpy.context.view_layer
    rebake = bool(geometry_changes(view_layer, bpy.context.evaluated_depsgraph_get(), session.kept(scene)))
    _pending.update(scene=scene, instant=False, settle=True, materials=True, rebake=rebake)
    _schedule(0.0)


def on_frame_change(scene, depsgraph=None):
    """With Live on, every frame's lights are applied (playback, scrubbing)."""
    if getattr(scene, "cubegi", None) and scene.cubegi.live and session.kept(scene) is not None:
        _pending.update(scene=scene, instant=False, settle=True)
        run_pending()


def _schedule(delay):
    import bpy

    if not bpy.app.timers.is_registered(_tick):
        bpy.app.timers.register(_tick, first_interval=delay)


def _tick():
    return run_pending()


def run_pending():
    """Run what is pending: the instant update now, the settled one once edits pause.
    Returns the seconds until it wants to run again (None: nothing left), as a timer does."""
    import bpy

    scene = _pending["scene"]
    if scene is None or not _pending["settle"]:
        return None
    context = bpy.context
    if context.scene != scene:
        _pending.update(scene=None, instant=False, settle=False, materials=False)
        return None
    _status["writing"] = True
    try:
        if _pending["instant"]:
            _pending["instant"] = False
            scene.cubegi.last_update = update(context, settle=False, geometry=False).line()
            return SETTLE_SECONDS
        materials, rebake = _pending["materials"], _pending["rebake"]
        _pending.update(scene=None, settle=False, materials=False, rebake=False)
        if rebake:
            scene.cubegi.last_update = _rebake(context)
        else:
            scene.cubegi.last_update = update(context, materials=materials, geometry=False).line()
    except BakeError as exc:
        scene.cubegi.last_update = f"not updated: {exc}"
    finally:
        _status["writing"] = False
    return None


def _rebake(context):
    """Static geometry moved: bake again with the kept settings; the kept capture is patched
    (only the probes the moved objects concern are drawn again)."""
    from . import pipeline

    kept = session.kept(context.scene)
    t = time.perf_counter()
    report = pipeline.bake(context, kept.settings, kept.resolution, lit=kept.lit, only=kept.only)
    drawn = report.probes_recaptured if report.probes_recaptured is not None else report.grid["probes"]
    return f"baked again in {1000 * (time.perf_counter() - t):.0f} ms: geometry moved, {drawn} of {report.grid['probes']} probes re-captured"


def stop():
    """Forget what is pending (Live turned off, unregister)."""
    import bpy

    _pending.update(scene=None, instant=False, settle=False, materials=False, rebake=False)
    if bpy.app.timers.is_registered(_tick):
        bpy.app.timers.unregister(_tick)


def on_live_toggle(settings, context):
    if not settings.live:
        stop()


def register():
    import bpy

    bpy.app.handlers.depsgraph_update_post.append(_persistent_update)
    bpy.app.handlers.frame_change_post.append(_persistent_frame)
    bpy.app.handlers.undo_post.append(_persistent_undo)
    bpy.app.handlers.redo_post.append(_persistent_undo)


def unregister():
    import bpy

    stop()
    for handlers, fn in ((bpy.app.handlers.depsgraph_update_post, _persistent_update), (bpy.app.handlers.frame_change_post, _persistent_frame),
                         (bpy.app.handlers.undo_post, _persistent_undo), (bpy.app.handlers.redo_post, _persistent_undo)):
        if fn in handlers:
            handlers.remove(fn)


def _persistent(fn):
    import bpy

    return bpy.app.handlers.persistent(interrupts.blender_callback(fn))


_persistent_update = _persistent(on_depsgraph_update)
_persistent_frame = _persistent(on_frame_change)
_persistent_undo = _persistent(on_undo)
