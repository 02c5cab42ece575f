"""The scaling benchmark: scenes baked at growing vertex counts and probe counts, with the
time of each stage and the peak memory (``benchmark --scaling``).

The sweeps subdivide every mesh (``cuts`` new edges across each edge: (cuts + 1)^2 times
the faces) of the demo Room (about 6,400 x (cuts + 1)^2 vertices) and, where the public
scenes are here, of *The Breakfast Room* (143K x about (cuts + 1)^2: geometry as a user
models it, chairs and blinds standing on floors and sills); the probes are a grid fitted
to the scene. Each bake runs in a process of its own, so that its peak memory (the
high-water mark of the resident set, reset after the scene is built) is its own. Writes
``scaling.json`` and ``scaling.png``.
"""

import json
import os
import platform
import time

import numpy as np

from benchmarks import in_child
from cubegi.cubegi_engine import __version__

# (cuts, probes) of each sweep: vertices at about 200 probes, probes at about 95K vertices,
# and the target point (a million vertices, a thousand probes).
VERTEX_SWEEP = ((0, 200), (1, 200), (3, 200), (6, 200), (12, 200))
PROBE_SWEEP = ((3, 50), (3, 200), (3, 500), (3, 1000), (3, 2000))
TARGET = ((12, 1000),)
# The Breakfast Room as modelled and subdivided once and twice (554K and 1.25M vertices), at
# the target's thousand probes.
REAL_SWEEP = ((0, 1000), (1, 1000), (2, 1000))
QUICK = {"vertices": ((0, 50), (1, 50)), "probes": ((0, 50), (0, 200)), "target": (), "real": ((0, 50),)}
BOUNCES = 3
ROOM = np.array([4.0, 9.0, 2.8])  # the demo Room's box (its probes' grid is fitted to it)


def resolution_for(probes, size=ROOM):
    """A grid over a box of ``size`` (the Room's by default) with about ``probes`` probes
    (cells about cubes)."""
    size = np.asarray(size, dtype=np.float64)
    k = (probes / np.prod(size)) ** (1.0 / 3.0)
    return tuple(int(max(1, round(x))) for x in size * k)


def one(cuts, probes, scene="room"):
    """Build the subdivided ``scene`` (``room``, or ``breakfast_room``: the public scene)
    and bake it (in this process); the record."""
    import bmesh
    import bpy

    from cubegi.cubegi_addon import pipeline
    from cubegi.cubegi_engine.settings import BakeSettings
    from tools import demo

    if scene == "room":
        demo.build_room()
        size = ROOM
    else:
        from benchmarks import public_scenes

        getattr(public_scenes, scene)()
        size = _mesh_box()
    for ob in bpy.context.scene.objects:
        if ob.type == "MESH" and cuts:
            bm = bmesh.new()
            bm.from_mesh(ob.data)
            bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=cuts, use_grid_fill=True)
            bm.to_mesh(ob.data)
            bm.free()
    vertices = sum(len(ob.data.vertices) for ob in bpy.context.scene.objects if ob.type == "MESH")
    before = _resident()
    _reset_peak()
    t = time.perf_counter()
    report, longest = longest_step(pipeline.bake_steps(bpy.context, BakeSettings(bounces=BOUNCES), resolution_for(probes, size),
                                                       progressive=True))
    seconds = time.perf_counter() - t
    drawn = report.capture_geometry
    return {
        "scene": scene, "cuts": cuts, "vertices": vertices, "points": report.points, "triangles": report.triangles,
        "probes": report.grid.probes, "probes_captured": report.grid.probes_captured or report.grid.probes,
        "capture_triangles": drawn.triangles if drawn else report.triangles, "bounces": len(report.bounces),
        "cube_size": report.settings["cube_size"], "seconds": seconds, "timings": report.timings,
        "peak_gb": _peak() / 2**30, "before_gb": before / 2**30, "gpu": _gpu(),
        "longest_step_seconds": longest[0], "longest_step_after": longest[1],
    }


def _mesh_box():
    """The size of the box around the scene's meshes, in world space."""
    import bpy
    from mathutils import Vector

    corners = np.array([ob.matrix_world @ Vector(c) for ob in bpy.context.scene.objects if ob.type == "MESH" for c in ob.bound_box])
    return corners.max(axis=0) - corners.min(axis=0)


def longest_step(steps):
    """Drive a bake's steps as the modal operator does (with its preview); ``(result,
    (seconds, message))``: the longest time Blender waited for a step, and the step before it
    (what it waited on came after that one)."""
    longest, message, last = (0.0, "the start"), "the start", time.perf_counter()
    while True:
        try:
            step = next(steps)
        except StopIteration as stop:
            gap = time.perf_counter() - last
            return stop.value, max(longest, (gap, message))
        gap, now = time.perf_counter() - last, time.perf_counter()
        longest = max(longest, (gap, message))
        message, last = step.message, now


def _status(field):
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def _resident():
    return _status("VmRSS:") or 0


