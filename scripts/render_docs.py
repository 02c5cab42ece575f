"""Render the README's pictures of the demo Room with EEVEE: without CubeGI (EEVEE's own
lighting) and with CubeGI's baked light wired into the materials (Show in Renders).

Usage: python scripts/render_docs.py [OUT_DIR]   (default: docs/)
"""

import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def main(out):
    import bpy

    from cubegi_engine.cli import PACKAGE, load_extension

    load_extension()
    demo = __import__(f"{PACKAGE}.cubegi_addon.demo", fromlist=["demo"])
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


if __name__ == "__main__":
    main(os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "docs")))
