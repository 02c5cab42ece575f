"""Speed of the demo Room bake: capture, direct light, each bounce by its parts, total.

Run: ``.venv/bin/python benchmarks/bench_room.py [--repeat 3]``. The first bake of a process
also pays for bringing up the GPU module and compiling shaders; it is reported apart. Every
timed bake starts without a kept capture (a full bake); then a re-bake after a light edit,
which reuses the kept capture, is timed against it. Last, the same bounces are computed the
paper's way (draw the lit scene into every probe's cube map again each bounce) in the same
process, and the speed is given as a ratio.
"""

import argparse
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import numpy as np  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--bounces", type=int, default=5)
    args = ap.parse_args()

    import bpy

    from tools import load_extension

    load_extension()
    from cubegi.cubegi_addon import gpu_capture, grid_objects, pipeline, scene_data, session
    from cubegi.cubegi_engine import capture, cubemap
    from cubegi.cubegi_engine.settings import BakeSettings
    from tools import demo

    demo.build_room()
    settings = BakeSettings(cube_size=32, bounces=args.bounces)

    t = time.perf_counter()
    gpu_capture.ensure_gpu()
    print(f"GPU module start-up (once per process): {time.perf_counter() - t:.3f} s")
    reports = []
    for k in range(args.repeat + 1):
        session.forget()
        rep = pipeline.bake(bpy.context, settings)
        if k == 0:
            print(f"first bake (compiles shaders): {rep.timings['total']:.3f} s")
            continue
        reports.append(rep)
    best = min(reports, key=lambda r: r.timings["total"])
    tm = best.timings
    print(f"Room: {best.triangles} triangles, {best.points} shading points, "
          f"{best.grid.probes} probes {tuple(best.grid.resolution)}, cube 32, {args.bounces} bounces")
    print(f"best of {args.repeat}:")
    for key in ("collect", "gpu_setup", "capture", "tables", "direct_lights", "direct_probes", "bounces", "tail", "write", "total"):
        print(f"  {key:14s} {tm[key] * 1000:8.1f} ms")
    for b in best.bounces:
        print(f"  bounce {b.bounce}: {b.seconds * 1000:6.2f} ms = gather and project {b.gather_seconds * 1000:.2f} + "
              f"interpolate {b.interpolate_seconds * 1000:.2f}")

    # A light edit: the next bake reuses the kept capture (same process, same scene).
    rebakes = []
    for _ in range(args.repeat):
        bpy.data.lights[0].energy *= 1.1
        rep = pipeline.bake(bpy.context, settings)
        assert rep.capture_reused
        rebakes.append(rep.timings["total"])
    print(f"re-bake after a light edit (capture kept): {min(rebakes) * 1000:.1f} ms, "
          f"{min(rebakes) / tm['total']:.2f}x the full bake")

    # The paper's way, same process: draw every probe's cube map with the lit colours.
    arrays = scene_data.collect(bpy.context).arrays
    grid, _, _ = grid_objects.resolve_grid(bpy.context.scene, arrays)
    renderer = gpu_capture.GpuRenderer(arrays.points, arrays.triangles)
    near, far = cubemap.clip_planes(arrays.scale)
    radiance = np.asarray(arrays.albedo) * 0.5
    capture.reference_coefficients(renderer, grid, arrays, radiance, 32, near, far)  # warm-up
    t = time.perf_counter()
    for _ in range(args.bounces):
        capture.reference_coefficients(renderer, grid, arrays, radiance, 32, near, far)
    drawn = (time.perf_counter() - t) / args.bounces
    per_bounce = tm["bounces"] / max(args.bounces, 1)
    print(f"paper's way (draw + read back + project per bounce): {drawn * 1000:.1f} ms per bounce, "
          f"{drawn / per_bounce:.0f}x the capture-once bounce ({per_bounce * 1000:.1f} ms)")


if __name__ == "__main__":
    main()
