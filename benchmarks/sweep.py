"""The benchmark: CubeGI's error against run time, and Cycles' curve on the same machine.

For each scene: a high-sample Cycles reference (cached on disk, the samples in the file
name), then CubeGI over grid spacing x cube-map size x bounces, then Cycles vertex bakes at
increasing samples. Every run is scored against the reference with the same measures
(:mod:`cubegi_engine.metrics`); :mod:`.analysis` analyses the records.
"""

import itertools
import json
import os
import platform
import time

import bpy
import numpy as np

from cubegi.cubegi_addon import attributes, grid_objects, reference, scene_data, session
from cubegi.cubegi_engine import __version__, metrics
from cubegi.cubegi_engine.grid import fit_bounds
from cubegi.cubegi_engine.report import BakeReport
from tools import demo

from . import analysis, public_scenes
from . import scenes as bench_scenes

SCENES = {
    "room": demo.build_room,
    "cornell": bench_scenes.cornell,
    "courtyard": bench_scenes.courtyard,
    "white_box_0.95": bench_scenes.white_box,
    "thin_wall": bench_scenes.thin_wall,
    # Public scenes authored outside CubeGI (see public_scenes; run where shared/scenes is here).
    "breakfast_room": public_scenes.breakfast_room,
    "cornell_original": public_scenes.cornell_original,
}
PUBLIC = ("breakfast_room", "cornell_original")
# The Breakfast Room's Cycles passes take 2.6 s a sample on a 2-core machine: its full run
# keeps a 256-sample reference, Cycles up to 64 samples and a short CubeGI sweep.
LARGE = {
    "breakfast_room": {
        "reference_samples": 256,
        "cycles_samples": (1, 4, 16, 64),
        "cells_along_longest": (6, 12),
        "cube_sizes": (16,),
        "bounces": ((5, True),),
    },
}

# Grid spacing is given as cells along the scene's longest side.
FULL = {
    "cells_along_longest": (4, 8, 12),
    "cube_sizes": (8, 16, 32),
    "bounces": ((2, False), (5, True)),
    "cycles_samples": (1, 4, 16, 64, 256),
    "reference_samples": 1024,
    "default_repeats": 3,  # the defaults' times: the median of this many bakes (timings here vary by 20%)
}
QUICK = {
    "cells_along_longest": (6,),
    "cube_sizes": (16,),
    "bounces": ((5, True),),
    "cycles_samples": (1, 4),
    "reference_samples": 16,
}


def _meshes():
    return sorted((ob for ob in bpy.context.scene.objects if ob.type == "MESH"), key=lambda ob: ob.name)


def _stack(objects, values_by_name):
    return np.concatenate([values_by_name[ob.name] for ob in objects])


def cached_reference(cache_dir, scene_name, samples, objects, log=print):
    """The scene's Cycles reference ``{"direct", "indirect"}`` per vertex (stacked over
    ``objects``), from ``cache_dir/<scene>-cycles-<samples>spp.npz`` or baked and saved there."""
    os.makedirs(cache_dir, exist_ok=True)
    path = os.path.join(cache_dir, f"{scene_name}-cycles-{samples}spp.npz")
    counts = np.array([len(ob.data.vertices) for ob in objects])
    if os.path.exists(path):
        data = np.load(path)
        if np.array_equal(data["counts"], counts):
            log(f"benchmark: {scene_name}: reference from {path}")
            return {"direct": data["direct"], "indirect": data["indirect"], "seconds": float(data["seconds"])}
    log(f"benchmark: {scene_name}: baking the Cycles reference at {samples} samples")
    baked, seconds = reference.bake_reference(bpy.context, objects, samples=samples, seed=0)
    ref = {"direct": _stack(objects, baked["DIRECT"]), "indirect": _stack(objects, baked["INDIRECT"]), "seconds": sum(seconds.values())}
    tmp = path + ".tmp.npz"
    np.savez(tmp, counts=counts, **ref)
    os.replace(tmp, path)
    return ref


# A surface of at least FINE_AREA of the scene's area modelled with at most FINE_VERTICES
# vertices (a wall of a few quads) has its mean from a handful of the reference's vertices,
# each as noisy as the reference's samples leave it: those surfaces are baked again, alone
# in the scene, at FINE_FACTOR times the samples (a few seconds), and the table shows both.
FINE_AREA, FINE_VERTICES, FINE_FACTOR = 0.01, 128, 16


def fine_surfaces(cache_dir, scene_name, samples, objects, scored, log=print):
    """``({object name: {"direct", "indirect"}: area-weighted mean}, samples)`` of the few-vertex
    large surfaces (see FINE_AREA) at ``samples``, cached beside the scene's reference; ``({},
    samples)`` where the scene has none."""
    total = sum(float(scored[ob.name].sum()) for ob in objects)
    few = [ob for ob in objects if len(ob.data.vertices) <= FINE_VERTICES and scored[ob.name].sum() >= FINE_AREA * total]
    if not few:
        return {}, samples
    ref = cached_reference(cache_dir, f"{scene_name}-surfaces", samples, few, log)
    out, start = {}, 0
    for ob in few:
        sl = slice(start, start + len(ob.data.vertices))
        start = sl.stop
        out[ob.name] = {part: float(np.average(ref[part][sl].mean(axis=1), weights=scored[ob.name])) for part in ("direct", "indirect")}
    return out, samples


