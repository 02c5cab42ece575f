"""The command line: bake a saved file, reopen the output, check every attribute; bad input
fails with one line and writes nothing."""

import os
import subprocess
import sys

import bpy
import numpy as np
import pytest
import scenes

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _cli(*args):
    env = dict(os.environ)
    return subprocess.run(
        [sys.executable, "-m", "cubegi_engine", *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300
    )


@pytest.fixture
def saved_scene(empty_scene, tmp_path):
    v, f = scenes.box_mesh((-2, -2, 0), (2, 2, 2.5), (8, 8, 5), inward=True)
    room = scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    bv, bf = scenes.box_mesh((-0.53, -0.37, 0.0), (0.41, 0.49, 0.93), (2, 2, 2), inward=False)
    block = scenes.mesh_object("Block", bv, bf, scenes.material("Red", (0.7, 0.1, 0.1)))
    block.data.attributes.new("user_data", "FLOAT", "POINT")
    scenes.add_light("POINT", (0.7, 0.9, 2.1), 100.0)
    path = tmp_path / "in.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path, {"Room": len(room.data.vertices), "Block": len(block.data.vertices)}


@pytest.mark.smoke
def test_cli_bakes_a_saved_file(saved_scene, tmp_path, cubegi):
    src, counts = saved_scene
    before = src.read_bytes()
    out, report = tmp_path / "out.blend", tmp_path / "report.json"
    r = _cli("bake", str(src), "-o", str(out), "--grid", "3", "3", "2", "--bounces", "3", "--no-tail", "--report", str(report))
    assert r.returncode == 0, r.stderr
    assert "bounce 3/3" in r.stdout
    assert src.read_bytes() == before  # the input is never written
    import json

    rep = json.loads(report.read_text())
    assert [b["attribute"] for b in rep["bounces"]] == ["CubeGI_bounce_1", "CubeGI_bounce_2", "CubeGI_bounce_3"]
    assert all(b["seconds"] > 0 for b in rep["bounces"]) and rep["total_seconds"] > 0
    assert rep["grid"]["resolution"] == [3, 3, 2]

    bpy.ops.wm.open_mainfile(filepath=str(out))
    names = ["CubeGI_direct", "CubeGI_bounce_1", "CubeGI_bounce_2", "CubeGI_bounce_3", "CubeGI"]
    attributes = cubegi.cubegi_addon.attributes
    for ob_name, count in counts.items():
        mesh = bpy.data.objects[ob_name].data
        for name in names:
            attr = mesh.attributes[name]
            assert attr.data_type == "FLOAT_COLOR" and attr.domain == "POINT"
            values = attributes.read(mesh, name)
            assert values.shape == (count, 3)
            assert np.isfinite(values).all() and (values >= 0).all()
        total = attributes.read(mesh, "CubeGI")
        summed = sum(attributes.read(mesh, f"CubeGI_bounce_{k}") for k in (1, 2, 3))
        np.testing.assert_allclose(total, summed, rtol=1e-5, atol=1e-7)
        assert attributes.read(mesh, "CubeGI_direct").mean() > 0
    assert "user_data" in bpy.data.objects["Block"].data.attributes


def test_the_output_keeps_a_linked_world_s_relative_path(empty_scene, tmp_path):
    """A world linked from a library by a relative path (``//lib.blend``): the output saved
    beside the input still finds it (the output was first written in a folder of its own,
    and Blender made the path relative to that: ``//../lib.blend``, missing)."""
    world = bpy.data.worlds.new("LibSky")
    world.use_fake_user = True
    bpy.data.libraries.write(str(tmp_path / "lib.blend"), {world})
    bpy.data.worlds.remove(world)
    v, f = scenes.box_mesh((-2, -2, 0), (2, 2, 2.5), (4, 4, 3), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    scenes.add_light("POINT", (0.3, 0.2, 2.0), 100.0)
    src = tmp_path / "in.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(src))
    with bpy.data.libraries.load("//lib.blend", link=True, relative=True) as (_, linked):
        linked.worlds = ["LibSky"]
    bpy.context.scene.world = linked.worlds[0]
    bpy.ops.wm.save_as_mainfile(filepath=str(src))
    out = tmp_path / "out.blend"
    r = _cli("bake", str(src), "-o", str(out), "--grid", "3", "3", "2", "--bounces", "1", "--no-tail")
    assert r.returncode == 0, r.stderr
    bpy.ops.wm.open_mainfile(filepath=str(out))
    (lib,) = bpy.data.libraries
    assert lib.filepath == "//lib.blend" and bpy.context.scene.world.name == "LibSky" and not bpy.context.scene.world.is_missing


def test_cli_rebake_replaces_only_its_own_attributes(saved_scene, tmp_path):
    src, _ = saved_scene
    first, second = tmp_path / "a.blend", tmp_path / "b.blend"
    assert _cli("bake", str(src), "-o", str(first), "--grid", "2", "2", "2", "--bounces", "3").returncode == 0
    assert _cli("bake", str(first), "-o", str(second), "--grid", "2", "2", "2", "--bounces", "1").returncode == 0
    bpy.ops.wm.open_mainfile(filepath=str(second))
    names = {a.name for a in bpy.data.objects["Block"].data.attributes}
    assert {"CubeGI_direct", "CubeGI_bounce_1", "CubeGI", "user_data"} <= names
    assert "CubeGI_bounce_2" not in names and "CubeGI_bounce_3" not in names


@pytest.mark.smoke
def test_cli_reference_writes_its_attributes_and_errors(saved_scene, tmp_path, cubegi):
    import json

    src, counts = saved_scene
    out, report = tmp_path / "out.blend", tmp_path / "report.json"
    r = _cli(
        "bake", str(src), "-o", str(out), "--grid", "3", "3", "2", "--tolerance", "0.05", "--bounces", "20",
        "--reference", "cycles", "--reference-samples", "16", "--report", str(report),
    )
    assert r.returncode == 0, r.stderr
    rep = json.loads(report.read_text())
    # Stopped by the tolerance before the cap, and says how much was missing.
    assert len(rep["bounces"]) < 20 and rep["estimated_remaining_error"] < 0.05
    assert "estimated missing indirect light" in r.stdout and "Cycles reference, 16 samples" in r.stdout
    assert "Fra:" not in r.stdout  # Cycles' status lines (Blender 4.5 prints one per object and step)
    ref = rep["reference"]
    assert ref["samples"] == 16 and ref["seconds"] > 0 and ref["cubegi_seconds"] > 0
    for part in ("direct", "indirect", "total"):
        e = ref["errors"][part]
        assert set(e) == {"rel_rmse", "rel_bias", "p95_rel", "reference_mean"}
        assert e["reference_mean"] > 0 and np.isfinite(list(e.values())).all()
    # Direct light is the part CubeGI computes exactly but for shadow edges: within 10% at
    # 16 samples (measured 3-4%); a broken comparison (wrong vertex order) is off by 50%+.
    assert abs(ref["errors"]["direct"]["rel_bias"]) < 0.1 and ref["errors"]["direct"]["rel_rmse"] < 0.25

    bpy.ops.wm.open_mainfile(filepath=str(out))
    for ob_name, count in counts.items():
        mesh = bpy.data.objects[ob_name].data
        for name in ("CubeGI_ref_direct", "CubeGI_ref_indirect"):
            attr = mesh.attributes[name]
            assert attr.data_type == "FLOAT_COLOR" and attr.domain == "POINT" and len(attr.data) == count
        assert "CubeGI_ref_tmp" not in mesh.attributes
    # A bake without a reference keeps the reference attributes.
    again = tmp_path / "again.blend"
    assert _cli("bake", str(out), "-o", str(again), "--grid", "2", "2", "2", "--bounces", "1").returncode == 0
    bpy.ops.wm.open_mainfile(filepath=str(again))
    assert "CubeGI_ref_indirect" in bpy.data.objects["Room"].data.attributes


@pytest.mark.parametrize(
    "args,needle",
    [
        (["bake", "/nonexistent/x.blend", "-o", "{tmp}/o.blend"], "does not exist"),
        (["bake", "{notblend}", "-o", "{tmp}/o.blend"], "not a .blend"),
        (["bake", "{src}", "-o", "/nonexistent-dir/o.blend"], "output folder does not exist"),
        (["bake", "{src}", "-o", "{src}"], "is the input"),
        (["bake", "{src}", "-o", "{tmp}/o.blend", "--grid", "0", "2", "2"], "--grid"),
        (["bake", "{src}", "-o", "{tmp}/o.blend", "--cube-size", "2"], "--cube-size"),
        (["bake", "{src}", "-o", "{tmp}/o.blend", "--bounces", "-1"], "--bounces"),
        (["bake", "{src}", "-o", "{tmp}/o.blend", "--tolerance", "-0.1"], "--tolerance"),
        (["bake", "{src}", "-o", "{tmp}/o.blend", "--tolerance", "1.5"], "--tolerance"),
        (["bake", "{src}", "-o", "{tmp}/o.blend", "--reference", "cycles", "--reference-samples", "0"], "--reference-samples"),
        (["bake", "{src}", "-o", "{tmp}/o.blend", "--cells", "0"], "--cells"),
        (["bake", "{src}", "-o", "{tmp}/o.blend", "--capture-triangles", "10"], "--capture-triangles"),
    ],
)
def test_cli_bad_input_is_one_line_and_writes_nothing(saved_scene, tmp_path, args, needle):
    src, _ = saved_scene
    notblend = tmp_path / "notes.txt"
    notblend.write_text("hello")
    args = [a.format(tmp=tmp_path, src=src, notblend=notblend) for a in args]
    before = sorted(os.listdir(tmp_path))
    r = _cli(*args)
    assert r.returncode != 0
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("cubegi: error:") and needle in lines[0], r.stderr
    assert sorted(os.listdir(tmp_path)) == before


def _readme_recipe():
    """The ``blender -b ... --python-expr "..."`` line of the README, and its expression."""
    import re

    text = open(os.path.join(ROOT, "README.md")).read()
    line = re.search(r'^blender -b (\S+) --python-expr "(.+)"$', text, re.M)
    assert line, "the README's headless recipe is missing"
    return line.group(1), line.group(2)


def test_the_readmes_headless_recipe_gives_what_the_cli_gives(saved_scene, tmp_path, cubegi):
    src, counts = saved_scene
    scene_name, expr = _readme_recipe()
    assert scene_name == "scene.blend" and "bpy.ops.cubegi.bake(" in expr
    cli_out = tmp_path / "cli.blend"
    assert _cli("bake", str(src), "-o", str(cli_out), "--bounces", "3").returncode == 0
    # What blender -b scene.blend --python-expr does: open the file, run the expression
    # (here with the extension loaded from this tree, as the install test does with the zip).
    # The recipe's relative path names a file in the folder Blender started in; Blender 4.5
    # resolves it against the folder this process started in, so it is made absolute here.
    bpy.ops.wm.open_mainfile(filepath=str(src))
    assert "'baked.blend'" in expr
    exec(expr.replace("'baked.blend'", repr(str(tmp_path / "baked.blend"))), {})
    attributes = cubegi.cubegi_addon.attributes
    ours = {n: {a: attributes.read(bpy.data.objects[n].data, a) for a in ("CubeGI_direct", "CubeGI", "CubeGI_total")} for n in counts}
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "baked.blend"))
    for n in counts:  # the recipe saved what it baked
        np.testing.assert_array_equal(attributes.read(bpy.data.objects[n].data, "CubeGI"), ours[n]["CubeGI"])
    bpy.ops.wm.open_mainfile(filepath=str(cli_out))
    for n in counts:
        for a, values in ours[n].items():
            np.testing.assert_allclose(attributes.read(bpy.data.objects[n].data, a), values, rtol=1e-5, atol=1e-7)


