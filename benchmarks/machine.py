"""The figures that compare two machines (a GPU's beside this one's): ``benchmark --machine``.

The Breakfast Room's default bake, stage by stage, scored against its cached Cycles reference
(256 samples, in ``OUT/cache``: baked there first if missing); Cycles at 16 and 64 samples on
the same machine; and the scaling benchmark's target point (the Room subdivided to a million
vertices, 1,000 probes, 3 bounces) and its 95K-vertex point, each in a process of its own.
Writes ``machine.json`` after each part, so a run cut short keeps what it measured.
"""

import json
import os
import platform
import time

import bpy
import numpy as np

from cubegi.cubegi_addon import reference, scene_data, session
from cubegi.cubegi_engine import __version__

from . import in_child, sweep

SCENE = "breakfast_room"
REFERENCE_SAMPLES = 256
CYCLES_SAMPLES = (16, 64)
# (cuts, probes) of the scaling points: the target, and the point at about 95K vertices.
SCALING = (("target", 12, 1000), ("room_95k", 3, 200))
PARTS = ("breakfast_room", "cycles") + tuple(name for name, _, _ in SCALING)


def run(out_dir, parts=PARTS, log=print, repeat=3, cache_dir=None):
    """Measure ``parts`` (of PARTS) and write ``machine.json``; the results. The reference is
    kept in ``cache_dir`` (default: ``out_dir/cache``)."""
    os.makedirs(out_dir, exist_ok=True)
    results = {"meta": {"cubegi": __version__, "blender": bpy.app.version_string,
                        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, {platform.system()}"}}

    def save():
        with open(os.path.join(out_dir, "machine.json"), "w") as f:
            json.dump(results, f, indent=1)

    if {"breakfast_room", "cycles"} & set(parts):
        sweep.SCENES[SCENE]()
        objects = sweep._meshes()
        ref = sweep.cached_reference(cache_dir or os.path.join(out_dir, "cache"), SCENE, REFERENCE_SAMPLES, objects, log)
        bpy.ops.cubegi.bake(bounces=1, cube_size=8, grid=(2, 2, 2))  # compiles the shaders; not timed
        results["meta"]["gpu"] = sweep._gpu_name()
        kept = session.kept(bpy.context.scene)
        scored = scene_data.scored_areas(kept.bake.targets, kept.bake.arrays)
        areas = np.concatenate([scored[ob.name] for ob in objects])
        runs = results.setdefault(SCENE, [])
        if "breakfast_room" in parts:
            runs.append(sweep._cubegi_run(SCENE, objects, ref, areas, {"default": "after"}, log, repeat=repeat))
            save()
        if "cycles" in parts:
            for k, samples in enumerate(CYCLES_SAMPLES):
                baked, seconds = reference.bake_reference(bpy.context, objects, samples=samples, seed=1 + k)
                direct, indirect = sweep._stack(objects, baked["DIRECT"]), sweep._stack(objects, baked["INDIRECT"])
                total = sum(seconds.values())
                runs.append(sweep._record(SCENE, "cycles", {"samples": samples}, total,
                                          {"indirect": seconds["INDIRECT"], "total": total}, direct, indirect, ref, areas))
                log(f"machine: Cycles {samples} samples: {total:.1f} s")
                save()
    for name, cuts, probes in SCALING:
        if name in parts:
            t = time.perf_counter()
            results[name] = in_child("scaling", "one(%d, %d)" % (cuts, probes), 900)
            log(f"machine: {name}: {results[name]['seconds']:.1f} s ({time.perf_counter() - t:.0f} s with the scene's build)")
            save()
    return results
