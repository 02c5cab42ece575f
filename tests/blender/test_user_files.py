"""User data is never lost: the command line's paths (the input is never written, nor a
device node, nor a file reached through links), CubeGI's ownership of only the attributes
it made, and outputs that keep everything of the user's and leave no stray files."""

import json
import os
import signal
import stat
import subprocess
import sys

import bpy
import pytest
import scenes
from state import scene_state

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "cubegi_engine", *map(str, args)], cwd=ROOT, capture_output=True, text=True, timeout=300
    )


def _one_line_refusal(r, needle):
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    assert r.returncode == 2, r.stderr
    assert len(lines) == 1 and lines[0].startswith("cubegi: error:") and needle in lines[0], r.stderr


def _room():
    v, f = scenes.box_mesh((-2, -2, 0), (2, 2, 2.5), (4, 4, 3), inward=True)
    room = scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    scenes.add_light("POINT", (0.3, 0.2, 1.5), 80.0)
    return room


@pytest.fixture
def saved(empty_scene, tmp_path):
    _room()
    path = tmp_path / "in.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=False)
    return path


FAST = ("--grid", "2", "2", "2", "--bounces", "1", "--cube-size", "8")


# --- paths: 15.1, 15.2, 15.3, 15.16 ---------------------------------------------------------

def test_a_report_naming_the_input_or_the_output_is_refused(saved, tmp_path):
    before = saved.read_bytes()
    out = tmp_path / "out.blend"
    _one_line_refusal(_cli("bake", saved, "-o", out, "--report", saved), "the report")
    assert saved.read_bytes() == before and not out.exists()
    _one_line_refusal(_cli("bake", saved, "-o", out, "--report", out), "is the output")
    assert not out.exists()


def test_device_nodes_fifos_and_folders_are_refused_as_outputs(saved, tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    before = sorted(os.listdir(tmp_path))
    _one_line_refusal(_cli("bake", saved, "-o", "/dev/null"), "not a regular file")
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)
    _one_line_refusal(_cli("bake", saved, "-o", fifo), "not a regular file")
    _one_line_refusal(_cli("bake", saved, "-o", tmp_path), "is a folder")
    _one_line_refusal(_cli("bake", saved, "-o", tmp_path / "o.blend", "--report", tmp_path), "is a folder")
    _one_line_refusal(_cli("bake", saved, "-o", tmp_path / "o.blend", "--report", "/dev/null"), "not a regular file")
    assert sorted(os.listdir(tmp_path)) == before and stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_an_output_reaching_the_input_through_links_is_refused(saved, tmp_path):
    before = saved.read_bytes()
    (tmp_path / "alias").symlink_to(tmp_path, target_is_directory=True)
    _one_line_refusal(_cli("bake", saved, "-o", tmp_path / "alias" / "in.blend"), "is the input")
    os.link(saved, tmp_path / "hard.blend")
    _one_line_refusal(_cli("bake", saved, "-o", tmp_path / "hard.blend"), "is the input")
    (tmp_path / "soft.blend").symlink_to(saved)
    _one_line_refusal(_cli("bake", saved, "-o", tmp_path / "soft.blend"), "is the input")
    _one_line_refusal(_cli("bake", saved, "-o", tmp_path / "o.blend", "--report", tmp_path / "alias" / "in.blend"), "is the input")
    assert saved.read_bytes() == before