def test_cli_quality_presets_set_what_is_not_given(saved_scene, tmp_path):
    """``--quality draft`` bakes with 4 cells along the longest side, 16^2 faces and 3
    bounces; an explicit option still wins; the default is the balanced preset, with the
    near field (``--no-near-field`` turns it off) and probes moved out of geometry
    (``--keep-probes-in-place`` turns that off), the sky through the probes
    (``--sky-per-vertex``: along each vertex's own lines of sight)."""
    import json

    src, _ = saved_scene
    runs = {
        "draft": ["--quality", "draft"],
        "draft, 2 bounces": ["--quality", "draft", "--bounces", "2"],
        "default": [],
        "no near field": ["--no-near-field"],
        "probes in place": ["--keep-probes-in-place"],
        "sky per vertex": ["--sky-per-vertex"],
    }
    got = {}
    for name, extra in runs.items():
        report = tmp_path / f"{name}.json"
        r = _cli("bake", str(src), "-o", str(tmp_path / "o.blend"), "--report", str(report), *extra)
        assert r.returncode == 0, r.stderr
        got[name] = json.loads(report.read_text())
    draft = got["draft"]["settings"]
    assert (draft["cells"], draft["cube_size"], draft["bounces"]) == (4, 16, 3)
    assert len(got["draft"]["bounces"]) == 3 and max(got["draft"]["grid"]["resolution"]) == 4
    assert got["draft, 2 bounces"]["settings"]["bounces"] == 2 and got["draft, 2 bounces"]["settings"]["cells"] == 4
    balanced = got["default"]["settings"]
    assert (balanced["cells"], balanced["cube_size"], balanced["bounces"]) == (8, 16, 5)
    assert max(got["default"]["grid"]["resolution"]) == 8
    assert balanced["near_field"] is True and got["default"]["near_field"]["points"] > 0
    assert got["no near field"]["settings"]["near_field"] is False and got["no near field"]["near_field"] is None
    assert balanced["move_probes"] is True and got["probes in place"]["settings"]["move_probes"] is False
    assert got["probes in place"]["grid"].get("probes_moved") is None
    assert balanced["sky_per_vertex"] is False and got["sky per vertex"]["settings"]["sky_per_vertex"] is True


