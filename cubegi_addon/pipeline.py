"""The bake as Blender sees it: collect -> bake -> write, and a report.

Thin glue: :mod:`.scene_data` turns the scene into arrays, :mod:`.grid_objects` gives the
probe grid, :mod:`.gpu_capture` draws, the engine computes, :mod:`.attributes` writes. The
bake's parts are kept for the next one (:mod:`.session`). Nothing is written to a mesh until
every value is computed; if writing fails midway, every mesh gets its previous CubeGI
attributes back.
"""

import time
import uuid
from dataclasses import replace

import bpy
import numpy as np

from ..cubegi_engine import emitters, metrics, relight
from ..cubegi_engine.bake import bake_steps as engine_bake_steps
from ..cubegi_engine.bake import run, start_simplifying
from ..cubegi_engine.errors import BakeError
from ..cubegi_engine.records import LeftOut, LeftOutKind, Progress, Stage, plural
from ..cubegi_engine.report import BakeReport, CaptureGeometryReport, GridReport, NearFieldReport, ReferenceReport
from ..cubegi_engine.settings import BakeSettings
from ..cubegi_engine.solve import area_weighted_mean
from ..cubegi_engine.working import in_background
from . import attributes, dynamic, grid_objects, light_groups, probe_view, reference, scene_data, session
from .gpu_capture import GpuRenderer

# An object seen from behind over more than this share of what the probes see of it is noted.
SEEN_FROM_BEHIND_NOTE = 0.1


class Preview:
    """The light so far, written to the meshes after every step of a progressive bake.

    It writes ``CubeGI_direct``, then after bounce k ``CubeGI_bounce_k``, ``CubeGI`` and
    ``CubeGI_total`` as they stand. :meth:`undo` puts every mesh back as it was before the
    first write (attributes, ownership list, active colour attributes).
    """

    def __init__(self):
        self.meshes, self.targets, self.saved = [], [], []
        self.direct = None

    def start(self, targets):
        self.targets = targets
        self.meshes = session.target_meshes(targets)
        self.saved = [attributes.snapshot(m) for m in self.meshes]

    def update(self, step):
        """Write a step's light (a generator: the vertex values are made in a thread)."""
        if step.stage == Stage.DIRECT:
            self.direct = step.new_light
            layers = {attributes.DIRECT: step.light, attributes.TOTAL: step.light}
        else:
            layers = {attributes.TOTAL: step.light, attributes.INDIRECT: step.light - self.direct}
            if step.bounce is not None:
                layers[attributes.bounce_name(step.bounce)] = step.new_light
        per_target = yield from in_background(
            lambda: [{name: attributes.vertex_values(target, values) for name, values in layers.items()} for target in self.targets],
            replace(step, light=None, new_light=None, working=True))
        for mesh, values in zip(self.meshes, per_target):
            for name, v in values.items():
                attributes.put(mesh, name, v)
            mesh.update()

    def undo(self):
        for mesh, snap in zip(self.meshes, self.saved):
            try:
                attributes.restore(mesh, snap)
                mesh.update()
            except ReferenceError:  # the mesh is gone (a new file loaded before the bake was closed): nothing to restore
                continue
        self.meshes = []


def _previewed(steps, preview):
    """Pass ``steps`` through, showing each new light with ``preview`` first."""
    while True:
        try:
            step = next(steps)
        except StopIteration as stop:
            return stop.value
        if step.light is not None:
            yield from preview.update(step)
        yield step


def bake(context, settings=None, resolution=None, lit=None, reference_samples=None, progress=None, only=None):
    """Bake the context's scene in one go; returns the :class:`BakeReport`."""
    return run(bake_steps(context, settings, resolution, lit, reference_samples, only=only), progress)


