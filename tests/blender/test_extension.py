"""The extension's manifest passes Blender's own validator; the built zip installs, bakes and
uninstalls."""

import os
import subprocess
import sys

import bpy
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.mark.smoke
def test_manifest_validates_with_blenders_tool():
    tool = os.path.join(bpy.utils.system_resource("SCRIPTS"), "addons_core", "bl_pkg", "cli", "blender_ext.py")
    r = subprocess.run([sys.executable, tool, "validate", ROOT], capture_output=True, text=True)
    assert r.returncode == 0 and "Success" in r.stdout, r.stdout + r.stderr


INSTALLED_BAKE = r"""
import os, sys
import bpy
import numpy as np

zip_path = sys.argv[1]
bpy.ops.wm.read_factory_settings(use_empty=True)
assert bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True) == {"FINISHED"}
import bl_ext.user_default.cubegi as installed
where = os.path.dirname(installed.__file__)
assert where.startswith(os.environ["BLENDER_USER_RESOURCES"]), where
assert not os.path.exists(os.path.join(where, "tests")) and os.path.exists(os.path.join(where, "cubegi_engine", "sh.py"))
assert "bl_ext.user_default.cubegi" in bpy.context.preferences.addons
bpy.ops.mesh.primitive_cube_add(size=2.0)
box = bpy.context.object
box.name = "Box"
bpy.ops.object.mode_set(mode="EDIT")
bpy.ops.mesh.flip_normals()  # a closed room seen from inside
bpy.ops.object.mode_set(mode="OBJECT")
light = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
light.data.energy = 10.0
light.location = (0.3, -0.2, 0.4)
bpy.context.scene.collection.objects.link(light)
assert bpy.ops.cubegi.bake(bounces=2, cube_size=8, grid=(2, 2, 2)) == {"FINISHED"}
assert bpy.types.CUBEGI_OT_bake.__module__.startswith("bl_ext.user_default.cubegi")
mesh = bpy.data.objects["Box"].data
values = np.empty(len(mesh.vertices) * 4, dtype=np.float32)
mesh.attributes["CubeGI"].data.foreach_get("color", values)
assert np.isfinite(values).all() and values.reshape(-1, 4)[:, :3].mean() > 0
prefs = bpy.context.preferences.addons["bl_ext.user_default.cubegi"].preferences
assert tuple(prefs.grid_resolution) == (4, 4, 2)
# ``blender -c cubegi ...``: the command the extension registers, called as Blender calls it
# (its execute function, with the words after the command's name).
saved, baked = os.path.join(sys.argv[2], "in.blend"), os.path.join(sys.argv[2], "cli.blend")
bpy.ops.wm.save_as_mainfile(filepath=saved)
command = installed.cubegi_addon.command
assert command.execute(["bake", saved, "-o", baked, "--bounces", "2", "--cube-size", "8"]) == 0
assert command.execute(["bake", saved, "-o", saved]) == 2  # refused in one line, the input untouched
assert command.execute(["demo"]) == 2  # the demo runs from the source tree only
bpy.ops.wm.open_mainfile(filepath=baked)
values = np.empty(len(bpy.data.objects["Box"].data.vertices) * 4, dtype=np.float32)
bpy.data.objects["Box"].data.attributes["CubeGI"].data.foreach_get("color", values)
assert np.isfinite(values).all() and values.reshape(-1, 4)[:, :3].mean() > 0
repo_index = next(i for i, r in enumerate(bpy.context.preferences.extensions.repos) if r.module == "user_default")
assert bpy.ops.extensions.package_uninstall(repo_index=repo_index, pkg_id="cubegi") == {"FINISHED"}
assert not os.path.exists(where), where
assert getattr(bpy.types, "CUBEGI_OT_bake", None) is None and not hasattr(bpy.types.Scene, "cubegi")
print("INSTALLED-BAKE-OK", where)
"""


@pytest.mark.smoke
def test_the_built_zip_installs_bakes_and_uninstalls(tmp_path):
    """``scripts/build.sh`` makes the zip with no Blender, bpy or virtual environment (a bare
    PATH): file for file what Blender's own tool builds from the same manifest, without the
    dev files. Blender installs it into a temporary user folder, the installed copy bakes,
    and uninstalling removes it all."""
    r = subprocess.run(["bash", os.path.join(ROOT, "scripts", "build.sh"), str(tmp_path / "dist")], capture_output=True,
                       text=True, env={"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)})
    assert r.returncode == 0, r.stderr
    zip_path = r.stdout.strip().splitlines()[-1]
    assert os.path.basename(zip_path) == "cubegi-0.1.0.zip"
    import zipfile

    tool = os.path.join(bpy.utils.system_resource("SCRIPTS"), "addons_core", "bl_pkg", "cli", "blender_ext.py")
    (tmp_path / "blender").mkdir()
    subprocess.run([sys.executable, tool, "build", "--source-dir", ROOT, "--output-dir", str(tmp_path / "blender")], check=True,
                   capture_output=True)
    ours, blenders = zipfile.ZipFile(zip_path), zipfile.ZipFile(tmp_path / "blender" / "cubegi-0.1.0.zip")
    names = ours.namelist()
    assert sorted(names) == sorted(blenders.namelist())
    assert all(ours.read(n) == blenders.read(n) for n in names)
    assert "blender_manifest.toml" in names and "cubegi_engine/sh.py" in names and "cubegi_addon/operators.py" in names
    # Run from the source tree only, each in a folder the manifest leaves out whole: the demo and the
    # source tree's command line (tools), the benchmarks and their scenes.
    assert not [n for n in names if n.split("/")[0] in {"tests", "scripts", "tools", "benchmarks", "docs", ".ci", ".git"}]
    assert {n.split("/")[0] for n in names if "/" in n} == {"cubegi_addon", "cubegi_engine"}, names
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "user"))
    r = subprocess.run(
        [sys.executable, "-c", INSTALLED_BAKE, zip_path, str(tmp_path)],
        capture_output=True, text=True, env=env, timeout=300,
    )
    assert r.returncode == 0 and "INSTALLED-BAKE-OK" in r.stdout, r.stdout[-3000:] + r.stderr[-3000:]
