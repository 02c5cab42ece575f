"""Render the README's pictures of the demo Room: with EEVEE, without CubeGI (EEVEE's own
lighting) and with CubeGI's baked light wired into the materials (Show in Renders); and the
dynamic-scene sequence, Suzanne (dynamic) moved through the Room and lit from the kept
probe field at each place, side by side (Workbench, the lit colour).

Usage: python scripts/render_docs.py [OUT_DIR] [--dynamic-only]   (default: docs/)
"""

import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def main(out):
    import bpy

    from cubegi_engine.__main__ import load_extension

    load_extension()
    from cubegi.cubegi_addon import demo

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

    from cubegi_engine.__main__ import load_extension

    load_extension()
    from cubegi.cubegi_addon import demo, live

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


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    folder = os.path.abspath(args[0] if args else os.path.join(ROOT, "docs"))
    if "--dynamic-only" not in sys.argv:
        main(folder)
    dynamic_sequence(folder)