def test_a_truncated_blend_file_and_an_edit_mode_file(saved, tmp_path):
    bad = tmp_path / "cut.blend"
    bad.write_bytes(saved.read_bytes()[:4000])
    r = _cli("bake", bad, "-o", tmp_path / "o.blend", *FAST)
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.startswith("cubegi:")]
    assert r.returncode == 2 and len(lines) == 1 and "cannot read the input" in lines[0], r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "o.blend").exists()

    # Saved in Edit Mode: baked as the edit data stands.
    bpy.ops.wm.open_mainfile(filepath=str(saved))
    room = bpy.data.objects["Room"]
    bpy.context.view_layer.objects.active = room
    bpy.ops.object.mode_set(mode="EDIT")
    edit = tmp_path / "edit.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(edit))
    bpy.ops.object.mode_set(mode="OBJECT")
    out = tmp_path / "edit_out.blend"
    r = _cli("bake", edit, "-o", out, *FAST)
    assert r.returncode == 0, r.stderr
    bpy.ops.wm.open_mainfile(filepath=str(out))
    assert "CubeGI" in bpy.data.objects["Room"].data.attributes


def test_a_failed_write_leaves_every_target_as_it_was(tmp_path, cubegi):
    files = cubegi.cubegi_addon.files
    first, second = tmp_path / "a.txt", tmp_path / "b.txt"
    first.write_text("old a")

    def full(tmp):
        raise OSError(28, "No space left on device")

    with pytest.raises(cubegi.cubegi_engine.errors.BakeError, match="No space left"):
        files.write_all([(str(first), lambda tmp: open(tmp, "w").write("new a")), (str(second), full)])
    assert first.read_text() == "old a" and not second.exists()
    assert sorted(os.listdir(tmp_path)) == ["a.txt"]  # no temporary folder left


# A bake process that gets SIGTERM while it saves: the save itself is Blender's, the signal
# comes from the process itself right after it, so that it lands in the save's step every run.
_TERM_DURING_SAVE = """
import importlib, os, signal, sys
sys.path.insert(0, {root!r})
from tools import load_extension
load_extension(register=False)
cli = importlib.import_module("cubegi.cubegi_addon.cli")
save = cli.save_blend

def save_then_term(compressed):
    write = save(compressed)

    def write_and_term(tmp):
        write(tmp)
        os.kill(os.getpid(), signal.SIGTERM)

    return write_and_term

cli.save_blend = save_then_term
sys.exit(cli.main(sys.argv[1:]))
"""


def test_sigterm_while_saving_finishes_the_save_and_leaves_no_temporary_folder(saved, tmp_path):
    """SIGTERM during the save (a job scheduler's stop): the write ends (every file whole),
    then the command stops with status 143 and one line naming what it wrote; no hidden
    ``.cubegi-*`` file stays (before: the process ended mid-save and left a folder)."""
    out, report = tmp_path / "out" / "out.blend", tmp_path / "out" / "out.json"
    out.parent.mkdir()
    before = saved.read_bytes()
    r = subprocess.run([sys.executable, "-c", _TERM_DURING_SAVE.format(root=ROOT), "bake", str(saved), "-o", str(out),
                        "--report", str(report), *FAST], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 128 + signal.SIGTERM, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("cubegi:")]
    assert lines == [f"cubegi: stopped by SIGTERM; {out}, {report} were written (whole) before it stopped"], r.stderr
    assert sorted(os.listdir(out.parent)) == ["out.blend", "out.json"] and saved.read_bytes() == before
    assert json.loads(report.read_text())["output"] == str(out)
    bpy.ops.wm.open_mainfile(filepath=str(out))
    assert "CubeGI" in bpy.data.objects["Room"].data.attributes