def _record(scene_name, method, settings, seconds, by_part, ours_direct, ours_indirect, ref, areas, extra=None):
    rec = {
        "scene": scene_name,
        "method": method,
        "settings": settings,
        "seconds": seconds,
        "seconds_by_part": by_part,
        "errors": metrics.compare(ours_direct, ours_indirect, ref["direct"], ref["indirect"], areas),
    }
    rec.update(extra or {})
    return rec


def run_scene(scene_name, config, cache_dir, log=print):
    """All runs of one scene: a list of records."""
    if config is FULL:
        config = {**config, **LARGE.get(scene_name, {})}
    SCENES[scene_name]()
    objects = _meshes()
    ref = cached_reference(cache_dir, scene_name, config["reference_samples"], objects, log)
    lo, hi = grid_objects.world_bounds(objects)
    records = []
    # A first bake compiles the shaders; it is not timed.
    bpy.ops.cubegi.bake(bounces=1, cube_size=8, grid=(2, 2, 2))
    kept = session.kept(bpy.context.scene)
    scored = scene_data.scored_areas(kept.bake.targets, kept.bake.arrays)  # black vertices left out: Cycles gives them no light
    areas = np.concatenate([scored[ob.name] for ob in objects])
    for cells, cube, (bounces, tail) in itertools.product(config["cells_along_longest"], config["cube_sizes"], config["bounces"]):
        res = fit_bounds(lo, hi, spacing=float(np.max(hi - lo)) / cells, max_probes=1 << 14)
        settings = {"grid": "x".join(map(str, res)), "cube": cube, "bounces": bounces, "tail": tail}
        records.append(_cubegi_run(scene_name, objects, ref, areas, settings, log,
                                   grid=res, cube_size=cube, bounces=bounces, add_tail=tail))
        if bounces == max(b for b, _ in config["bounces"]):  # the same without the near field
            records.append(_cubegi_run(scene_name, objects, ref, areas, {**settings, "near field": False}, log,
                                       grid=res, cube_size=cube, bounces=bounces, add_tail=tail, near_field=False))
    # The default a new user gets (no options: the fitted grid), the one before the near field
    # and the one with its probes inside geometry left in place.
    # Where the scene has a sky, also the default with the sky per vertex (an option).
    variants = [("before", {"near_field": False}), ("probes in place", {"move_probes": False}), ("after", {})]
    if np.any(kept.bake.arrays.sky > 0):
        variants.append(("sky per vertex", {"sky_per_vertex": True}))
    for which, kw in variants:
        records.append(_cubegi_run(scene_name, objects, ref, areas, {"default": which}, log, repeat=config.get("default_repeats", 1), **kw))
        if which == "after":
            ours = baked_light(objects)
            records[-1]["surfaces"] = _surfaces(objects, ours, ref, scored)
            fine, fine_samples = fine_surfaces(cache_dir, scene_name, FINE_FACTOR * config["reference_samples"], objects, scored, log)
            for name, means in fine.items():
                records[-1]["surfaces"][name]["fine"] = {**means, "samples": fine_samples}
            records[-1]["error_holders"] = {part: metrics.error_holders(ours[part], ref[part], areas) for part in ours}
    for k, samples in enumerate(config["cycles_samples"]):
        baked, seconds = reference.bake_reference(bpy.context, objects, samples=samples, seed=1 + k)
        direct, indirect = _stack(objects, baked["DIRECT"]), _stack(objects, baked["INDIRECT"])
        total = sum(seconds.values())
        by_part = {"indirect": seconds["INDIRECT"], "total": total}
        records.append(_record(scene_name, "cycles", {"samples": samples}, total, by_part, direct, indirect, ref, areas))
        e = records[-1]["errors"]
        log(
            f"benchmark: {scene_name}: Cycles {samples} samples: {total:.2f} s, "
            f"indirect RMSE {100 * e['indirect']['rel_rmse']:.1f}%, total RMSE {100 * e['total']['rel_rmse']:.1f}%"
        )
    return records


def baked_light(objects):
    """The last bake's ``{"direct", "indirect"}`` light per vertex, stacked over ``objects``."""
    return {part: _stack(objects, {ob.name: attributes.read(ob.data, name) for ob in objects})
            for part, name in (("direct", attributes.DIRECT), ("indirect", attributes.INDIRECT))}