def bake_steps(context, settings=None, resolution=None, lit=None, reference_samples=None, progressive=False, only=None):
    """Bake the context's scene. A generator of engine Progress; returns the BakeReport.

    ``only``: the ``session_uid`` of the objects to write light into (Bake Selected, ``--only``);
    every other object lights and shadows them as before and keeps the light it has.

    ``lit``: a :class:`~.attributes.LitMode` or its name (None: none): ``CubeGI_lit`` = albedo
    x all light, or x the indirect light. With ``reference_samples``, Cycles also bakes the same light into
    ``CubeGI_ref_direct`` and ``CubeGI_ref_indirect`` and the report gives CubeGI's error
    against it. With ``progressive``, the light so far is written to the meshes after every
    step (see :class:`Preview`); closing the generator early (a cancel) or a failure puts
    every mesh back as it was.
    """
    settings = (settings or BakeSettings()).validate()
    lit = attributes.LitMode.of(lit)
    preview = Preview() if progressive else None
    try:
        return (yield from _bake_steps(context, settings, resolution, lit, reference_samples, preview, only))
    except BaseException:
        if preview is not None:
            preview.undo()
        raise


def _checked_grid(context, collected, settings, resolution, lit, reference_samples, only):
    """What a bake of ``collected`` needs before the capture, checked: ``(light groups,
    grid, where the grid comes from)``. Refuses (BakeError) a bake with no mesh to write,
    or one whose attribute names clash with the user's."""
    arrays = collected.arrays
    if not collected.targets and not collected.moving:
        if only is not None:
            names = sorted(ob.name for ob in bpy.data.objects if ob.session_uid in only)
            raise BakeError(f"none of the objects to bake ({', '.join(names) or 'none selected'}) is a mesh that renders "
                            "and receives light")
        raise BakeError("no mesh in the scene can receive baked light")
    groups = light_groups.read(context, arrays, collected.notes)
    attributes.check_clashes(
        [(bpy.data.objects[t.object_name], bpy.data.meshes[t.mesh_name]) for t in collected.targets],
        attributes.bake_names(settings.bounces, lit, reference_samples, groups.names if groups else ()),
    )
    attributes.check_clashes(
        [(bpy.data.objects[t.object_name], bpy.data.meshes[t.mesh_name]) for _, t in collected.moving],
        attributes.bake_names(0, lit),  # dynamic objects get no bounce layers
    )
    grid, grid_source, outside = grid_objects.resolve_grid(context.scene, arrays, resolution, settings.cells,
                                                           settings.probe_spacing, collected.notes)
    if outside > 0:
        collected.notes.append(
            f"{100 * outside:.1f}% of the shading points lie outside every probe grid; they get the light of the nearest grid's nearest probes"
        )
    return groups, grid, grid_source


def _on_gpu(arrays, settings, earlier, total):
    """The scene to the GPU (steps): ``(renderer, simplifying, seconds)``. A new capture's
    simplified scene (``earlier``: none kept) depends on nothing the GPU holds: it is made
    in a thread meanwhile (:func:`~cubegi_engine.bake.start_simplifying`)."""
    simplifying = start_simplifying(arrays, settings) if earlier is None else None
    t = time.perf_counter()
    renderer = yield from GpuRenderer.steps(arrays.points, arrays.triangles, Progress(Stage.CAPTURE, 0, total, "the scene to the GPU",
                                                                                     working=True), sheet=arrays.sheet_triangles())
    t_setup = time.perf_counter() - t
    yield Progress(Stage.CAPTURE, 0, total, "the scene is on the GPU", working=True)
    return renderer, simplifying, t_setup


