"""Render the README's pictures of the demo Room: with EEVEE, without CubeGI (EEVEE's own
lighting) and with CubeGI's baked light wired into the materials (Show in Renders); and the
dynamic-scene sequence, Suzanne (dynamic) moved through the Room and lit from the kept
probe field at each place, side by side (Workbench, the lit colour); and the error picture,
each vertex's indirect error against Cycles coloured, without and with the near field.

Usage: python scripts/render_docs.py [OUT_DIR] [--dynamic-only | --error-only | --breakfast-only]   (default: docs/)
"""

import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def main(out):
    import bpy

    from tools import load_extension

    load_extension()
    from tools import demo

    demo.build_room()
    scene = bpy.context.scene
    scene.render.engine = "BLENDER_EEVEE"
    scene.eevee.taa_render_samples = 16
    scene.render.resolution_x, scene.render.resolution_y = 800, 450
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "PNG"
    os.makedirs(out, exist_ok=True)
    for name, wired in (("room_eevee_without.png", False), ("room_eevee_with_cubegi.png", True)):
        if wired:
            assert bpy.ops.cubegi.bake(bounces=5) == {"FINISHED"}
            assert bpy.ops.cubegi.wire_materials() == {"FINISHED"}
        scene.render.filepath = os.path.join(out, name)
        t = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        print(f"render_docs: {scene.render.filepath} in {time.perf_counter() - t:.1f} s", flush=True)


# Where Suzanne stands in the sequence: on the red table, low over the carpet near the
# light, by the white side wall, in the darker far end (the paper's Figure 3 moves its bunny
# the same way).
PLACES = ((0.0, -0.5, 1.15), (0.8, -1.7, 0.4), (-1.55, -1.0, 1.3), (1.2, 2.6, 0.45))


def dynamic_sequence(out):
    """Suzanne, dynamic, at each of PLACES: one update each, rendered and tiled."""
    import bpy
    import numpy as np

    from tools import load_extension

    load_extension()
    from cubegi.cubegi_addon import live
    from tools import demo

    demo.build_room()
    scene = bpy.context.scene
    suzanne = bpy.data.objects["Suzanne"]
    suzanne.cubegi.dynamic = True
    suzanne.scale = (0.4, 0.4, 0.4)
    suzanne.rotation_euler = (0.0, 0.0, 0.0)  # facing the camera
    scene.cubegi.lit = "ALL"
    cam = scene.camera
    cam.location, cam.rotation_euler = (0.0, -4.4, 1.4), (np.radians(80), 0.0, 0.0)
    cam.data.lens = 18
    assert bpy.ops.cubegi.bake() == {"FINISHED"}
    tiles = []
    for k, place in enumerate(PLACES):
        suzanne.location = place
        report = live.update(bpy.context)
        print(f"render_docs: Suzanne at {place}: {report.line()}", flush=True)
        path = os.path.join(out, f"_dynamic_{k}.png")
        demo.render_png(path, attribute="CubeGI_lit", resolution=(400, 300))
        image = bpy.data.images.load(path)
        px = np.empty(400 * 300 * 4, dtype=np.float32)
        image.pixels.foreach_get(px)
        bpy.data.images.remove(image)
        os.remove(path)
        tiles.append(px.reshape(300, 400, 4))
    strip = np.concatenate(tiles, axis=1)
    image = bpy.data.images.new("dynamic", strip.shape[1], strip.shape[0], alpha=True)
    image.pixels.foreach_set(strip.ravel())
    image.filepath_raw = os.path.join(out, "dynamic_suzanne.png")
    image.file_format = "PNG"
    image.save()
    print(f"render_docs: {image.filepath_raw}", flush=True)


def _tile(paths, out_path, size):
    """Put the PNGs ``paths`` side by side into ``out_path`` and remove them."""
    import bpy
    import numpy as np

    w, h = size
    tiles = []
    for path in paths:
        image = bpy.data.images.load(path)
        px = np.empty(w * h * 4, dtype=np.float32)
        image.pixels.foreach_get(px)
        bpy.data.images.remove(image)
        os.remove(path)
        tiles.append(px.reshape(h, w, 4))
    strip = np.concatenate(tiles, axis=1)
    image = bpy.data.images.new("tiles", strip.shape[1], strip.shape[0], alpha=True)
    image.pixels.foreach_set(strip.ravel())
    image.filepath_raw = out_path
    image.file_format = "PNG"
    image.save()
    print(f"render_docs: {out_path}", flush=True)