def test_the_command_line_bakes_with_the_files_own_settings_unless_an_option_overrides(saved_scene, tmp_path, cubegi):
    """A file saved with Quality Final, Near Field off and Lit Color on: `bake` and
    `bake-animation` with no options bake it so (before: Balanced, with the near field, no
    lit colour); an option given wins over the file."""
    import json

    src, _ = saved_scene
    bpy.ops.wm.open_mainfile(filepath=str(src))
    s = bpy.context.scene.cubegi
    s.quality = "FINAL"  # sets its cells, cube size and bounces
    s.near_field = False
    s.lit = "ALL"
    s.bounces = 2  # edited after the preset, as a user may
    bpy.ops.wm.save_as_mainfile(filepath=str(src))
    runs = {"file": ("bake", []), "overridden": ("bake", ["--quality", "draft", "--lit", "indirect"]),
            "animation": ("bake-animation", ["--frames", "1", "1"])}
    got = {}
    for name, (command, extra) in runs.items():
        report, out = tmp_path / f"{name}.json", tmp_path / f"{name}.blend"
        r = _cli(command, str(src), "-o", str(out), "--report", str(report), *extra)
        assert r.returncode == 0, r.stderr
        got[name] = json.loads(report.read_text())
        bpy.ops.wm.open_mainfile(filepath=str(out))
        got[name]["lit"] = "CubeGI_lit" in bpy.data.objects["Room"].data.attributes
    file_settings = got["file"]["settings"]
    assert (file_settings["cells"], file_settings["cube_size"], file_settings["bounces"]) == (12, 32, 2)
    assert file_settings["near_field"] is False and got["file"]["lit"]
    over = got["overridden"]["settings"]
    assert (over["cells"], over["cube_size"], over["bounces"]) == (4, 16, 3) and over["near_field"] is False
    assert got["overridden"]["lit"]
    assert got["animation"]["frames"][0]["probes"] == got["file"]["grid"]["probes"] and got["animation"]["lit"]


def test_running_out_of_memory_is_refused_in_one_line_and_writes_nothing(saved_scene, tmp_path, cubegi, monkeypatch, capsys):
    """A scene too large for the machine's memory is the user's situation: status 2 and one
    line saying what to do, not a defect's status 3 (the bake's allocation fails as
    MemoryError; here the pipeline raises it, as numpy does on a huge array)."""
    src, _ = saved_scene
    out = tmp_path / "out.blend"

    def too_large(*args, **kwargs):
        raise MemoryError("Unable to allocate 93.1 GiB for an array with shape (1000000, 6144, 4)")

    monkeypatch.setattr(cubegi.cubegi_addon.pipeline, "bake", too_large)
    import cubegi.cubegi_addon.cli as cli

    assert cli.main(["bake", str(src), "-o", str(out)]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "out of memory" in err[0] and "please report" not in err[0], err
    assert not out.exists()