def _surfaces(objects, ours, ref, scored):
    """Per object: its area, its area-weighted mean direct and indirect light, ``ours``
    (:func:`baked_light`) and the reference's, and its share of the scene's squared error of
    each (where the error sits, surface by surface)."""
    areas = np.concatenate([scored[ob.name] for ob in objects])
    shares = {part: metrics.squared_error(ours[part], ref[part], areas) for part in ours}
    out, start = {}, 0
    for ob in objects:
        count = len(ob.data.vertices)
        sl = slice(start, start + count)
        start += count
        w = scored[ob.name]
        if w.sum() <= 0:
            continue
        row = {"area": float(w.sum())}
        for part in ours:
            mine = ours[part][sl].mean(axis=1)
            theirs = np.asarray(ref[part][sl]).mean(axis=1)
            row[part] = [float(np.average(mine, weights=w)), float(np.average(theirs, weights=w))]
            row[f"{part}_error_share"] = float(shares[part][sl].sum())
        out[ob.name] = row
    return out


def _cubegi_run(scene_name, objects, ref, areas, settings, log, repeat=1, **bake):
    """One CubeGI bake with the operator's ``bake`` options, scored: its record. A one-shot
    bake: the kept capture of the run before is dropped first (else a run on the same grid
    would be timed without its capture). ``repeat``: bakes timed, the median kept (the
    light is the same every time)."""
    times = []
    for _ in range(repeat):
        session.forget()
        if bpy.ops.cubegi.bake(**bake) != {"FINISHED"}:
            raise RuntimeError(f"{scene_name}: the bake with {bake} did not finish")
        times.append(BakeReport.from_json(bpy.context.scene.cubegi.last_report).total_seconds)
    rep = BakeReport.from_json(bpy.context.scene.cubegi.last_report)
    light = baked_light(objects)
    direct, indirect = light["direct"], light["indirect"]
    t = float(np.median(times))
    if "grid" not in settings:  # a default bake: what it chose
        settings = dict(settings, grid="x".join(map(str, rep.grid.resolution)), cube=rep.settings["cube_size"],
                        bounces=len(rep.bounces), tail=rep.tail.added, **({"near field": False} if not rep.near_field else {}),
                        **({"probes moved": rep.grid.probes_moved} if rep.grid.probes_moved else {}))
    extra = {"probes": rep.grid.probes, "timings": rep.timings, "estimated_remaining_error": rep.estimated_remaining_error}
    record = _record(scene_name, "cubegi", settings, t, {"indirect": t, "total": t}, direct, indirect, ref, areas, extra)
    e = record["errors"]
    log(
        f"benchmark: {scene_name}: CubeGI {analysis.describe(settings)}: {t:.2f} s, "
        f"indirect RMSE {100 * e['indirect']['rel_rmse']:.1f}%, total RMSE {100 * e['total']['rel_rmse']:.1f}%"
    )
    return record


def run(out_dir, quick=False, scenes=None, log=print):
    """Run the benchmark and write ``results.json``, ``results.md``, ``error_vs_time.png``."""
    config = QUICK if quick else FULL
    os.makedirs(out_dir, exist_ok=True)
    names = list(scenes or SCENES)
    unknown = [n for n in names if n not in SCENES]
    if unknown:
        raise ValueError(f"unknown benchmark scene(s) {', '.join(unknown)}; known: {', '.join(SCENES)}")
    if quick and not scenes:  # the quick sweep is a smoke test: the scenes built in code
        names = [n for n in names if n not in PUBLIC]
    if public_scenes.scenes_dir() is None:
        if scenes and set(names) & set(PUBLIC):
            raise ValueError("the public scenes are not here: set CUBEGI_PUBLIC_SCENES to the folder of shared/scenes")
        log(f"benchmark: the public scenes ({', '.join(PUBLIC)}) are not here and are left out (set CUBEGI_PUBLIC_SCENES)")
        names = [n for n in names if n not in PUBLIC]
    t0 = time.perf_counter()
    records = []
    for name in names:
        records += run_scene(name, config, os.path.join(out_dir, "cache"), log)
    meta = {
        "cubegi": __version__,
        **({"credits": "; ".join(public_scenes.CREDIT[n] for n in names if n in public_scenes.CREDIT)}
           if set(names) & set(PUBLIC) else {}),
        "blender": bpy.app.version_string,
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, {platform.system()}",
        "gpu": _gpu_name(),
        "mode": "quick" if quick else "full",
        "reference samples": ", ".join(f"{n} {LARGE.get(n, {}).get('reference_samples', config['reference_samples'])}"
                                       for n in names) if not quick else config["reference_samples"],
        "wall seconds": round(time.perf_counter() - t0, 1),
    }
    with open(os.path.join(out_dir, "results.json"), "w") as fh:
        json.dump({"meta": meta, "config": config, "records": records}, fh, indent=1)
    with open(os.path.join(out_dir, "results.md"), "w") as fh:
        fh.write(analysis.markdown(records, meta))
    png = os.path.join(out_dir, "error_vs_time.png")
    if not analysis.plot(records, png):
        log("benchmark: matplotlib is not installed; error_vs_time.png was not drawn")
    return records


def _gpu_name():
    try:
        import gpu

        return f"{gpu.platform.renderer_get()} ({gpu.platform.backend_type_get()})"
    except Exception:  # the GPU module is not up outside a bake
        return "unknown"
