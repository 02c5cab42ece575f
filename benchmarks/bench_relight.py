"""Updates on the kept capture against a full bake, same process, the demo Room.

Run: ``.venv/bin/python benchmarks/bench_relight.py [--repeat 5]``. Prints, best of the
repeats: a full bake (no kept capture), a power or colour edit (instant: the weighted sum and
the direct, indirect, total and lit layers; settled: the energy balance of the new mix and
every layer), a moved light (its shadow map drawn again, all bounces in one solve), a
material colour edit (the bounce operator rebuilt), each with its share of the full bake;
then Suzanne made dynamic and moved (its direct light with shadows and its light from the
probe field), and the probe field's light at 10,000 points (indirect alone; direct and
indirect together).
"""

import argparse
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def best(fn, repeat):
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()

    import bpy

    from tools import load_extension

    load_extension()
    from cubegi.cubegi_addon import live, pipeline, session
    from cubegi.cubegi_engine.settings import BakeSettings
    from tools import demo

    demo.build_room()
    settings = BakeSettings(cube_size=32, bounces=5)
    pipeline.bake(bpy.context, settings)  # compiles the shaders

    def full():
        session.forget()
        return pipeline.bake(bpy.context, settings)

    t_full, rep = best(full, args.repeat)
    t = time.perf_counter()
    live.state_of(bpy.context).live.light  # noqa: B018 - builds the operator, once per capture
    t_build = time.perf_counter() - t
    lamp = bpy.data.lights["Lamp A"]

    def power(settle):
        def run():
            lamp.energy *= 1.01
            return live.update(bpy.context, settle=settle)
        return run

    t_instant, u = best(power(False), args.repeat)
    assert u.route == "weights"
    engine = sum(v for k, v in u.seconds.items() if k != "write")
    t_settled, u = best(power(True), args.repeat)
    ob = bpy.data.objects["Lamp A"]

    def move():
        ob.location.x += 0.05
        return live.update(bpy.context)

    t_move, u_move = best(move, args.repeat)
    assert u_move.route == "lights"
    carpet = bpy.data.materials["Carpet"].node_tree.nodes["Principled BSDF"].inputs["Base Color"]

    def recolour():
        carpet.default_value = (carpet.default_value[0] * 0.99, 0.12, 0.06, 1.0)
        return live.update(bpy.context, materials=True)

    t_albedo, u_albedo = best(recolour, max(2, args.repeat // 2))
    print(f"Room: {rep.points} shading points, {rep.grid.probes} probes, cube 32, {len(rep.bounces)} bounces + tail")
    print(f"full bake (capture included)      {t_full * 1000:8.1f} ms")
    print(f"operator built from the bake      {t_build * 1000:8.1f} ms (once per capture)")
    rows = [
        ("power edit, instant", t_instant, f"engine {engine * 1000:.2f} ms + writing 4 layers"),
        ("power edit, settled", t_settled, "energy balance of the new mix, every layer"),
        ("moved light", t_move, f"its shadow map {u_move.seconds['lights'] * 1000:.0f} ms, solve {u_move.seconds['solve'] * 1000:.0f} ms"),
        ("material colour edit", t_albedo,
         f"read the scene {u_albedo.seconds['lights'] * 1000:.0f} ms, solve {u_albedo.seconds['solve'] * 1000:.0f} ms"),
    ]
    for name, seconds, note in rows:
        print(f"{name:33s} {seconds * 1000:8.1f} ms  {100 * seconds / t_full:5.1f}% of the full bake  ({note})")
    dynamic_object(bpy, settings, args.repeat)


def dynamic_object(bpy, settings, repeat):
    """Suzanne dynamic: a move lit from the kept field and shadow maps; the field alone at
    10,000 points."""
    import numpy as np

    from cubegi.cubegi_addon import live, pipeline, session

    suzanne = bpy.data.objects["Suzanne"]
    suzanne.cubegi.dynamic = True
    session.forget()
    pipeline.bake(bpy.context, settings)
    verts = len(suzanne.data.vertices)

    def move():
        suzanne.location.x += 0.02
        return live.update(bpy.context)

    t_move, u = best(move, repeat)
    assert u.route == "dynamic"
    field = session.kept(bpy.context.scene).live.field
    rng = np.random.default_rng(0)
    lo, hi = field.grid.positions().min(axis=0), field.grid.positions().max(axis=0)
    pts = lo + rng.random((10_000, 3)) * (hi - lo)
    nrm = rng.normal(size=(10_000, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    t_ind, _ = best(lambda: field.light_at(pts, nrm, part="indirect", one_sided=True), 5 * repeat)
    t_both, _ = best(lambda: field.light_parts(pts, nrm, ("direct", "indirect"), one_sided=True), 5 * repeat)
    print(f"dynamic Suzanne ({verts} vertices) moved   {t_move * 1000:8.1f} ms  (direct with shadows, field, 3 layers written)")
    print(f"probe field, 10,000 points: indirect {t_ind * 1000:.2f} ms; direct and indirect together {t_both * 1000:.2f} ms")


if __name__ == "__main__":
    main()
