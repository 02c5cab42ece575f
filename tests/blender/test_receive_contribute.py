"""Which objects a bake writes light into and which light the others: Bake Selected and the
command line's ``--only``, and each object's Receive and Contribute, each against a full bake
of the same objects."""

import os
import subprocess
import sys

import bpy
import numpy as np
import pytest
import scenes

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SETTINGS = dict(grid=(4, 4, 3), cube_size=16, bounces=3)
FAST = ("--grid", "4", "4", "3", "--cube-size", "16", "--bounces", "3")
LAYERS = ("CubeGI_direct", "CubeGI", "CubeGI_total")
# The same objects baked the same way give the same numbers; 1e-6 of the peak allows for the
# order of float32 sums.
SAME = 1e-6


@pytest.fixture
def room(empty_scene, cubegi):
    """A closed room with a block on its floor and a crate beside it, lit by a point light."""
    v, f = scenes.box_mesh((-2, -2, 0), (2, 2, 2.5), (6, 6, 4), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    v, f = scenes.box_mesh((-0.6, -0.4, 0.0), (0.3, 0.5, 0.9), (3, 3, 3), inward=False)
    scenes.mesh_object("Block", v, f, scenes.material("Red", (0.7, 0.1, 0.1)))
    v, f = scenes.box_mesh((0.8, -1.2, 0.0), (1.3, -0.7, 0.5), (2, 2, 2), inward=False)
    scenes.mesh_object("Crate", v, f, scenes.material("Green", (0.1, 0.6, 0.1)))
    scenes.add_light("POINT", (1.0, 1.0, 2.0), 200.0)
    return cubegi


def _light(cubegi, names=("Room", "Block", "Crate")):
    read = cubegi.cubegi_addon.attributes.read
    out = {}
    for name in names:
        mesh = bpy.data.objects[name].data
        for layer in LAYERS:
            if layer in mesh.attributes:
                out[name, layer] = read(mesh, layer).copy()
    return out


def _same(a, b, tol=SAME):
    assert a.keys() == b.keys(), (sorted(a), sorted(b))
    peak = max(v.max() for v in b.values())
    for key in b:
        np.testing.assert_allclose(a[key], b[key], rtol=0, atol=tol * peak, err_msg=str(key))


def _bake(**kw):
    assert bpy.ops.cubegi.bake(**SETTINGS, **kw) == {"FINISHED"}


def _clear():
    for ob in bpy.data.objects:
        if ob.type == "MESH":
            for name in [a.name for a in ob.data.attributes if a.name.startswith("CubeGI")]:
                ob.data.attributes.remove(ob.data.attributes[name])


def test_bake_selected_receive_off_and_only_write_just_their_objects(room, tmp_path):
    """Bake Selected, Receive off and ``--only`` write the light of a full bake into their
    objects; every other object lights and shadows them as before and keeps the light it had
    (here an older bake's, at another power)."""
    lamp = bpy.data.objects["point"].data
    lamp.energy = 50.0
    _bake()
    older = _light(room)
    lamp.energy = 200.0
    _bake()
    full = _light(room)
    assert not np.allclose(full["Block", "CubeGI_total"], older["Block", "CubeGI_total"])

    def kept_older_except(names):
        return {k: (full[k] if k[0] in names else older[k]) for k in full}

    # Bake Selected, from the operator (the panel's button).
    _clear()
    lamp.energy = 50.0
    _bake()
    lamp.energy = 200.0
    bpy.ops.object.select_all(action="DESELECT")
    for name in ("Room", "Crate"):
        bpy.data.objects[name].select_set(True)
    _bake(selected_only=True)
    _same(_light(room), kept_older_except({"Room", "Crate"}))
    kept = room.cubegi_addon.session.kept(bpy.context.scene)
    assert sorted(t.object_name for t in kept.bake.targets) == ["Crate", "Room"]
    # An update writes the same objects only.
    lamp.energy = 100.0
    assert bpy.ops.cubegi.update_light() == {"FINISHED"}
    assert np.array_equal(_light(room, ("Block",))["Block", "CubeGI_total"], older["Block", "CubeGI_total"])
    lamp.energy = 200.0
    assert bpy.ops.cubegi.update_light() == {"FINISHED"}
    _same(_light(room), kept_older_except({"Room", "Crate"}), 1e-4)  # an update equals a bake to the solve's tolerance
    # Live's bake again (after a geometry edit) keeps to the same objects, renamed or not: they
    # are held by session_uid.
    bpy.data.objects["Crate"].name = "Crate renamed"
    lamp.energy = 100.0  # light is linear in power: the objects baked get half the light
    room.cubegi_addon.pipeline.bake(bpy.context, kept.bake.settings, kept.bake.resolution, only=kept.bake.only)
    now = _light(room, ("Room", "Block", "Crate renamed"))
    np.testing.assert_allclose(now["Crate renamed", "CubeGI_total"], 0.5 * full["Crate", "CubeGI_total"], rtol=1e-4, atol=1e-6)
    assert np.array_equal(now["Block", "CubeGI_total"], older["Block", "CubeGI_total"])
    bpy.data.objects["Crate renamed"].name = "Crate"
    lamp.energy = 200.0

    # Receive off on the Block.
    _clear()
    lamp.energy = 50.0
    _bake()
    lamp.energy = 200.0
    bpy.data.objects["Block"].cubegi.receive = False
    _bake()
    _same(_light(room), kept_older_except({"Room", "Crate"}))
    bpy.data.objects["Block"].cubegi.receive = True

    # Nothing selected: refused, nothing changed.
    bpy.ops.object.select_all(action="DESELECT")
    before = _light(room)
    with pytest.raises(RuntimeError, match="select the meshes to bake"):
        bpy.ops.cubegi.bake(**SETTINGS, selected_only=True)
    _same(_light(room), before, 0.0)

    # The command line's --only, on a file that holds the older light.
    _clear()
    lamp.energy = 50.0
    _bake()
    lamp.energy = 200.0
    src, out = tmp_path / "in.blend", tmp_path / "out.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(src))
    r = subprocess.run([sys.executable, "-m", "cubegi_engine", "bake", str(src), "-o", str(out), "--only", "Block", *FAST],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    bpy.ops.wm.open_mainfile(filepath=str(out))
    _same(_light(room), kept_older_except({"Block"}))
    r = subprocess.run([sys.executable, "-m", "cubegi_engine", "bake", str(src), "-o", str(out), "--only", "Nothing", *FAST],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "--only: no mesh object named 'Nothing'" in r.stderr, r.stderr


def test_contribute_off_is_invisible_to_the_rest_and_lit_as_a_dynamic_object(room):
    """An object with Contribute off casts no shadow and passes on no light: the rest equals a
    full bake without it; it is lit as a Dynamic object is (the same numbers), and its direct
    light is a full bake's (a convex box shadows nothing of itself)."""
    block = bpy.data.objects["Block"]
    _bake()
    with_block = _light(room)
    block.hide_render = True
    _bake()
    without_block = _light(room, ("Room", "Crate"))
    block.hide_render = False
    block.cubegi.contribute = False
    _bake()
    off = _light(room)
    _same({k: v for k, v in off.items() if k[0] != "Block"}, without_block)
    kept = room.cubegi_addon.session.kept(bpy.context.scene)
    assert "Block" not in kept.bake.arrays.object_names and [t.object_name for _, t in kept.live.moving] == ["Block"]
    assert not np.allclose(off["Room", "CubeGI_total"], with_block["Room", "CubeGI_total"])  # its shadow is gone
    lit = off["Block", "CubeGI_direct"]
    assert np.isfinite(lit).all() and lit.max() > 0
    np.testing.assert_allclose(lit.mean(axis=0), with_block["Block", "CubeGI_direct"].mean(axis=0), rtol=0.02)
    block.cubegi.contribute = True
    block.cubegi.dynamic = True
    _bake()
    _same(_light(room), off)
    # Bake Selected of that object alone: it is lit; the rest keeps its light.
    block.cubegi.dynamic = False
    block.cubegi.contribute = False
    bpy.ops.object.select_all(action="DESELECT")
    block.select_set(True)
    before = _light(room, ("Room", "Crate"))
    _bake(selected_only=True)
    _same(_light(room), {**before, **{k: v for k, v in off.items() if k[0] == "Block"}})
