"""Animation bakes: every frame's light into ``OUT.cubegi/frame_NNNN.npz`` by the cheapest
path, equal to a full bake of that frame; the frame's light shown when the frame changes, so
renders of an animation show each frame's light."""

import json
import os
import signal
import subprocess
import sys

import bpy
import numpy as np
import pytest
import scenes
from interrupt import interrupt_cli

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# The cache is what the update path computes; a full bake of the same frame agrees to the
# tail solve's tolerance (float32 bounces, GMRES to 1e-5).
SOLVE_TOL = 2e-5
FAST = ("--grid", "3", "3", "2", "--cube-size", "16", "--bounces", "3")


def _animated_room(tmp_path, dynamic=True):
    v, f = scenes.box_mesh((-2, -2, 0), (2, 2, 2.5), (6, 6, 4), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    bv, bf = scenes.box_mesh((-0.5, 0.3, 0.0), (0.4, 1.1, 0.9), (2, 2, 2), inward=False)
    scenes.mesh_object("Block", bv, bf, scenes.material("Red", (0.7, 0.1, 0.1)))
    lamp = scenes.add_light("POINT", (1.2, -1.2, 2.0), 150.0)
    lamp.keyframe_insert("location", frame=1)
    lamp.location = (-1.2, 1.2, 1.6)
    lamp.keyframe_insert("location", frame=3)
    if dynamic:
        cv, cf = scenes.box_mesh((-0.2, -0.2, 0.0), (0.2, 0.2, 0.4), (2, 2, 2), inward=False)
        cube = scenes.mesh_object("Crate", cv, cf, scenes.material("Grey", (0.5, 0.5, 0.5)))
        cube.location = (1.0, -1.0, 0.0)
        cube.keyframe_insert("location", frame=1)
        cube.location = (-1.0, -1.0, 0.0)
        cube.keyframe_insert("location", frame=3)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.location, cam.rotation_euler = (0.0, -1.9, 1.2), (1.45, 0.0, 0.0)
    bpy.context.scene.collection.objects.link(cam)
    bpy.context.scene.camera = cam
    bpy.context.scene.frame_start, bpy.context.scene.frame_end = 1, 3
    path = tmp_path / "anim.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "cubegi_engine", *map(str, args)], cwd=ROOT, capture_output=True, text=True, timeout=300)


@pytest.mark.smoke
def test_bake_animation_writes_the_documented_cache_and_each_frame_equals_a_full_bake(empty_scene, cubegi, tmp_path):
    src = _animated_room(tmp_path)
    out, report = tmp_path / "out.blend", tmp_path / "report.json"
    r = _cli("bake-animation", src, "-o", out, "--dynamic", "Crate", "--report", report, *FAST)
    assert r.returncode == 0, r.stderr
    folder = tmp_path / "out.cubegi"
    assert sorted(os.listdir(folder)) == ["frame_0001.npz", "frame_0002.npz", "frame_0003.npz"]
    rep = json.loads(report.read_text())
    assert [f["frame"] for f in rep["frames"]] == [1, 2, 3]
    assert [f["path"] for f in rep["frames"]] == ["full", "lights", "lights"]
    assert all(f["seconds"] > 0 and len(f["mean_direct"]) == 3 for f in rep["frames"])
    bpy.ops.wm.open_mainfile(filepath=str(out))
    counts = {n: len(bpy.data.objects[n].data.vertices) for n in ("Room", "Block", "Crate")}
    with np.load(folder / "frame_0003.npz") as data:
        assert sorted(data.files) == sorted(f"{n}:{p}" for n in counts for p in ("direct", "indirect"))
        for name, count in counts.items():
            assert data[f"{name}:direct"].dtype == np.float32 and data[f"{name}:direct"].shape == (count, 3)
        cached = {k: data[k] for k in data.files}
    # Changing the frame shows that frame's light (the saved file opens on frame 1).
    read = cubegi.cubegi_addon.attributes.read
    assert bpy.context.scene.cubegi.animation_cache == "//out.cubegi"
    bpy.context.scene.frame_set(3)
    for name in counts:
        np.testing.assert_array_equal(read(bpy.data.objects[name].data, "CubeGI").astype(np.float32), cached[f"{name}:indirect"])
        np.testing.assert_array_equal(read(bpy.data.objects[name].data, "CubeGI_direct").astype(np.float32), cached[f"{name}:direct"])
    # A full bake of frame 3 gives the same light.
    bpy.ops.wm.open_mainfile(filepath=str(src))
    bpy.data.objects["Crate"].cubegi.dynamic = True
    bpy.context.scene.frame_set(3)
    assert bpy.ops.cubegi.bake(grid=(3, 3, 2), cube_size=16, bounces=3) == {"FINISHED"}
    peak = max(float(v.max()) for v in cached.values())
    for name in counts:
        for part, layer in (("direct", "CubeGI_direct"), ("indirect", "CubeGI")):
            np.testing.assert_allclose(read(bpy.data.objects[name].data, layer), cached[f"{name}:{part}"],
                                       rtol=0, atol=SOLVE_TOL * peak, err_msg=f"{name}:{part}")


def test_renders_of_two_frames_show_each_frames_light(empty_scene, cubegi, tmp_path):
    src = _animated_room(tmp_path, dynamic=False)
    out = tmp_path / "out.blend"
    assert _cli("bake-animation", src, "-o", out, *FAST).returncode == 0
    bpy.ops.wm.open_mainfile(filepath=str(out))
    bpy.context.scene.view_settings.exposure = -4.0  # 150 W in a small room: keep the pixels below white
    from tools import demo

    def render(frame, name):
        bpy.context.scene.frame_set(frame)
        path = str(tmp_path / name)
        demo.render_png(path, attribute="CubeGI_total", resolution=(64, 36))
        image = bpy.data.images.load(path)
        px = np.empty(64 * 36 * 4, dtype=np.float32)
        image.pixels.foreach_get(px)
        bpy.data.images.remove(image)
        return px.reshape(36, 64, 4)[..., :3]

    first, third = render(1, "f1.png"), render(3, "f3.png")
    assert np.abs(first - third).mean() > 0.02  # the light moved across the room
    # Without the cache, changing the frame leaves the light as it is: the same image.
    bpy.context.scene.cubegi.animation_cache = ""
    bpy.context.scene.frame_set(1)
    again = render(3, "f3_nocache.png")
    assert np.abs(again - render(1, "f1_again.png")).max() < 1e-6


def test_the_bake_animation_operator_fills_the_cache_beside_the_file(empty_scene, cubegi, tmp_path):
    src = _animated_room(tmp_path, dynamic=False)
    bpy.ops.wm.open_mainfile(filepath=str(src))
    bpy.context.scene.cubegi.cube_size, bpy.context.scene.cubegi.bounces = 16, 2
    assert bpy.ops.cubegi.bake_animation() == {"FINISHED"}
    assert sorted(os.listdir(tmp_path / "anim.cubegi")) == ["frame_0001.npz", "frame_0002.npz", "frame_0003.npz"]
    assert bpy.context.scene.cubegi.animation_cache == "//anim.cubegi"
    with np.load(tmp_path / "anim.cubegi" / "frame_0002.npz") as data:
        two = data["Room:indirect"]
    bpy.context.scene.frame_set(2)
    read = cubegi.cubegi_addon.attributes.read
    np.testing.assert_array_equal(read(bpy.data.objects["Room"].data, "CubeGI").astype(np.float32), two)


def test_a_frame_whose_static_geometry_moved_is_baked_in_full(empty_scene, cubegi, tmp_path):
    src = _animated_room(tmp_path, dynamic=False)
    bpy.ops.wm.open_mainfile(filepath=str(src))
    block = bpy.data.objects["Block"]
    block.keyframe_insert("location", frame=2)
    block.location.x += 0.5
    block.keyframe_insert("location", frame=3)
    bpy.ops.wm.save_as_mainfile(filepath=str(src))
    report = tmp_path / "r.json"
    assert _cli("bake-animation", src, "-o", tmp_path / "out.blend", "--report", report, *FAST).returncode == 0
    assert [f["path"] for f in json.loads(report.read_text())["frames"]] == ["full", "lights", "full"]


def test_a_frame_whose_render_only_modifier_moved_the_geometry_is_baked_in_full(empty_scene, cubegi, tmp_path):
    """A modifier enabled for renders alone and animated (the Block pushed up at frame 3): the
    viewport's evaluation does not see it, the render's does; that frame is baked in full."""
    src = _animated_room(tmp_path, dynamic=False)
    bpy.ops.wm.open_mainfile(filepath=str(src))
    block = bpy.data.objects["Block"]
    push = block.modifiers.new("Push", "DISPLACE")
    push.show_viewport, push.show_render, push.direction, push.mid_level = False, True, "Z", 0.0
    push.strength = 0.0
    push.keyframe_insert("strength", frame=2)
    push.strength = 0.4
    push.keyframe_insert("strength", frame=3)
    bpy.ops.wm.save_as_mainfile(filepath=str(src))
    report = tmp_path / "r.json"
    r = _cli("bake-animation", src, "-o", tmp_path / "out.blend", "--report", report, *FAST)
    assert r.returncode == 0, r.stderr
    assert [f["path"] for f in json.loads(report.read_text())["frames"]][1:] == ["lights", "full"]


def test_an_object_keyframed_into_and_out_of_renders_casts_its_shadow_only_while_it_renders(empty_scene, cubegi, tmp_path):
    """The Block leaves renders at frame 2 and comes back at frame 3; a Crate renders only at
    frame 2. Each frame whose set of rendered objects changed is baked in full, and every
    frame equals a full bake of it (before: the Block's shadow stayed at frame 2 and the
    Crate never cast one)."""
    src = _animated_room(tmp_path, dynamic=False)
    bpy.ops.wm.open_mainfile(filepath=str(src))
    cv, cf = scenes.box_mesh((-0.3, -0.3, 0.0), (0.3, 0.3, 0.6), (2, 2, 2), inward=False)
    crate = scenes.mesh_object("Crate", cv, cf, scenes.material("Grey", (0.5, 0.5, 0.5)))
    crate.location = (0.8, -0.8, 0.0)
    block = bpy.data.objects["Block"]
    for ob, hidden in ((block, (False, True, False)), (crate, (True, False, True))):
        for frame, hide in zip((1, 2, 3), hidden):
            ob.hide_render = hide
            ob.keyframe_insert("hide_render", frame=frame)
    bpy.ops.wm.save_as_mainfile(filepath=str(src))
    report = tmp_path / "r.json"
    r = _cli("bake-animation", src, "-o", tmp_path / "out.blend", "--report", report, *FAST)
    assert r.returncode == 0, r.stderr
    assert [f["path"] for f in json.loads(report.read_text())["frames"]] == ["full", "full", "full"]
    read = cubegi.cubegi_addon.attributes.read
    for frame in (2, 3):
        with np.load(tmp_path / "out.cubegi" / f"frame_{frame:04d}.npz") as data:
            cached = data["Room:direct"]
        bpy.ops.wm.open_mainfile(filepath=str(src))
        bpy.context.scene.frame_set(frame)
        assert bpy.ops.cubegi.bake(grid=(3, 3, 2), cube_size=16, bounces=3) == {"FINISHED"}
        np.testing.assert_allclose(read(bpy.data.objects["Room"].data, "CubeGI_direct"), cached, rtol=0,
                                   atol=SOLVE_TOL * float(cached.max()), err_msg=f"frame {frame}")


def test_ctrl_c_mid_animation_keeps_the_finished_frames_and_says_so(empty_scene, cubegi, tmp_path):
    """Ctrl-C during ``bake-animation``: status 130 and one line naming the frames whose light
    is kept (each file whole) and saying the output was not written (before: "nothing was
    written", with the frames there). A cluster run's key in the folder goes: its frames
    changed."""
    src = _animated_room(tmp_path, dynamic=False)
    bpy.context.scene.frame_end = 200
    bpy.ops.wm.save_as_mainfile(filepath=str(src))
    out = tmp_path / "out.blend"
    cache = tmp_path / "out.cubegi"
    cache.mkdir()
    (cache / cubegi.cubegi_addon.animation.KEY_FILE).write_text("{}")
    rc, _, err = interrupt_cli(["bake-animation", src, "-o", out, *FAST], lambda: len(list(cache.glob("frame_*.npz"))) >= 3)
    assert rc == 128 + signal.SIGINT, err
    frames = sorted(int(p.stem.split("_")[1]) for p in cache.glob("frame_*.npz"))
    lines = [ln for ln in err.splitlines() if ln.startswith("cubegi:")]
    assert lines == [f"cubegi: interrupted; the light of frames 1-{frames[-1]} is baked and kept in {cache} (each frame "
                     f"whole); {out} was not written; a run again bakes every frame"], err
    assert frames == list(range(1, frames[-1] + 1)) and len(frames) >= 3
    for frame in frames:
        with np.load(cache / f"frame_{frame:04d}.npz") as data:
            assert set(data.files) == {"Room:direct", "Room:indirect", "Block:direct", "Block:indirect"}
    assert not out.exists() and not [n for n in os.listdir(tmp_path) if n.startswith(".cubegi")]  # no temporary folder
    assert sorted(os.listdir(cache)) == [f"frame_{f:04d}.npz" for f in frames]  # the key is gone


def test_the_cache_in_the_add_on_never_shows_stale_light_without_a_word(empty_scene, cubegi, tmp_path):
    """After an animation bake: a refused Bake Animation keeps the valid cache linked; a
    still Bake replaces the cache's light (a frame change no longer brings the old cache
    back); a missing cache folder or an object renamed since the bake is named in the panel's
    Last Update line (before: each was silent, or overwrote the still bake)."""
    src = _animated_room(tmp_path, dynamic=False)
    out = tmp_path / "out.blend"
    assert _cli("bake-animation", src, "-o", out, *FAST).returncode == 0
    read = cubegi.cubegi_addon.attributes.read
    bpy.ops.wm.open_mainfile(filepath=str(out))
    s = bpy.context.scene.cubegi
    assert s.animation_cache == "//out.cubegi"
    # Refused (nothing renders): the cache stays linked, and still plays.
    for ob in bpy.data.objects:
        ob.hide_render = ob.type == "MESH"
    with pytest.raises(RuntimeError, match="no visible geometry"):
        bpy.ops.cubegi.bake_animation()
    assert s.animation_cache == "//out.cubegi"
    for ob in bpy.data.objects:
        ob.hide_render = False
    # An object renamed since the bake: named, and it keeps the light it had.
    bpy.data.objects["Block"].name = "Crate"
    bpy.context.scene.frame_set(2)
    assert "no light for Crate" in s.last_update, s.last_update
    bpy.data.objects["Crate"].name = "Block"
    bpy.context.scene.frame_set(3)
    assert not s.last_update.startswith("animation cache")
    # A still bake replaces the animation's light for good.
    bpy.data.lights["point"].energy *= 3.0
    assert bpy.ops.cubegi.bake(grid=(3, 3, 2), cube_size=16, bounces=3) == {"FINISHED"}
    still = read(bpy.data.objects["Room"].data, "CubeGI_direct")
    assert s.animation_cache == ""
    bpy.context.scene.frame_set(1)
    np.testing.assert_array_equal(read(bpy.data.objects["Room"].data, "CubeGI_direct"), still)
    # A missing cache folder: named.
    s.animation_cache = "//out.cubegi"
    os.rename(tmp_path / "out.cubegi", tmp_path / "moved.cubegi")
    bpy.context.scene.frame_set(2)
    assert "the cache folder is missing" in s.last_update, s.last_update
