"""The extension's manifest passes Blender's own validator, and the package registers and
unregisters cleanly."""

import os
import subprocess
import sys

import bpy

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_manifest_validates_with_blenders_tool():
    tool = os.path.join(bpy.utils.system_resource("SCRIPTS"), "addons_core", "bl_pkg", "cli", "blender_ext.py")
    r = subprocess.run([sys.executable, tool, "validate", ROOT], capture_output=True, text=True)
    assert r.returncode == 0 and "Success" in r.stdout, r.stdout + r.stderr


def test_unregister_removes_everything_and_register_restores_it(cubegi):
    cubegi.unregister()
    try:
        assert not hasattr(bpy.types.Scene, "cubegi") and not hasattr(bpy.types.Object, "cubegi")
        assert getattr(bpy.types, "CUBEGI_OT_bake", None) is None
        assert getattr(bpy.types, "CUBEGI_PT_bake", None) is None
    finally:
        cubegi.register()
    assert hasattr(bpy.types.Scene, "cubegi")
    assert getattr(bpy.types, "CUBEGI_OT_bake", None) is not None
    assert getattr(bpy.types, "CUBEGI_PT_bake", None) is not None


class _Layout:
    """Records what a panel's draw puts in its layout."""

    def __init__(self):
        self.props, self.operators, self.labels = [], [], []

    def column(self, **_):
        return self

    row = box = column

    def prop(self, data, name, **_):
        self.props.append(name)

    def operator(self, idname, **_):
        self.operators.append(idname)

    def label(self, text="", **_):
        self.labels.append(text)


def test_panel_shows_settings_bake_clear_and_the_last_report(empty_scene, cubegi):
    import scenes

    scenes.closed_box(albedo=0.5, emission=(1.0, 1.0, 1.0))
    panel = bpy.types.CUBEGI_PT_bake
    layout = _Layout()
    panel.draw(type("Panel", (), {"layout": layout})(), bpy.context)
    assert {"cube_size", "bounces", "tolerance", "add_tail", "visibility"} <= set(layout.props)
    assert layout.operators == ["cubegi.bake", "cubegi.clear"] and layout.labels == []
    assert bpy.ops.cubegi.bake(bounces=3, grid=(2, 2, 2)) == {"FINISHED"}
    layout = _Layout()
    panel.draw(type("Panel", (), {"layout": layout})(), bpy.context)
    text = "\n".join(layout.labels)
    assert "3 bounces in" in text and "bounce 3:" in text and "x0.500 of the one before" in text
    assert "estimated missing indirect light after bounce 3: 12.5% (solved, added to CubeGI)" in text
