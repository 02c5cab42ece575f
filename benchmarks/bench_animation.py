"""An animated demo Room (a light moving across it and Suzanne, dynamic, moving through it),
24 frames: CubeGI's animation bake against a full CubeGI bake per frame and a Cycles bake
per frame at CubeGI's error, all in this process.

Run: ``.venv/bin/python benchmarks/bench_animation.py [--frames 24] [--reference-samples 256]``.
Cycles' time at equal error is read off its error-against-time curve on frame 1 (16 and 64
samples, against a reference of ``--reference-samples``), as the main benchmark does.
"""

import argparse
import os
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import numpy as np  # noqa: E402


def animate(bpy, frames, light=True):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, frames
    if light:
        lamp = bpy.data.objects["Lamp A"]
        lamp.location = (0.8, -2.5, 2.5)
        lamp.keyframe_insert("location", frame=1)
        lamp.location = (0.8, 2.5, 2.5)
        lamp.keyframe_insert("location", frame=frames)
    suzanne = bpy.data.objects["Suzanne"]
    suzanne.cubegi.dynamic = True
    suzanne.location = (-1.2, -2.5, 0.6)
    suzanne.keyframe_insert("location", frame=1)
    suzanne.location = (1.2, 3.2, 0.6)
    suzanne.keyframe_insert("location", frame=frames)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--reference-samples", type=int, default=256)
    args = ap.parse_args()

    import bpy

    from tools import load_extension

    load_extension()
    from benchmarks import analysis
    from cubegi.cubegi_addon import animation, attributes, pipeline, reference, scene_data, session
    from cubegi.cubegi_engine import metrics
    from cubegi.cubegi_engine.bake import run
    from cubegi.cubegi_engine.settings import BakeSettings
    from tools import demo

    settings = BakeSettings()
    variants = {}
    for name, light in (("Suzanne moving alone", False), ("Lamp A and Suzanne moving", True)):
        demo.build_room()
        animate(bpy, args.frames, light)
        pipeline.bake(bpy.context, settings)  # compiles the shaders
        session.forget()
        folder = tempfile.mkdtemp(prefix="cubegi-anim-")
        t = time.perf_counter()
        result = run(animation.bake_animation_steps(bpy.context, settings, range(1, args.frames + 1), folder))
        t_anim = time.perf_counter() - t
        paths = result.paths()
        later = [f.seconds for f in result.frames[1:]]
        variants[name] = (t_anim, t_anim / args.frames, float(np.median(later)), paths)

    full = []
    for frame in (1, args.frames // 2, args.frames):
        bpy.context.scene.frame_set(frame)
        session.forget()
        t = time.perf_counter()
        pipeline.bake(bpy.context, settings)
        full.append(time.perf_counter() - t)
    t_full = float(np.mean(full))

    # Cycles at CubeGI's error, on frame 1.
    bpy.context.scene.frame_set(1)
    session.forget()
    pipeline.bake(bpy.context, settings)
    objects = sorted((ob for ob in bpy.context.scene.objects if ob.type == "MESH"), key=lambda ob: ob.name)
    areas = np.concatenate([scene_data.vertex_areas(ob) for ob in objects])

    def stack(values):
        return np.concatenate([values[ob.name] for ob in objects])

    ours = {p: stack({ob.name: attributes.read(ob.data, n) for ob in objects}) for p, n in (("direct", "CubeGI_direct"), ("indirect", "CubeGI"))}
    ref, _ = reference.bake_reference(bpy.context, objects, samples=args.reference_samples, seed=0)
    ref = {p.lower(): stack(v) for p, v in ref.items()}
    err = metrics.compare(ours["direct"], ours["indirect"], ref["direct"], ref["indirect"], areas)["total"]["rel_rmse"]
    records = []
    for k, samples in enumerate((4, 16, 64)):
        baked, seconds = reference.bake_reference(bpy.context, objects, samples=samples, seed=1 + k)
        e = metrics.compare(stack(baked["DIRECT"]), stack(baked["INDIRECT"]), ref["direct"], ref["indirect"], areas)
        records.append({"seconds": sum(seconds.values()), "errors": e, "settings": {"samples": samples}})
    t_cycles, how = analysis.cycles_time_at(err, records, part="total")

    print(f"Room, {args.frames} frames: Suzanne (dynamic, 1980 vertices) moves through the room; Lamp A across it or not")
    print(f"full CubeGI bake of a frame: {t_full * 1000:.0f} ms")
    print(f"CubeGI's total-light error on frame 1 against Cycles at {args.reference_samples} samples: {100 * err:.1f}%")
    for r in records:
        print(f"  Cycles {r['settings']['samples']:3d} samples: {r['seconds']:.2f} s, total error {100 * r['errors']['total']['rel_rmse']:.1f}%")
    print(f"Cycles at CubeGI's error: {t_cycles:.2f} s a frame ({how})")
    for name, (t_anim, per_frame, median, paths) in variants.items():
        print(f"{name}: {t_anim:.2f} s, {per_frame * 1000:.0f} ms a frame (after the first: {median * 1000:.0f} ms median; "
              f"paths {paths}); {t_full / per_frame:.1f}x a full bake per frame, {t_cycles / per_frame:.1f}x Cycles")


if __name__ == "__main__":
    main()