def _bake_steps(context, settings, resolution, lit, reference_samples, preview, only):
    t0 = time.perf_counter()
    total = 3 + settings.bounces
    collected = yield from scene_data.collect_steps(context, Progress(Stage.CAPTURE, 0, total, "reading the scene", working=True),
                                                    only=only)
    groups, grid, grid_source = _checked_grid(context, collected, settings, resolution, lit, reference_samples, only)
    coarse = _coarse_objects(collected.arrays, grid)  # as modelled, before their light's sampling
    collected = yield from in_background(scene_data.sampled, Progress(Stage.CAPTURE, 0, total, "sampling the surfaces", working=True),
                                         collected, grid)
    arrays = collected.arrays
    t_collect = time.perf_counter() - t0
    yield Progress(Stage.CAPTURE, 0, total, f"read {len(collected.targets)} meshes", working=True)  # Blender's turn

    earlier = session.kept(context.scene)
    renderer, simplifying, t_setup = yield from _on_gpu(arrays, settings, earlier, total)
    steps = engine_bake_steps(arrays, grid, renderer, settings, capture=earlier.bake.result.capture if earlier else None,
                              keep_shadows=bool(collected.moving), whole_field=bool(collected.moving), simplifying=simplifying)
    if preview is not None:
        preview.start(collected.targets)
        steps = _previewed(steps, preview)
    result = yield from steps

    t = time.perf_counter()
    def vertex_layers():  # numpy alone: in a thread
        _note_capture(collected, result, grid, coarse)
        return [_layers(target, result, arrays, lit) for target in collected.targets]

    layers_per_target = yield from in_background(vertex_layers, Progress(Stage.TAIL, total, total, "the light of each mesh's vertices",
                                                                         working=True))
    yield Progress(Stage.TAIL, total, total, "the light of every mesh is ready", working=True)
    state = None
    shadows = dict(result.shadows)  # the live state's copy: later edits redraw into it, never into the bake's
    if groups is not None:  # each group's light: the bake's, per source (kept for updates too)
        state = relight.solved_light(result, arrays, settings, lambda: renderer, shadows if collected.moving else None)
        per_group = light_groups.layers(state, groups, result.direct + result.indirect)
        for target, layers in zip(collected.targets, layers_per_target):
            layers.update((attributes.group_name(g), attributes.vertex_values(target, v)) for g, v in per_group.items())
    t_layers = time.perf_counter() - t
    cubegi_seconds = time.perf_counter() - t0  # before the write, for the reference report

    reference_report = None
    if reference_samples:
        steps_total = 3 + settings.bounces
        yield Progress(Stage.REFERENCE, steps_total, steps_total + 1, f"Cycles reference at {reference_samples} samples")
        ref_layers, ref_seconds = reference.reference_layers(context, collected.targets, reference_samples)
        reference_report = _reference_report(collected.targets, arrays, layers_per_target, ref_layers, reference_samples, ref_seconds,
                                             cubegi_seconds)
        for layers, ref in zip(layers_per_target, ref_layers):
            layers.update(ref)

    t = time.perf_counter()
    moving = [(target, dynamic.moving_layers(obj, target, result.field, arrays.lights, result.shadows, settings, lit))
              for obj, target in collected.moving]
    if moving:
        names = ", ".join(t.object_name for t, _ in moving)
        collected.notes.append(f"dynamic objects lit from the probe field (not captured, cast no light on the rest): {names}")
    write_all(collected.targets + [t for t, _ in moving], layers_per_target + [layers for _, layers in moving])
    objects = grid_objects.probe_grid_objects(context.scene)
    if objects:
        grid_objects.store_probe_light(objects, result.field.whole())
        probe_view.forget_drawing()
    context.scene.cubegi.bake_id = uuid.uuid4().hex
    snapshot = session.BakeSnapshot(
        arrays, collected.targets, result, settings, lit, placements=session.placements(arrays.object_names),
        shapes=scene_data.static_shapes(context.view_layer, context.evaluated_depsgraph_get()),
        bake_id=context.scene.cubegi.bake_id, resolution=resolution, only=None if only is None else frozenset(only))
    session.keep(context.scene, session.Kept(snapshot, session.LiveState.of(
        snapshot, collected.moving, groups, light=state, renderer=renderer if state is not None else None, shadows=shadows)))
    t_write = t_layers + time.perf_counter() - t

    timings = dict(result.timings)
    # CubeGI's own time: everything but the Cycles reference.
    total = time.perf_counter() - t0 - (reference_report.seconds if reference_report else 0.0)
    timings.update(collect=t_collect, gpu_setup=t_setup, write=t_write, total=total)
    names = list(layers_per_target[0] if layers_per_target else moving[0][1])
    return _report(settings, lit, grid, grid_source, collected, result, timings, reference_report, names)


# Points no probe lights are noted above this share (of the points that are not set aside).
NO_PROBE_NOTE = 0.01