@pytest.mark.parametrize("when", ["writing", "renaming"])
def test_an_interrupt_while_files_are_written_waits_for_the_write_to_end(tmp_path, cubegi, monkeypatch, when):
    """All or none: a signal while a job's files are written or renamed into place waits
    until the last is in place; then the interrupt goes on, naming them."""
    files, interrupts = cubegi.cubegi_addon.files, cubegi.cubegi_addon.interrupts
    first, second = tmp_path / "a.txt", tmp_path / "b.txt"
    first.write_text("old a")
    second.write_text("old b")
    replace = os.replace

    def replace_then_term(src, dst):
        replace(src, dst)
        os.kill(os.getpid(), signal.SIGTERM)

    def write_then_term(tmp):
        files.text("new b")(tmp)
        os.kill(os.getpid(), signal.SIGTERM)

    if when == "renaming":
        monkeypatch.setattr(files.os, "replace", replace_then_term)
    with interrupts.interruptible(), pytest.raises(cubegi.cubegi_engine.errors.Interrupted) as stop:
        files.write_all([(str(first), files.text("new a")), (str(second), write_then_term if when == "writing" else files.text("new b"))])
    assert stop.value.signum == signal.SIGTERM and stop.value.written == [str(first), str(second)]
    assert (first.read_text(), second.read_text()) == ("new a", "new b")  # both, not one
    assert sorted(os.listdir(tmp_path)) == ["a.txt", "b.txt"]  # no temporary folder left
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL  # the handler is the command line's only while it runs


def test_an_interrupt_in_a_blender_handler_waits_for_the_next_step(empty_scene, cubegi):
    """Blender prints and drops an exception raised in a handler (here frame_change_post): an
    interrupt that comes there waits for the next progress step instead of being lost."""
    interrupts = cubegi.cubegi_addon.interrupts
    seen = []

    @interrupts.blender_callback
    def handler(scene, depsgraph=None):
        os.kill(os.getpid(), signal.SIGINT)
        seen.append(scene.frame_current)  # runs on: the interrupt waits

    bpy.app.handlers.frame_change_post.append(handler)
    try:
        with interrupts.interruptible():
            bpy.context.scene.frame_set(2)
            assert seen == [2]
            with pytest.raises(cubegi.cubegi_engine.errors.Interrupted) as stop:
                interrupts.check()
    finally:
        bpy.app.handlers.frame_change_post.remove(handler)
    assert stop.value.signum == signal.SIGINT
    interrupts.check()  # raised once only


def test_the_operators_report_path_is_checked_before_the_bake(empty_scene, cubegi, tmp_path):
    _room()
    before = scene_state()
    with pytest.raises(RuntimeError, match="report folder does not exist"):
        bpy.ops.cubegi.bake(grid=(2, 2, 2), bounces=1, report_path=str(tmp_path / "missing" / "r.json"))
    assert scene_state() == before


# --- outputs keep the user's file whole: 15.5, 15.6 --------------------------------------------

@pytest.mark.parametrize("compress", [True, False])
def test_the_output_keeps_the_ui_and_the_compression_and_leaves_no_stray_file(empty_scene, tmp_path, compress):
    bpy.ops.wm.read_factory_settings()  # with the UI, as users save
    for ob in list(bpy.data.objects):
        bpy.data.objects.remove(ob)
    _room()
    bpy.data.workspaces["Animation"].name = "My Lighting"
    src = tmp_path / "in.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(src), compress=compress)
    out, report = tmp_path / "out.blend", tmp_path / "report.json"
    r = _cli("bake", src, "-o", out, "--report", report, *FAST)
    assert r.returncode == 0, r.stderr
    assert "EGL" not in r.stderr  # the GPU's start-up chatter is silenced
    assert sorted(os.listdir(tmp_path)) == ["in.blend", "out.blend", "report.json"]  # no .blend1, no temporary file
    assert out.read_bytes()[:4] == src.read_bytes()[:4]  # zstd header or BLEN, as the input
    bpy.ops.wm.open_mainfile(filepath=str(out), load_ui=True)
    assert "My Lighting" in bpy.data.workspaces
    assert "CubeGI" in bpy.data.objects["Room"].data.attributes
    # A second run over the same output replaces it, still with no backup file.
    assert _cli("bake", src, "-o", out, *FAST).returncode == 0
    assert sorted(os.listdir(tmp_path)) == ["in.blend", "out.blend", "report.json"]


