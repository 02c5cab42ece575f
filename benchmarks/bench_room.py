"""Speed of the demo Room bake: capture, direct light, each bounce by its parts, total.

Run: ``.venv/bin/python benchmarks/bench_room.py [--repeat 3]``. The first bake of a process
also pays for bringing up the GPU module and compiling shaders; it is reported apart. Then
the same bounces are computed the paper's way (draw the lit scene into every probe's cube
map again each bounce) in the same process, and the speed is given as a ratio.
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
    from cubegi_engine.bake import BakeSettings, run
    from cubegi_engine import transport
    from cubegi_engine.cli import load_extension

    ext = load_extension()
    addon = ext.cubegi_addon
    import importlib

    demo = importlib.import_module("cubegi.cubegi_addon.demo")
    demo.build_room()
    settings = BakeSettings(cube_size=32, bounces=args.bounces)

    t = time.perf_counter()
    addon.gpu_capture.ensure_gpu()
    print(f"GPU module start-up (once per process): {time.perf_counter() - t:.3f} s")
    reports = []
    for k in range(args.repeat + 1):
        rep = run(addon.pipeline.bake_steps(bpy.context, settings))
        if k == 0:
            print(f"first bake (compiles shaders): {rep['timings']['total']:.3f} s")
            continue
        reports.append(rep)
    best = min(reports, key=lambda r: r["timings"]["total"])
    tm = best["timings"]
    print(f"Room: {best['scene']['triangles']} triangles, {best['scene']['points']} shading points, "
          f"{best['grid']['probes']} probes {tuple(best['grid']['resolution'])}, cube 32, {args.bounces} bounces")
    print(f"best of {args.repeat}:")
    for key in ("collect", "gpu_setup", "capture", "tables", "direct_lights", "direct_probes", "bounces", "tail", "write", "total"):
        print(f"  {key:14s} {tm[key] * 1000:8.1f} ms")
    for b in best["bounces"]:
        print(f"  bounce {b['bounce']}: {b['seconds'] * 1000:6.2f} ms = gather {b['gather_seconds'] * 1000:.2f} + "
              f"project {b['project_seconds'] * 1000:.2f} + interpolate {b['interpolate_seconds'] * 1000:.2f}")

    # The paper's way, same process: draw every probe's cube map with the lit colours.
    collected = addon.scene_data.collect(bpy.context)
    arrays = collected.arrays
    grid, _, _ = addon.pipeline.resolve_grid(bpy.context.scene, arrays)
    renderer = addon.gpu_capture.GpuRenderer(arrays.points, arrays.triangles)
    near, far = transport.clip_planes(arrays.scale)
    radiance = np.asarray(arrays.albedo) * 0.5
    transport.reference_coefficients(renderer, grid, arrays, radiance, 32, near, far)  # warm-up
    t = time.perf_counter()
    for _ in range(args.bounces):
        transport.reference_coefficients(renderer, grid, arrays, radiance, 32, near, far)
    drawn = (time.perf_counter() - t) / args.bounces
    per_bounce = tm["bounces"] / max(args.bounces, 1)
    print(f"paper's way (draw + read back + project per bounce): {drawn * 1000:.1f} ms per bounce, "
          f"{drawn / per_bounce:.0f}x the capture-once bounce ({per_bounce * 1000:.1f} ms)")


if __name__ == "__main__":
    main()