def _coarse_objects(arrays, grid):
    """The objects whose median triangle edge is longer than the grid's smallest cell."""
    if arrays.point_object is None or not len(arrays.triangles):
        return []
    tri = arrays.triangles
    p = arrays.points
    edge = np.linalg.norm(p[tri[:, 1]] - p[tri[:, 0]], axis=1)
    owner = arrays.point_object[tri[:, 0]]
    cell = float(np.min(grid.point_cell_edge(p[:1])))
    return [arrays.object_names[k] for k in np.unique(owner) if np.median(edge[owner == k]) > cell]


# Emitters close to a surface named one by one, up to this many.
TRAPPED_NOTES = 3
# A baked object that no probe sees over more than this share of its area is noted.
UNSEEN_NOTE = 0.9


def _note_unseen(collected, transport, baked):
    """Note the baked objects that no probe lights over most of their surface (the tables'
    ``covered`` points): each stands under or inside other surfaces, or in a room whose
    normals point outwards (every probe around it sees back faces, and is left out as
    inside geometry), and only its near field's rays light it indirectly (a vase in a room
    made from the default cube: none, where Cycles lights back faces as it lights fronts).
    An object the probes see from behind has its own note (see _note_capture)."""
    arrays, covered = collected.arrays, transport.covered
    if arrays.point_object is None or not covered.any():
        return
    seen = ~covered if arrays.dark is None else ~covered | arrays.dark
    areas = arrays.point_areas()
    count = len(arrays.object_names)
    total = np.bincount(arrays.point_object, areas, minlength=count)
    unseen = np.bincount(arrays.point_object, areas * ~seen, minlength=count) / np.maximum(total, 1e-300)
    if transport.seen_from_behind is not None:
        unseen[transport.seen_from_behind > SEEN_FROM_BEHIND_NOTE] = 0.0
    for k in np.flatnonzero((unseen > UNSEEN_NOTE) & (total > 0)):
        if arrays.object_names[k] in baked:
            collected.notes.append(
                f"{arrays.object_names[k]}: no probe sees {100 * unseen[k]:.0f}% of it (other surfaces cover it, or it is or stands "
                "in a closed mesh whose normals point outwards, a room made from a cube: every probe around it sees back faces and "
                "is left out), so only its near field's rays light it indirectly, and back faces send them nothing; for a room, "
                "recalculate its normals to face inwards (Mesh > Normals > Recalculate Inside)")


def _note_capture(collected, result, grid, coarse=()):
    no_probe = result.capture.transport.no_probe
    if collected.arrays.dark is not None:
        no_probe = no_probe & ~collected.arrays.dark
    if no_probe.mean() > NO_PROBE_NOTE:
        owners = collected.arrays.point_object[no_probe]
        names = [collected.arrays.object_names[k] for k in np.unique(owners)][:5]
        collected.notes.append(
            f"{100 * no_probe.mean():.1f}% of the shading points get no probe light (the probes of their grid around "
            f"them all lie in a finer grid's box), on {', '.join(names)}; add a probe grid over them if they should "
            "get indirect light"
        )
    names = collected.arrays.object_names
    _note_unseen(collected, result.capture.transport, {t.object_name for t in collected.targets})
    traps = emitters.trapped_light(collected.arrays, result.capture.transport.near)
    unbalanced = emitters.gap_closed(traps)  # the scene's energy balance is left out (emitters.balanced_landing)
    for trap in traps[:TRAPPED_NOTES]:
        collected.notes.append(
            f"{names[trap.emitter]}: an emitter {100 * trap.gap:.2g} cm from {names[trap.surface]} ({trap.points} points of "
            f"{names[trap.surface]} see it over up to {100 * trap.view:.0f}% of their view), a gap finer than the probes "
            "resolve: the light bouncing between them is gathered by the near field alone, from both surfaces sampled "
            "finely there, " + (
                "and the bake leaves out the energy balance (it cannot weigh light sent and received within such a "
                "gap), so the rest of the scene's indirect light can be off by up to a tenth either way" if unbalanced
                else "and the light leaking out of it is only estimated by the energy balance") +
            " (see docs/accuracy.md, a lamp close to a surface)"
        )
    if len(traps) > TRAPPED_NOTES:
        collected.notes.append(f"and {len(traps) - TRAPPED_NOTES} more emitters as close to a surface (the same holds there)")
    if coarse:
        collected.notes.append(
            f"{', '.join(coarse[:5])}{' and more' if len(coarse) > 5 else ''}: edges longer than a probe cell; the bake "
            "samples their light across them, but a vertex colour holds it only at their corners, far apart (a cube's 8 "
            "vertices sit where it meets its neighbours): subdivide them for light that changes across them"
        )
    if not result.probe_valid.any():
        collected.notes.append(
            f"all {result.capture.grid.count} probes captured see back faces over more than a quarter of their view (inside geometry, or "
            "normals pointing away from them); each point uses its plain trilinear weights"
        )
    if result.seen_from_behind is not None:
        for name, share in zip(collected.arrays.object_names, result.seen_from_behind):
            if share > SEEN_FROM_BEHIND_NOTE:
                collected.notes.append(
                    f"{name}: {100 * share:.0f}% of what the probes see of it are back faces (flipped normals, or a "
                    "one-sided surface seen from behind); back faces get and pass on no light. Recalculate its normals "
                    "(Mesh > Normals > Recalculate Outside) or give thin walls thickness"
                )


