"""What outlives a bake: the kept capture is reused when the geometry is unchanged and gives
what a fresh bake gives; a geometry change takes a new capture; the kept parts are freed on
file load and bounded in memory; the probe field lights points the way the bake does; and
``python -m cubegi_engine`` holds one copy of every module."""

import json
import os
import subprocess
import sys

import bpy
import numpy as np
import pytest
import scenes

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# Reusing a capture runs the same float32 arithmetic on the same tables: equal to the bit on
# one machine; a millionth of the peak allows for summation order elsewhere.
REUSE_TOL = 1e-6
SETTINGS = dict(grid=(3, 3, 2), cube_size=8, bounces=3)


def _light(names=("CubeGI_direct", "CubeGI", "CubeGI_total")):
    read = __import__("cubegi").cubegi_addon.attributes.read
    return {(ob.name, n): read(ob.data, n) for ob in bpy.context.scene.objects if ob.type == "MESH" for n in names}


def _report():
    return json.loads(bpy.context.scene.cubegi.last_report)


@pytest.fixture
def cornell(empty_scene, cubegi):
    scenes.cornell(light=True)
    return cubegi


def test_a_light_edit_reuses_the_capture_and_equals_a_fresh_bake(cornell):
    session = cornell.cubegi_addon.session
    assert bpy.ops.cubegi.bake(**SETTINGS) == {"FINISHED"} and not _report()["capture_reused"]
    assert session.kept(bpy.context.scene) is not None
    bpy.data.lights[0].energy *= 1.7
    bpy.data.materials["Red"].node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.2, 0.6, 0.9, 1)
    assert bpy.ops.cubegi.bake(**SETTINGS) == {"FINISHED"}
    rep = _report()
    assert rep["capture_reused"] and rep["timings"]["capture"] == 0.0 and "capture reused" in "\n".join(
        cornell.cubegi_engine.report.BakeReport.from_dict(rep).summary_lines())
    reused = _light()
    session.forget()
    assert bpy.ops.cubegi.bake(**SETTINGS) == {"FINISHED"} and not _report()["capture_reused"]
    fresh = _light()
    peak = max(v.max() for v in fresh.values())
    for key in fresh:
        np.testing.assert_allclose(reused[key], fresh[key], rtol=0, atol=REUSE_TOL * peak, err_msg=str(key))


def test_a_geometry_edit_or_new_settings_take_a_new_capture(cornell):
    assert bpy.ops.cubegi.bake(**SETTINGS) == {"FINISHED"}
    bpy.data.objects["Tall"].location.x += 0.1
    assert bpy.ops.cubegi.bake(**SETTINGS) == {"FINISHED"} and not _report()["capture_reused"]
    kept = cornell.cubegi_addon.session.kept(bpy.context.scene)
    old = kept.bake.result.capture
    # The moved object is what changed, and some probes see it.
    arrays = cornell.cubegi_addon.scene_data.collect(bpy.context).arrays
    assert arrays.fingerprint().changed(old.fingerprint) == set()
    tall = arrays.object_names.index("Tall")
    sees = old.probes_seeing([tall])
    assert 0 < sees.sum() <= len(sees)
    assert bpy.ops.cubegi.bake(**dict(SETTINGS, cube_size=16)) == {"FINISHED"} and not _report()["capture_reused"]
    assert bpy.ops.cubegi.bake(**dict(SETTINGS, cube_size=16)) == {"FINISHED"} and _report()["capture_reused"]