def _reset_peak():
    """Start the high-water mark afresh (Linux: clear_refs 5), so the bake's peak is its own."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass


def _peak():
    import resource

    hwm = _status("VmHWM:")
    return hwm if hwm is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _child(cuts, probes, timeout, scene="room"):
    return in_child("scaling", "one(%d, %d, %r)" % (cuts, probes, scene), timeout)


def slope(xs, ys):
    """The log-log slope of ``ys`` against ``xs`` (1: linear), fitted by least squares."""
    x, y = np.log(np.asarray(xs, dtype=float)), np.log(np.asarray(ys, dtype=float))
    return float(np.polyfit(x, y, 1)[0]) if len(x) > 1 else float("nan")


def run(out_dir, quick=False, log=print, timeout=900):
    """Both sweeps and the target point; writes ``scaling.json`` and ``scaling.png``."""
    os.makedirs(out_dir, exist_ok=True)
    plan = QUICK if quick else {"vertices": VERTEX_SWEEP, "probes": PROBE_SWEEP, "target": TARGET, "real": REAL_SWEEP}
    if plan["real"] and _public_scenes() is None:
        log("scaling: the public scenes are not here (CUBEGI_PUBLIC_SCENES): the real scene's sweep is left out")
        plan = {**plan, "real": ()}
    results = {}
    for sweep, points in plan.items():
        results[sweep] = []
        for cuts, probes in points:
            rec = _child(cuts, probes, timeout, "breakfast_room" if sweep == "real" else "room")
            results[sweep].append(rec)
            log(f"scaling: {rec['vertices']:,} vertices, {rec['probes']} probes ({rec['probes_captured']} captured, "
                f"{rec['capture_triangles']:,} of {rec['triangles']:,} triangles drawn): {rec['seconds']:.1f} s, "
                f"peak {rec['peak_gb']:.2f} GB; longest step {rec['longest_step_seconds']:.2f} s (after "
                f"{rec['longest_step_after']!r})")
    fits = {}
    if len(results["vertices"]) > 1:
        fits["seconds_vs_vertices"] = slope([r["vertices"] for r in results["vertices"]], [r["seconds"] for r in results["vertices"]])
    if len(results["probes"]) > 1:
        fits["seconds_vs_probes"] = slope([r["probes"] for r in results["probes"]], [r["seconds"] for r in results["probes"]])
    if len(results["real"]) > 1:
        fits["real_seconds_vs_vertices"] = slope([r["vertices"] for r in results["real"]], [r["seconds"] for r in results["real"]])
    meta = {"cubegi": __version__, "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, {platform.system()}",
            "gpu": next((r["gpu"] for recs in results.values() for r in recs), "unknown"), "bounces": BOUNCES, "mode": "quick" if quick else "full"}
    with open(os.path.join(out_dir, "scaling.json"), "w") as f:
        json.dump({"meta": meta, "fits": fits, **results}, f, indent=1)
    _plot(results, fits, os.path.join(out_dir, "scaling.png"))
    for name, value in fits.items():
        log(f"scaling: log-log slope of {name.replace('_', ' ')}: {value:.2f} (1 = linear)")
    return results, fits


def _public_scenes():
    from benchmarks.public_scenes import scenes_dir

    return scenes_dir()


def _gpu():
    try:
        import gpu

        return gpu.platform.renderer_get()
    except Exception:  # noqa: BLE001 - not drawn yet, or no GPU module: the plot says so
        return "unknown"


STAGES = ("collect", "simplify", "capture", "tables", "direct", "bounces", "tail", "write")


def _plot(results, fits, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("vertices", "vertices", "seconds_vs_vertices", "the Room"), ("probes", "probes", "seconds_vs_probes", "the Room")]
    if results.get("real"):
        panels.append(("real", "vertices", "real_seconds_vs_vertices", "The Breakfast Room"))
    fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 4.8))
    for ax, (sweep, label, fit_key, scene) in zip(axes, panels):
        key = label
        recs = results.get(sweep) or []
        if not recs:
            continue
        xs = np.array([r[key] for r in recs], dtype=float)
        bottom = np.zeros(len(recs))
        for stage in STAGES:
            ys = np.array([r["timings"].get(stage, 0.0) for r in recs])
            ax.fill_between(xs, bottom, bottom + ys, step=None, alpha=0.6, label=stage)
            bottom = bottom + ys
        ax.plot(xs, [r["seconds"] for r in recs], "k.-", label="total")
        ax.set_xscale("log")
        ax.set_xlabel(label)
        ax.set_ylabel("seconds")
        mem = ax.twinx()
        mem.plot(xs, [r["peak_gb"] for r in recs], "r^--", label="peak memory")
        mem.set_ylabel("peak memory (GB)", color="r")
        fit = fits.get(fit_key, float("nan"))
        fixed = "probes" if key == "vertices" else "vertices"
        slope_text = f"log-log slope of the time {fit:.2f}" if np.isfinite(fit) else "one bake"
        ax.set_title(f"{scene} against {label} ({fixed} near {int(recs[0][fixed]):,})\n{slope_text}", fontsize=10)
        ax.legend(loc="upper left", fontsize=7)
    for rec in results.get("target") or []:
        fig.suptitle(f"{rec['vertices']:,} vertices, {rec['probes']} probes, {rec['bounces']} bounces: "
                     f"{rec['seconds']:.1f} s, peak {rec['peak_gb']:.2f} GB")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