def _layers(target, result, arrays, lit):
    """One target's attribute layers: name -> ``(v, 3)``."""
    layers = attributes.light_layers(result.direct, result.indirect, result.bounces, arrays.albedo, lit)
    return {name: attributes.vertex_values(target, values) for name, values in layers.items()}


def _report(settings, lit, grid, grid_source, collected, result, timings, reference_report, names):
    arrays, solution = collected.arrays, result.solution
    areas = arrays.point_areas()
    for rec in solution.records:
        rec.attribute = attributes.bounce_name(rec.bounce)
    return BakeReport(
        settings=settings.as_dict(lit=str(lit)),
        grid=GridReport.from_dict({**grid_objects.grid_report(grid), "probes_inside_geometry": int((~result.probe_valid).sum()),
                                   "probes_captured": int(result.capture.grid.count), "source": grid_source,
                                   **_placement(result.placement)}),
        points=len(arrays.points), triangles=len(arrays.triangles), lights=len(arrays.lights), sky=arrays.sky.tolist(),
        meshes_baked=[t.object_name for t in collected.targets], notes=collected.notes,
        direct_seconds=timings["direct"], direct_mean_light=area_weighted_mean(result.direct, areas).tolist(),
        emitter_energy_factor=np.asarray(result.direct_parts.emitter_energy_factor).tolist(),
        bounces=solution.records, indirect_mean_light=area_weighted_mean(result.indirect, areas).tolist(),
        tail=solution.tail_report, timings=timings, attributes=names,
        warnings=[w for w in (solution.tail_report.warning,) if w], reference=reference_report,
        capture_reused=result.capture_reused, probes_recaptured=result.probes_recaptured,
        left_out=list(result.direct_parts.left_out) + _left_out_of_capture(result.capture, grid, result.placement),
        capture_geometry=_capture_geometry(result.capture.proxy), near_field=_near_field(result.capture.transport.own_near),
    )


def _near_field(near):
    if near is None:
        return None
    return NearFieldReport(near.count, len(near.hit_row), near.pairs, near.crowded, near.reach, near.seconds, near.skipped)


def _capture_geometry(proxy):
    if proxy is None:
        return None
    return CaptureGeometryReport(len(proxy.triangles), proxy.source_triangles, proxy.count, proxy.max_offset())


def _placement(placement):
    if placement is None:
        return {}
    return {"probes_moved": placement.moved, "probes_left_inside": placement.left_out}


def _object_names(capture, objects):
    """The names of the captured scene's ``objects`` (indices in its fingerprint's order)."""
    names = [name for name, _ in capture.fingerprint.objects]
    return tuple(names[k] for k in objects if k < len(names))


def _first_names(names, shown=5):
    """``"A, B, C, D, E and 3 more"``."""
    more = f" and {len(names) - shown} more" if len(names) > shown else ""
    return ", ".join(names[:shown]) + more


