"""The lights benchmark: the hall (:func:`benchmarks.scenes.hall`) lit by one area lamp and by
thirteen, the same light in all, each baked at the default quality in a process of its own
and scored against Cycles (``benchmark --lights``): how many lights cost. Writes
``lights.json`` and ``lights.md``; the Cycles references are kept in ``cache/`` under the
output folder.
"""

import json
import os
import platform
import time

import numpy as np

from benchmarks import in_child
from cubegi.cubegi_engine import __version__

LAMPS = (1, 13)
REFERENCE_SAMPLES = 256


def one(lamps, cache_dir):
    """Build the hall with ``lamps`` lamps, bake it at the default quality (in this process,
    after a first bake that compiles the shaders) and score it: the record."""
    import bpy

    from benchmarks import scenes, sweep
    from cubegi.cubegi_addon import scene_data, session
    from cubegi.cubegi_engine import metrics
    from cubegi.cubegi_engine.report import BakeReport

    scenes.hall(lamps)
    objects = sweep._meshes()
    ref = sweep.cached_reference(cache_dir, f"hall_{lamps}_lamps", REFERENCE_SAMPLES, objects, log=lambda m: None)
    bpy.ops.cubegi.bake(bounces=1, cube_size=8, grid=(2, 2, 2))
    session.forget()
    t = time.perf_counter()
    assert bpy.ops.cubegi.bake() == {"FINISHED"}
    seconds = time.perf_counter() - t
    report = BakeReport.from_json(bpy.context.scene.cubegi.last_report)
    bake = session.kept(bpy.context.scene).bake
    scored = scene_data.scored_areas(bake.targets, bake.arrays)
    areas = np.concatenate([scored[ob.name] for ob in objects])
    read = sweep.baked_light(objects)
    errors = metrics.compare(read["direct"], read["indirect"], ref["direct"], ref["indirect"], areas)
    return {"lamps": lamps, "points": report.points, "triangles": report.triangles, "seconds": seconds, "timings": report.timings,
            "shadow_eyes": sorted(bake.result.direct_parts.eyes.values()),
            "errors": {part: {"rel_rmse": errors[part]["rel_rmse"], "rel_bias": errors[part]["rel_bias"]}
                       for part in ("direct", "indirect", "total")},
            "reference_samples": REFERENCE_SAMPLES, "reference_seconds": ref["seconds"]}


def _child(lamps, cache_dir, timeout):
    return in_child("lights", "one(%d, %r)" % (lamps, cache_dir), timeout)


STAGES = ("capture", "tables", "near_field", "direct", "bounces", "tail")


def run(out_dir, log=print, timeout=3600):
    """The hall with each count of LAMPS; writes ``lights.json`` and ``lights.md``; the records."""
    os.makedirs(out_dir, exist_ok=True)
    cache = os.path.join(out_dir, "cache")
    records = []
    for lamps in LAMPS:
        rec = _child(lamps, cache, timeout)
        records.append(rec)
        e = rec["errors"]
        log(f"lights: the hall with {lamps} lamp(s): {rec['seconds']:.2f} s (direct {rec['timings'].get('direct', 0.0):.2f} s, "
            f"shadow eyes {sum(rec['shadow_eyes'])}), direct {100 * e['direct']['rel_rmse']:.1f}%, "
            f"indirect {100 * e['indirect']['rel_rmse']:.1f}%")
    ratio = records[-1]["seconds"] / records[0]["seconds"]
    log(f"lights: {LAMPS[-1]} lamps take {ratio:.2f}x the time of {LAMPS[0]}")
    meta = {"cubegi": __version__, "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, {platform.system()}"}
    with open(os.path.join(out_dir, "lights.json"), "w") as f:
        json.dump({"meta": meta, "ratio": ratio, "records": records}, f, indent=1)
    rows = ["| lamps | points | time | " + " | ".join(STAGES) + " | shadow eyes | direct error | indirect error | total error |",
            "|---" * (len(STAGES) + 7) + "|"]
    for rec in records:
        t, e = rec["timings"], rec["errors"]
        rows.append(f"| {rec['lamps']} | {rec['points']:,} | {rec['seconds']:.2f} s | "
                    + " | ".join(f"{t.get(s, 0.0):.2f}" for s in STAGES)
                    + f" | {sum(rec['shadow_eyes'])} | " + " | ".join(f"{100 * e[p]['rel_rmse']:.1f}%" for p in ("direct", "indirect", "total"))
                    + " |")
    text = ("# CubeGI lights benchmark\n\n"
            f"- cubegi: {meta['cubegi']}\n- machine: {meta['machine']}\n- reference: Cycles at {REFERENCE_SAMPLES} samples\n\n"
            "The hall (20 x 8 x 5 m, pillars, a table, a floating staircase; `benchmarks/scenes.py`, `hall`) lit by one "
            "area lamp and by thirteen, the same light in all, each baked at the default quality in a process of its own. "
            "Seconds per stage (the near field's time is part of the tables'); errors are per-vertex relative RMSE "
            "against Cycles.\n\n" + "\n".join(rows)
            + f"\n\n{LAMPS[-1]} lamps take **{ratio:.2f}x** the time of {LAMPS[0]}.\n")
    with open(os.path.join(out_dir, "lights.md"), "w") as f:
        f.write(text)
    return records, ratio
