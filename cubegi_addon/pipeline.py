"""The bake as Blender sees it: scene in, attributes out, a report.

Thin glue: :mod:`.scene_data` turns the scene into arrays, :mod:`.gpu_capture` draws, the
engine computes, :mod:`.attributes` writes. Nothing is written to a mesh until every value is
computed; if writing fails midway, every mesh gets its previous CubeGI attributes back.
"""

import json
import os
import time

import numpy as np

from ..cubegi_engine import __version__
from ..cubegi_engine import metrics
from ..cubegi_engine.bake import BakeSettings, Progress, area_weighted_mean, bake_steps as engine_bake_steps, check_memory
from ..cubegi_engine.grid import GridSet, ProbeGrid, fit_bounds
from . import attributes, probe_view, reference, scene_data
from .gpu_capture import GpuRenderer

# Probes of a fitted grid: cells of about an eighth of the scene's longest side.
MAX_FITTED_PROBES = 4096
# An object seen from behind over more than this share of what the probes see of it is noted.
SEEN_FROM_BEHIND_NOTE = 0.1


def probe_grid_objects(scene):
    """The scene's probe grid objects (Empties marked by ``Object.cubegi.is_probe_grid``), by
    name: the order of a bake's grids and of their probes."""
    return sorted(
        (ob for ob in scene.objects if ob.type == "EMPTY" and getattr(ob, "cubegi", None) and ob.cubegi.is_probe_grid),
        key=lambda ob: ob.name,
    )


def new_probe_grid(collection, lo, hi, resolution, name="CubeGI Probe Grid"):
    """Link a probe grid Empty whose cube spans ``lo``..``hi``; returns the object."""
    import bpy

    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    ob = bpy.data.objects.new(name, None)
    ob.empty_display_type = "CUBE"
    ob.empty_display_size = 1.0
    ob.location = tuple(0.5 * (lo + hi))
    ob.scale = tuple(np.maximum(0.5 * (hi - lo), 1e-6))
    collection.objects.link(ob)
    ob.cubegi.is_probe_grid = True
    ob.cubegi.resolution = tuple(int(r) for r in resolution)
    return ob


def world_bounds(objects):
    """World-space axis-aligned box ``(lo, hi)`` of the objects' bounding boxes, or None."""
    corners = [np.array([list(c) + [1.0] for c in ob.bound_box]) @ np.array(ob.matrix_world).T for ob in objects]
    if not corners:
        return None
    pts = np.concatenate(corners)[:, :3]
    return pts.min(axis=0), pts.max(axis=0)


def grid_bounds_of(ob):
    """World-space axis-aligned box of a probe grid object's cube (rotation is ignored)."""
    s = ob.empty_display_size
    corners = np.array([[x, y, z, 1.0] for x in (-s, s) for y in (-s, s) for z in (-s, s)])
    world = corners @ np.array(ob.matrix_world, dtype=np.float64).T
    return world[:, :3].min(axis=0), world[:, :3].max(axis=0)


def resolve_grid(scene, arrays, resolution=None):
    """The probe grid(s) of a bake, where they came from, and the share of points outside.

    ``resolution`` (3 ints) overrides the resolution (of every grid). The bounds come from the
    scene's probe grid objects if it has any, else from the geometry's bounding box. With
    several grid objects each point uses the finest grid whose box contains it (see
    :class:`cubegi_engine.grid.GridSet`); points outside every grid get the light of the
    nearest grid's nearest probes (trilinear weights clamped at its faces). A grid object
    with no geometry inside is refused.
    """
    objects = probe_grid_objects(scene)
    if objects:
        grids, inside_any = [], np.zeros(len(arrays.points), dtype=bool)
        for ob in objects:
            lo, hi = grid_bounds_of(ob)
            inside = np.all((arrays.points >= lo) & (arrays.points <= hi), axis=1)
            if not inside.any():
                raise ValueError(f"probe grid {ob.name!r} contains no geometry; move or scale it over the scene")
            inside_any |= inside
            grids.append(ProbeGrid(lo, hi, resolution or tuple(ob.cubegi.resolution)))
        names = ", ".join(repr(ob.name) for ob in objects)
        grid = grids[0] if len(grids) == 1 else GridSet(grids)
        source = f"probe grid object{'s' if len(grids) > 1 else ''} {names}"
        return grid, source, float(1.0 - inside_any.mean())
    lo, hi = arrays.bounds()
    pad = np.maximum(hi - lo, 1e-9 * max(arrays.scale, 1e-30)) * 1e-3
    lo, hi = lo - pad, hi + pad
    if resolution:
        return ProbeGrid(lo, hi, resolution), "scene bounds", 0.0
    return ProbeGrid(lo, hi, fit_bounds(lo, hi, max_probes=MAX_FITTED_PROBES)), "fitted to scene bounds", 0.0