def test_the_demo_leaves_no_stray_file(tmp_path):
    r = _cli("demo", "--out", tmp_path, "--no-render", "--grid", "2", "2", "2", "--bounces", "1", "--cube-size", "8")
    assert r.returncode == 0, r.stderr
    assert sorted(os.listdir(tmp_path)) == ["report.json", "room.blend"]


# --- CubeGI owns only what it made: 15.4 --------------------------------------------------------

def _user_data(room, kind):
    mesh = room.data
    if kind == "vector":
        mesh.attributes.new("CubeGI", "FLOAT_VECTOR", "POINT")
    elif kind == "uv":
        mesh.uv_layers.new(name="CubeGI")
    elif kind == "group":
        room.vertex_groups.new(name="CubeGI")
    elif kind == "face_float":
        mesh.attributes.new("CubeGI", "FLOAT", "FACE")
    elif kind == "corner_bytes":
        mesh.attributes.new("CubeGI_direct", "BYTE_COLOR", "CORNER")
    elif kind == "same_type":  # even CubeGI's own type: the user made it
        mesh.attributes.new("CubeGI_total", "FLOAT_COLOR", "POINT").data[0].color = (0.25, 0.5, 0.75, 1.0)


@pytest.mark.parametrize("kind", ["vector", "uv", "group", "face_float", "corner_bytes", "same_type"])
def test_user_data_named_like_cubegis_refuses_the_bake_and_is_kept(empty_scene, cubegi, kind):
    room = _room()
    _user_data(room, kind)
    before = scene_state()
    groups = [g.name for g in room.vertex_groups]
    with pytest.raises(RuntimeError) as info:
        bpy.ops.cubegi.bake(grid=(2, 2, 2), bounces=1, cube_size=8)
    message = str(info.value).strip().splitlines()
    assert len(message) == 1 and "mesh 'Room'" in message[0] and "CubeGI did not make" in message[0], message
    assert scene_state() == before and [g.name for g in room.vertex_groups] == groups


def test_user_attributes_with_cubegi_like_names_survive_bakes_and_clear(empty_scene, cubegi):
    room = _room()
    mesh = room.data
    extra = mesh.attributes.new("CubeGI_bounce_42", "FLOAT_COLOR", "POINT")
    extra.data[0].color = (1.0, 2.0, 3.0, 1.0)
    mesh.uv_layers.new(name="CubeGI_lit")
    assert bpy.ops.cubegi.bake(grid=(2, 2, 2), bounces=2, cube_size=8) == {"FINISHED"}  # lit off: CubeGI_lit unused
    assert {"CubeGI", "CubeGI_bounce_2", "CubeGI_bounce_42", "CubeGI_lit"} <= set(mesh.attributes.keys())
    assert bpy.ops.cubegi.bake(grid=(2, 2, 2), bounces=1, cube_size=8) == {"FINISHED"}
    assert "CubeGI_bounce_2" not in mesh.attributes  # its own, replaced
    assert bpy.ops.cubegi.clear() == {"FINISHED"}
    names = set(mesh.attributes.keys())
    assert "CubeGI" not in names and "CubeGI_direct" not in names
    assert {"CubeGI_bounce_42", "CubeGI_lit"} <= names and "CubeGI_lit" in mesh.uv_layers
    assert tuple(mesh.attributes["CubeGI_bounce_42"].data[0].color)[:3] == (1.0, 2.0, 3.0)
    with pytest.raises(RuntimeError, match="UV map 'CubeGI_lit'"):
        bpy.ops.cubegi.bake(grid=(2, 2, 2), bounces=1, cube_size=8, lit="ALL")


def test_the_cli_refuses_a_clash_in_one_line(empty_scene, tmp_path):
    room = _room()
    room.data.uv_layers.new(name="CubeGI")
    src = tmp_path / "in.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(src))
    r = _cli("bake", src, "-o", tmp_path / "o.blend", *FAST)
    _one_line_refusal(r, "UV map 'CubeGI'")
    assert not (tmp_path / "o.blend").exists()