def error_picture(out, samples=1024):
    """The Room's per-vertex indirect error against a Cycles bake (``samples``; the
    benchmark's cached reference when there is one), without the near field (before) and
    with it (after), the carpet hidden to show the floor under it: black none, red the
    scene's mean indirect light or more too bright, blue as much too dark."""
    import bpy
    import numpy as np

    from tools import load_extension

    load_extension()
    from cubegi.cubegi_addon import attributes, reference, session
    from tools import demo

    demo.build_room()
    objects = sorted((ob for ob in bpy.context.scene.objects if ob.type == "MESH"), key=lambda ob: ob.name)
    cache = os.path.join(ROOT, "out", "benchmark", "cache", f"room-cycles-{samples}spp.npz")
    if os.path.exists(cache):  # the benchmark's reference, stacked over the meshes by name
        stacked = np.load(cache)["indirect"]
        ends = np.cumsum([len(ob.data.vertices) for ob in objects])
        ref = {"INDIRECT": {ob.name: part for ob, part in zip(objects, np.split(stacked, ends[:-1]))}}
    else:
        ref, _ = reference.bake_reference(bpy.context, objects, passes=("INDIRECT",), samples=samples, seed=0)
    mean = float(np.mean(np.concatenate([ref["INDIRECT"][ob.name] for ob in objects])))
    paths = []
    for k, near in enumerate((False, True)):
        session.forget()
        assert bpy.ops.cubegi.bake(bounces=5, near_field=near) == {"FINISHED"}
        for ob in objects:
            e = (attributes.read(ob.data, "CubeGI") - ref["INDIRECT"][ob.name]).mean(axis=1) / mean
            colour = np.zeros((len(e), 3))
            colour[:, 0], colour[:, 2] = np.clip(e, 0, 1), np.clip(-e, 0, 1)
            attributes.put(ob.data, "CubeGI_error", colour)
        paths.append(os.path.join(out, f"_error_{k}.png"))
        bpy.data.objects["Carpet"].hide_render = True  # for the picture only: the bakes see it
        demo.render_png(paths[-1], attribute="CubeGI_error", resolution=(480, 270))
        bpy.data.objects["Carpet"].hide_render = False
    _tile(paths, os.path.join(out, "room_indirect_error.png"), (480, 270))


def breakfast_error_picture(out, samples=256):
    """The Breakfast Room's per-vertex error of the default bake against Cycles (the
    benchmark's cached reference, ``out/benchmark/cache``, else baked: about 2.6 s a sample
    here), direct light left, indirect right, seen from the scene's camera: black none, red
    the scene's mean light (of that kind, over its surface) or more too bright, blue as much
    too dark. Credit:
    The Breakfast Room by Wig42, converted by Benedikt Bitterli (CC BY 3.0)."""
    import bpy
    import numpy as np

    from tools import load_extension

    load_extension()
    from benchmarks import public_scenes
    from cubegi.cubegi_addon import attributes, reference, scene_data, session
    from tools import demo

    public_scenes.breakfast_room()
    objects = sorted((ob for ob in bpy.context.scene.objects if ob.type == "MESH"), key=lambda ob: ob.name)
    public_scenes.breakfast_camera()
    cache = os.path.join(ROOT, "out", "benchmark", "cache", f"breakfast_room-cycles-{samples}spp.npz")
    if os.path.exists(cache):
        data = np.load(cache)
        ends = np.cumsum([len(ob.data.vertices) for ob in objects])
        ref = {part.upper(): {ob.name: p for ob, p in zip(objects, np.split(data[part], ends[:-1]))} for part in ("direct", "indirect")}
    else:
        ref, _ = reference.bake_reference(bpy.context, objects, samples=samples, seed=0)
    session.forget()
    assert bpy.ops.cubegi.bake() == {"FINISHED"}
    bpy.context.scene.render.film_transparent = True  # the sky seen through the window: no error drawn
    paths = []
    areas = {ob.name: scene_data.vertex_areas(ob) for ob in objects}
    for k, (part, name) in enumerate((("DIRECT", attributes.DIRECT), ("INDIRECT", attributes.INDIRECT))):
        # The mean over the surface (as the benchmark's errors weigh it), not over vertices: the
        # chairs' and the china's many dim vertices would make a wall's few per cent look large.
        mean = sum(areas[ob.name] @ ref[part][ob.name].mean(axis=1) for ob in objects) / sum(a.sum() for a in areas.values())
        for ob in objects:
            e = (attributes.read(ob.data, name) - ref[part][ob.name]).mean(axis=1) / mean
            colour = np.zeros((len(e), 3))
            colour[:, 0], colour[:, 2] = np.clip(e, 0, 1), np.clip(-e, 0, 1)
            attributes.put(ob.data, "CubeGI_error", colour)
        paths.append(os.path.join(out, f"_error_{k}.png"))
        demo.render_png(paths[-1], attribute="CubeGI_error", resolution=(640, 360))
    _tile(paths, os.path.join(out, "public-scenes", "breakfast_room_error.png"), (640, 360))


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    folder = os.path.abspath(args[0] if args else os.path.join(ROOT, "docs"))
    if "--breakfast-only" in sys.argv:
        breakfast_error_picture(folder)
    elif "--error-only" in sys.argv:
        error_picture(folder)
    else:
        if "--dynamic-only" not in sys.argv:
            main(folder)
        dynamic_sequence(folder)
        error_picture(folder)