def _left_out_of_capture(capture, grid, placement=None):
    """What the capture left out: probes, the near field of vertices, geometry (LeftOut)."""
    out = []
    captured = capture.grid.count
    inside = placement.left_out if placement is not None else 0
    crowded = placement.crowded if placement is not None else 0
    unused = grid.count - captured - inside
    if unused > 0:
        out.append(LeftOut(LeftOutKind.PROBES, (
            f"{unused} of {grid.count} light no vertex (none lies within a cell of them) and were "
            f"not captured ({100 * unused / grid.count:.0f}% of the capture saved; a scene with a dynamic object "
            "captures them all)"), unused))
    if inside:
        out.append(LeftOut(LeftOutKind.PROBES, (
            f"{inside} {plural(inside, 'sits', 'sit')} inside geometry with no way out within "
            f"{plural(inside, 'its cell', 'their cells')} and {plural(inside, 'was', 'were')} not captured"
            + (f" ({crowded} of them among finely cut geometry, where probes are left out, not moved)" if crowded else "")), inside))
    near = capture.transport.near
    if near is not None and near.skipped:
        out.append(LeftOut(LeftOutKind.NEAR_FIELD, f"every vertex ({near.skipped}); the probes light their surroundings as "
                                                   "seen from a cell away", len(capture.transport.index)))
    elif near is not None and near.crowded:
        where = _object_names(capture, near.crowded_objects)
        out.append(LeftOut(LeftOutKind.NEAR_FIELD, (
            f"{near.crowded:,} vertices in dense geometry (hundreds of triangles within {near.reach:.3g}"
            f"{': ' + _first_names(where) if where else ''}); the probes light their surroundings"), near.crowded, where))
    if capture.small_objects:
        small = _object_names(capture, capture.small_objects)
        n = len(capture.small_objects)
        out.append(LeftOut(LeftOutKind.CAPTURE_GEOMETRY, (
            f"{n} {plural(n, 'object', 'objects')} smaller than a texel from every probe ({_first_names(small)}) "
            f"{plural(n, 'was', 'were')} not drawn by the probes; {plural(n, 'it', 'they')} still "
            f"{plural(n, 'receives', 'receive')} light and {plural(n, 'casts', 'cast')} shadows"), n, small))
    proxy = capture.proxy
    if proxy is not None:
        saved = 1.0 - len(proxy.triangles) / max(proxy.source_triangles, 1)
        out.append(LeftOut(LeftOutKind.CAPTURE_GEOMETRY, (
            f"the probes drew {len(proxy.triangles):,} of {proxy.source_triangles:,} triangles "
            f"({100 * saved:.0f}% fewer; surfaces within {proxy.max_offset():.3g} of where they are, radiance averaged "
            f"over clusters that size); direct light and shadows use every triangle"), proxy.source_triangles - len(proxy.triangles)))
    return out


def _reference_report(targets, arrays, ours, theirs, samples, ref_seconds, cubegi_seconds):
    scored = scene_data.scored_areas(targets, arrays)  # black vertices left out: Cycles gives them no light
    areas = np.concatenate([scored[t.object_name] for t in targets])

    def stack(layers, name):
        return np.concatenate([layer[name] for layer in layers])

    light = {"direct": stack(ours, attributes.DIRECT), "indirect": stack(ours, attributes.INDIRECT)}
    reference = {"direct": stack(theirs, attributes.REF_DIRECT), "indirect": stack(theirs, attributes.REF_INDIRECT)}
    errors = metrics.compare(light["direct"], light["indirect"], reference["direct"], reference["indirect"], areas)
    furthest = metrics.furthest_off([t.object_name for t in targets], [len(scored[t.object_name]) for t in targets], light, reference, areas)
    return ReferenceReport(int(samples), ref_seconds, cubegi_seconds, [attributes.REF_DIRECT, attributes.REF_INDIRECT], errors,
                           objects=furthest)


def write_all(targets, layers_per_target):
    """Write every target's layers, or none: a failure restores what was there."""
    meshes = [bpy.data.meshes[t.mesh_name] for t in targets]
    saved = [attributes.snapshot(m) for m in meshes]
    try:
        for mesh, layers in zip(meshes, layers_per_target):
            attributes.write(mesh, layers)
            mesh.update()
    except BaseException:
        for mesh, snap in zip(meshes, saved):
            attributes.restore(mesh, snap)
        raise