def grid_report(grid):
    """The grid part of a report: every grid's resolution and box (the first's at top level)."""
    grids = getattr(grid, "grids", (grid,))
    each = [{"resolution": list(g.resolution), "lo": list(g.lo), "hi": list(g.hi), "probes": g.count} for g in grids]
    return dict(each[0], probes=grid.count, grids=each)


class Preview:
    """The light so far, written to the meshes after every step of a progressive bake.

    It writes ``CubeGI_direct``, then after bounce k ``CubeGI_bounce_k``, ``CubeGI`` and
    ``CubeGI_total`` as they stand. :meth:`undo` puts every mesh back as it was before the
    first write (attributes and active colour attributes).
    """

    def __init__(self):
        self.meshes, self.targets, self.saved = [], [], []
        self.direct = self.previous = None
        self.bounce = 0

    def start(self, targets):
        import bpy

        self.targets = targets
        self.meshes = [bpy.data.meshes[t.mesh_name] for t in targets]
        self.saved = [attributes.snapshot(m) for m in self.meshes]

    def update(self, step):
        light = step.light
        if self.direct is None:
            self.direct = light
            layers = {attributes.DIRECT: light, attributes.TOTAL_LIGHT: light}
        else:
            layers = {attributes.TOTAL_LIGHT: light, attributes.TOTAL: light - self.direct}
            if step.stage == "bounce":
                self.bounce += 1
                layers[attributes.bounce_name(self.bounce)] = light - self.previous
        self.previous = light
        for target, mesh in zip(self.targets, self.meshes):
            for name, values in layers.items():
                attributes.put(mesh, name, attributes.vertex_values(target, values))
            mesh.update()

    def undo(self):
        for mesh, snap in zip(self.meshes, self.saved):
            attributes.restore(mesh, snap)
            mesh.update()
        self.meshes = []


def _previewed(steps, preview):
    """Pass ``steps`` through, showing each new light with ``preview`` (if any)."""
    while True:
        try:
            step = next(steps)
        except StopIteration as stop:
            return stop.value
        if preview is not None and step.light is not None:
            preview.update(step)
        yield step


def bake_steps(context, settings=None, resolution=None, lit=False, reference_samples=None, progressive=False):
    """Bake the context's scene. A generator of engine Progress; returns the report dict.

    ``lit``: False, True or "ALL" (``CubeGI_lit`` = albedo x all light) or "INDIRECT"
    (albedo x indirect light). With ``reference_samples``, Cycles also bakes the same light into ``CubeGI_ref_direct``
    and ``CubeGI_ref_indirect`` and the report gives CubeGI's error against it. With
    ``progressive``, the light so far is written to the meshes after every step (see
    :class:`Preview`); closing the generator early (a cancel) or a failure puts every mesh
    back as it was.
    """
    preview = Preview() if progressive else None
    try:
        return (yield from _bake_steps(context, settings, resolution, lit, reference_samples, preview))
    except BaseException:
        if preview is not None:
            preview.undo()
        raise


