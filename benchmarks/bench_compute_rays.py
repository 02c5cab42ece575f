"""Rays through the GPU module's compute shader against Blender's BVH tree, same process.

Run: ``.venv/bin/python benchmarks/bench_compute_rays.py [--rays 262144] [--triangles 100000]``.
Casts the same rays, towards a narrow cone as a sun's disk asks (shadow rays: ``blocked``)
and in all directions (nearest hits: ``cast``), at random triangles, with
``mathutils.bvhtree`` (:class:`~cubegi_addon.bvh_rays.BvhRays`) and with the tree of boxes
walked by a compute shader (:class:`~cubegi_addon.gpu_rays.GpuRays`, on llvmpipe's threads
where there is no GPU). Prints each one's rays a second, the ratio, and how many answers
differ.
"""

import argparse
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rays", type=int, default=1 << 18)
    ap.add_argument("--triangles", type=int, default=100_000)
    args = ap.parse_args()

    import bpy
    import gpu
    import numpy as np

    from tools import load_extension

    cubegi = load_extension()
    cubegi.cubegi_addon.gpu_capture.ensure_gpu()
    from cubegi.cubegi_addon.bvh_rays import BvhRays
    from cubegi.cubegi_addon.gpu_rays import GpuRays

    rng = np.random.default_rng(0)
    centres = rng.random((args.triangles, 1, 3)) * [8.0, 8.0, 3.0]
    corners = centres + rng.normal(scale=0.05, size=(args.triangles, 3, 3))
    points, triangles = corners.reshape(-1, 3), np.arange(3 * args.triangles).reshape(-1, 3)
    origins = rng.random((args.rays, 3)) * [8.0, 8.0, 3.0]
    towards_sun = np.tile([0.3, 0.2, 1.0], (args.rays, 1)) + rng.normal(scale=0.01, size=(args.rays, 3))
    anywhere = rng.normal(size=(args.rays, 3))
    print(f"bpy {bpy.app.version_string}, {gpu.platform.renderer_get()}: {args.rays:,} rays, {args.triangles:,} triangles")
    t = time.perf_counter()
    tree = BvhRays(points, triangles)
    tree_build = time.perf_counter() - t
    t = time.perf_counter()
    shader = GpuRays(points, triangles)
    shader_build = time.perf_counter() - t
    print(f"built: Blender's tree {tree_build:.2f} s, the tree of boxes {shader_build:.2f} s")
    shader.blocked(origins[:64], anywhere[:64] / np.linalg.norm(anywhere[:64], axis=1, keepdims=True))  # (compile, upload)
    for name, dirs in (("shadow rays towards a sun", towards_sun), ("nearest hits, any direction", anywhere)):
        dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        times, answers = [], []
        for caster in (tree, shader):
            t = time.perf_counter()
            answers.append(caster.blocked(origins, dirs) if "shadow" in name else caster.cast(origins, dirs, 2.0).triangle)
            times.append(time.perf_counter() - t)
        print(f"{name}: Blender's tree {times[0]:.2f} s ({args.rays / times[0] / 1e6:.2f}M a second), the shader "
              f"{times[1]:.2f} s ({args.rays / times[1] / 1e6:.2f}M a second), {times[0] / times[1]:.1f}x; "
              f"{int((answers[0] != answers[1]).sum())} answers differ")
    if shader._fallback is not None:
        print("the shader could not run here: every ray above went through Blender's tree")


if __name__ == "__main__":
    main()