def test_kept_bakes_are_freed_on_file_load_and_bounded(cornell, tmp_path, monkeypatch):
    session = cornell.cubegi_addon.session
    assert bpy.ops.cubegi.bake(**SETTINGS) == {"FINISHED"}
    kept = session.kept(bpy.context.scene)
    assert kept is not None and 0 < kept.nbytes == session.kept_bytes()
    path = tmp_path / "c.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.open_mainfile(filepath=str(path))
    assert session.kept(bpy.context.scene) is None and session.kept_bytes() == 0
    monkeypatch.setattr(session, "budget", lambda: kept.nbytes // 2)
    assert bpy.ops.cubegi.bake(**SETTINGS) == {"FINISHED"}
    assert session.kept(bpy.context.scene) is None  # too large for the budget: not kept
    assert bpy.ops.cubegi.clear() == {"FINISHED"}


def test_the_probe_field_lights_the_scenes_points_as_the_bake_does(cornell):
    """With plain trilinear weights (no visibility, no near field) the field at the scene's
    own points is the bake's light from the probes: the indirect light. Deringing each bounce apart or
    their sum differs slightly where a probe rings."""
    assert bpy.ops.cubegi.bake(grid=(3, 3, 3), cube_size=16, bounces=4, visibility=False, near_field=False) == {"FINISHED"}
    kept = cornell.cubegi_addon.session.kept(bpy.context.scene)
    field, result = kept.bake.result.field, kept.bake.result
    at_points = field.light_at(kept.bake.arrays.points, kept.bake.arrays.normals)
    indirect = result.indirect
    areas = kept.bake.arrays.point_areas()
    mean = float((indirect * areas[:, None]).sum() / areas.sum())
    rel_rmse = np.sqrt(((at_points - indirect) ** 2 * areas[:, None]).sum() / areas.sum() / 3) / mean
    assert rel_rmse < 0.02, rel_rmse  # measured 0.3%


def test_the_command_line_holds_one_copy_of_every_module(empty_scene, tmp_path):
    v, f = scenes.box_mesh((-1, -1, 0), (1, 1, 2), (2, 2, 2), inward=True)
    scenes.mesh_object("Box", v, f)
    scenes.add_light("POINT", (0, 0, 1), 20.0)
    src = tmp_path / "in.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(src))
    code = f"""
import json, os, runpy, sys
sys.argv = ["cubegi_engine", "bake", {str(src)!r}, "-o", {str(tmp_path / 'out.blend')!r}, "--grid", "2", "2", "2", "--bounces", "1"]
try:
    runpy.run_module("cubegi_engine", run_name="__main__", alter_sys=True)
except SystemExit as stop:
    status = stop.code
copies = {{}}
for name, module in list(sys.modules.items()):
    path = getattr(module, "__file__", None)
    if path and os.path.realpath(path).startswith({ROOT!r} + os.sep) and "site-packages" not in path:
        copies.setdefault(os.path.realpath(path), set()).add(id(module))
import cubegi.cubegi_engine.settings as a, cubegi.cubegi_addon.cli as cli
print(json.dumps({{"status": status, "files": len(copies), "twice": sorted(p for p, ids in copies.items() if len(ids) > 1),
                  "renamed": [m.__name__ for m in sys.modules.values() if getattr(m, "__name__", "").startswith("cubegi")
                              and m is not sys.modules.get(m.__name__)],
                  "outside": sorted(n for n in sys.modules if n.startswith("cubegi_engine.") or n.startswith("cubegi_addon")),
                  "same": cli.BakeSettings is a.BakeSettings}}))
"""
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["status"] == 0 and out["files"] > 20, (out, r.stderr[-2000:])
    assert out["twice"] == [] and out["renamed"] == [] and out["outside"] == [] and out["same"]


def test_a_moved_object_recaptures_only_the_probes_it_concerns(empty_scene, cubegi):
    """Two rooms sealed by a wall: a block moved in the left room concerns the left room's
    probes only; the patched capture gives what a fresh one gives."""
    from benchmarks.scenes import box, material, mesh_object, thin_wall

    thin_wall()
    v, f = box((-2.5, -0.5, 0.0), (-1.9, 0.3, 0.8), (2, 2, 2))
    block = mesh_object("Block", v, f, material("Red", (0.7, 0.1, 0.1)))
    settings = dict(grid=(8, 4, 3), cube_size=16, bounces=3)
    assert bpy.ops.cubegi.bake(**settings) == {"FINISHED"}
    block.location.x -= 0.5
    assert bpy.ops.cubegi.bake(**settings) == {"FINISHED"}
    rep = _report()
    assert 0 < rep["probes_recaptured"] <= rep["grid"]["probes"] // 2 and not rep["capture_reused"]
    assert f"{rep['probes_recaptured']} re-captured" in "\n".join(cubegi.cubegi_engine.report.BakeReport.from_dict(rep).summary_lines())
    patched = _light()
    cubegi.cubegi_addon.session.forget()
    assert bpy.ops.cubegi.bake(**settings) == {"FINISHED"} and _report()["probes_recaptured"] is None
    fresh = _light()
    peak = max(v.max() for v in fresh.values())
    for key in fresh:  # the unit frame the GPU draws in moved with the scene's box: float32 rounding
        np.testing.assert_allclose(patched[key], fresh[key], rtol=0, atol=1e-5 * peak, err_msg=str(key))