def _bake_steps(context, settings, resolution, lit, reference_samples, preview):
    settings = settings or BakeSettings()
    settings.validate()
    t0 = time.perf_counter()
    collected = scene_data.collect(context)
    arrays = collected.arrays
    grid, grid_source, outside = resolve_grid(context.scene, arrays, resolution)
    if outside > 0:
        collected.notes.append(
            f"{100 * outside:.1f}% of the shading points lie outside every probe grid; they get the light of the nearest grid's nearest probes"
        )
    t_collect = time.perf_counter() - t0
    if not collected.targets:
        raise ValueError("no mesh in the scene can receive baked light")

    check_memory(grid.count, settings.cube_size, len(arrays.points))
    t = time.perf_counter()
    renderer = GpuRenderer(arrays.points, arrays.triangles)
    t_setup = time.perf_counter() - t
    if preview is not None:
        preview.start(collected.targets)
    result = yield from _previewed(engine_bake_steps(arrays, grid, renderer, settings), preview)

    if not result.probe_valid.any():
        collected.notes.append(
            f"all {grid.count} probes see back faces over more than a quarter of their view (inside geometry, or "
            "normals pointing away from them); each point uses its plain trilinear weights"
        )
    if result.seen_from_behind is not None:
        for name, share in zip(collected.object_names, result.seen_from_behind):
            if share > SEEN_FROM_BEHIND_NOTE:
                collected.notes.append(
                    f"{name}: {100 * share:.0f}% of what the probes see of it are back faces (flipped normals, or a "
                    "one-sided surface seen from behind); back faces get and pass on no light. Recalculate its normals "
                    "(Mesh > Normals > Recalculate Outside) or give thin walls thickness"
                )
    t = time.perf_counter()
    layers_per_target = []
    indirect = result.indirect
    for target in collected.targets:
        layers = {attributes.DIRECT: attributes.vertex_values(target, result.direct)}
        for k, b in enumerate(result.bounces, start=1):
            layers[attributes.bounce_name(k)] = attributes.vertex_values(target, b)
        layers[attributes.TOTAL] = attributes.vertex_values(target, indirect)
        layers[attributes.TOTAL_LIGHT] = attributes.vertex_values(target, result.direct + indirect)
        if lit:
            light = indirect if lit == "INDIRECT" else result.direct + indirect
            layers[attributes.LIT] = attributes.vertex_values(target, arrays.albedo * light)
        layers_per_target.append(layers)
    t_layers = time.perf_counter() - t
    cubegi_seconds = time.perf_counter() - t0  # before the write, for the reference report

    reference_report = None
    if reference_samples:
        steps = 3 + settings.bounces
        yield Progress("reference", steps, steps + 1, f"Cycles reference at {reference_samples} samples")
        ref_layers, ref_seconds = reference.reference_layers(context, collected.targets, reference_samples)
        reference_report = _reference_report(collected.targets, layers_per_target, ref_layers, reference_samples, ref_seconds, cubegi_seconds)
        for layers, ref in zip(layers_per_target, ref_layers):
            layers.update(ref)

    t = time.perf_counter()
    write_all(context, collected.targets, layers_per_target)
    grid_objects = probe_grid_objects(context.scene)
    if grid_objects:
        probe_view.store(grid_objects, grid, result.probe_coeffs, result.probe_valid)
    t_write = t_layers + time.perf_counter() - t

    areas = arrays.point_areas()
    names = list(layers_per_target[0].keys())
    for rec in result.bounce_records:
        rec["attribute"] = attributes.bounce_name(rec["bounce"])
    timings = dict(result.timings)
    # CubeGI's own time: everything but the Cycles reference.
    total = time.perf_counter() - t0 - (reference_report["seconds"] if reference_report else 0.0)
    timings.update(collect=t_collect, gpu_setup=t_setup, write=t_write, total=total)
    return {
        "cubegi_version": __version__,
        "settings": {
            "cube_size": settings.cube_size,
            "bounces": settings.bounces,
            "visibility": settings.visibility,
            "shadow_size": settings.shadow_size,
            "tolerance": settings.tolerance,
            "add_tail": settings.add_tail,
            "conserve_energy": settings.conserve_energy,
            "lit": ("INDIRECT" if lit == "INDIRECT" else "ALL") if lit else "NONE",
        },
        "grid": {
            **grid_report(grid),
            "probes_inside_geometry": int((~result.probe_valid).sum()),
            "source": grid_source,
        },
        "scene": {
            "points": len(arrays.points),
            "triangles": len(arrays.triangles),
            "lights": len(arrays.lights),
            "sky": arrays.sky.tolist(),
            "meshes_baked": [t.object_name for t in collected.targets],
            "notes": collected.notes,
        },
        "direct": {
            "seconds": timings["direct"],
            "mean_light": area_weighted_mean(result.direct, areas).tolist(),
            "attribute": attributes.DIRECT,
            "emitter_energy_factor": np.asarray(result.emitter_energy_factor).tolist(),
        },
        "bounces": result.bounce_records,
        "indirect": {"mean_light": area_weighted_mean(indirect, areas).tolist(), "attribute": attributes.TOTAL},
        "tail": result.tail_report,
        # The share of the full indirect light the computed bounces miss (estimated from the
        # observed rate); with tail.added it is in CubeGI as the tail.
        "estimated_remaining_error": result.tail_report["estimated_remaining"],
        "timings": timings,
        "total_seconds": timings["total"],
        "reference": reference_report,
        "attributes": names,
        "warnings": [w for w in (result.tail_report.get("warning"),) if w],
    }


def _reference_report(targets, ours, theirs, samples, ref_seconds, cubegi_seconds):
    import bpy

    areas = np.concatenate([scene_data.vertex_areas(bpy.data.objects[t.object_name]) for t in targets])

    def stack(layers, name):
        return np.concatenate([layer[name] for layer in layers])

    errors = metrics.compare(
        stack(ours, attributes.DIRECT), stack(ours, attributes.TOTAL),
        stack(theirs, attributes.REF_DIRECT), stack(theirs, attributes.REF_INDIRECT), areas,
    )
    return {
        "renderer": "cycles",
        "samples": int(samples),
        "seconds": ref_seconds,
        "cubegi_seconds": cubegi_seconds,
        "attributes": [attributes.REF_DIRECT, attributes.REF_INDIRECT],
        "errors": errors,
    }


def write_all(context, targets, layers_per_target):
    """Write every target's layers, or none: a failure restores what was there."""
    import bpy

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


def write_report(report, path):
    """Write the report as JSON through a temporary file."""
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as fh:
        json.dump(report, fh, indent=2)
    os.replace(tmp, path)
