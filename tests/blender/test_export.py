"""The baked light in glTF: the lit colour as COLOR_0 through Blender's bundled exporter, and
CubeGI's own export that keeps light above 1 (float attributes), read back here by a reader
of its own."""

import json
import os
import struct
import subprocess
import sys

import bpy
import numpy as np
import pytest
import scenes

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# glTF accessor component types and how to read them (normalised integers map to [0, 1]).
COMPONENTS = {5126: (np.float32, 1.0), 5123: (np.uint16, 65535.0), 5121: (np.uint8, 255.0)}
WIDTH = {"VEC3": 3, "VEC4": 4}


def read_glb(path):
    """The JSON and binary chunks of a .glb file."""
    data = open(path, "rb").read()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF" and version == 2 and length == len(data)
    json_len, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A
    doc = json.loads(data[20 : 20 + json_len])
    bin_len, bin_type = struct.unpack_from("<II", data, 20 + json_len)
    assert bin_type == 0x004E4942
    return doc, data[28 + json_len : 28 + json_len + bin_len]


def accessor(doc, blob, index):
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    dtype, scale = COMPONENTS[acc["componentType"]]
    width = WIDTH[acc["type"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    stride = view.get("byteStride", width * np.dtype(dtype).itemsize)
    rows = np.ndarray((acc["count"], width), dtype=dtype, buffer=blob, offset=start, strides=(stride, np.dtype(dtype).itemsize))
    values = rows.astype(np.float64)
    return values / scale if acc.get("normalized") or dtype is not np.float32 else values


@pytest.mark.parametrize("mode", ["ALL", "INDIRECT"])
def test_the_lit_colour_is_exported_as_color_0(empty_scene, cubegi, tmp_path, mode):
    scenes.closed_box(albedo=0.5, cells=4)
    scenes.add_light("POINT", (0.3, -0.2, 0.4), 10.0)
    assert bpy.ops.cubegi.bake(bounces=2, cube_size=8, grid=(2, 2, 2), lit=mode) == {"FINISHED"}
    attributes = cubegi.cubegi_addon.attributes
    mesh = bpy.data.objects["Box"].data
    lit = attributes.read(mesh, "CubeGI_lit")
    light = attributes.read(mesh, "CubeGI_total" if mode == "ALL" else "CubeGI")
    np.testing.assert_allclose(lit, 0.5 * light, rtol=1e-5, atol=1e-7)
    assert 0.0 < lit.max() < 1.0  # inside glTF's colour range, so nothing is clamped
    path = str(tmp_path / "box.glb")
    bpy.ops.export_scene.gltf(
        filepath=path, export_format="GLB", export_vertex_color="NAME", export_vertex_color_name="CubeGI_lit"
    )
    doc, blob = read_glb(path)
    (prim,) = doc["meshes"][0]["primitives"]
    colours = accessor(doc, blob, prim["attributes"]["COLOR_0"])[:, :3]
    positions = accessor(doc, blob, prim["attributes"]["POSITION"])
    # glTF is Y up: (x, y, z) in Blender is (x, z, -y) in the file. Each exported vertex is
    # a copy of a mesh vertex (split at seams; the box's faces have their own vertices at
    # its edges): find the mesh vertex at its position with the same colour.
    ours = np.array([v.co for v in mesh.vertices])[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0])
    same_place = ((positions[:, None, :] - ours[None, :, :]) ** 2).sum(-1) < 1e-10  # (exported, ours)
    assert same_place.any(axis=1).all()
    colour_gap = np.abs(colours[:, None, :] - lit[None, :, :]).max(-1)
    match = same_place & (colour_gap < 1e-5)
    assert match.any(axis=1).all(), np.where(same_place, colour_gap, np.inf).min(axis=1).max()
    assert match.any(axis=0).all()  # every vertex's colour is in the file
    assert len(colours) >= len(mesh.vertices)


@pytest.mark.parametrize("how", ["operator", "cli"])
def test_the_cubegi_export_keeps_light_above_1(empty_scene, cubegi, tmp_path, how):
    """A bright room (its light up to several times 1): the .glb's float attribute
    ``_CUBEGI_LIGHT`` holds every vertex's light as baked, above 1 included, and COLOR_0 the
    light times 2^exposure (stored in asset.extras), clamped; the user's meshes keep
    nothing of the export. By the operator (File > Export) and by ``bake --gltf``."""
    v, f = scenes.box_mesh((-1, -1, 0), (1, 1, 2), (4, 4, 4), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    scenes.add_light("POINT", (0.3, -0.2, 1.2), 400.0)
    attributes = cubegi.cubegi_addon.attributes
    path = tmp_path / "room.glb"
    if how == "operator":
        assert bpy.ops.cubegi.bake(bounces=2, cube_size=8, grid=(2, 2, 2)) == {"FINISHED"}
        before = {a.name for a in bpy.data.meshes["Room"].attributes}
        assert bpy.ops.cubegi.export_gltf(filepath=str(path)) == {"FINISHED"}
        assert {a.name for a in bpy.data.meshes["Room"].attributes} == before
    else:
        src, out = tmp_path / "in.blend", tmp_path / "out.blend"
        bpy.ops.wm.save_as_mainfile(filepath=str(src))
        r = subprocess.run([sys.executable, "-m", "cubegi_engine", "bake", str(src), "-o", str(out), "--gltf", str(path),
                            "--bounces", "2", "--cube-size", "8", "--grid", "2", "2", "2"],
                           cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        bpy.ops.wm.open_mainfile(filepath=str(out))
    mesh = bpy.data.meshes["Room"]
    light = attributes.read(mesh, "CubeGI_total")
    indirect = attributes.read(mesh, "CubeGI")
    assert light.max() > 2.0  # the case a clamped COLOR_0 cannot carry
    doc, blob = read_glb(path)
    extras = doc["asset"]["extras"]["cubegi"]
    (prim,) = doc["meshes"][0]["primitives"]
    exported = accessor(doc, blob, prim["attributes"]["_CUBEGI_LIGHT"])
    exported_indirect = accessor(doc, blob, prim["attributes"]["_CUBEGI_INDIRECT"])
    colours = accessor(doc, blob, prim["attributes"]["COLOR_0"])[:, :3]
    assert doc["accessors"][prim["attributes"]["_CUBEGI_LIGHT"]]["componentType"] == 5126  # float
    positions = accessor(doc, blob, prim["attributes"]["POSITION"])
    ours = np.array([v.co for v in mesh.vertices])[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0])
    # Each exported vertex is a copy of a mesh vertex at its place (the box's sides have
    # their own vertices along its edges, so a place can hold several): one there must have
    # exactly its light, and every mesh vertex must be in the file.
    same_place = ((positions[:, None, :] - ours[None, :, :]) ** 2).sum(-1) < 1e-10  # (exported, ours)
    gap = np.maximum(np.abs(exported[:, None] - light[None]).max(-1), np.abs(exported_indirect[:, None] - indirect[None]).max(-1))
    match = same_place & (gap <= 1e-6 * light.max())
    assert match.any(axis=1).all() and match.any(axis=0).all()
    scale = 2.0 ** extras["exposure"]
    first = match.argmax(axis=1)
    np.testing.assert_allclose(colours, np.clip(light[first] * scale, 0, 1), atol=1e-4)  # 16-bit
    assert (light.max(axis=1) * scale <= 1.0 + 1e-6).mean() >= 0.985  # 99% of vertices unclipped


def test_light_groups_are_layers_of_their_own_in_the_bake_the_updates_and_the_glb(empty_scene, cubegi, tmp_path):
    """A view layer with two light groups (a key lamp; a fill lamp with the world): each
    gets a layer, CubeGI_group_<name>, of its sources' light alone; with every source in a
    group they add up to CubeGI_total exactly (each is its share of it). Each is near a bake with only that group's sources on
    (the energy balance is the whole scene's, as in the layers' sum). Update Light keeps
    them current; the .glb carries each, above 1 included. A scene without groups gets none."""
    attributes = cubegi.cubegi_addon.attributes
    v, f = scenes.box_mesh((-2, -2, 0), (2, 2, 2.5), (6, 6, 4), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    v, f = scenes.box_mesh((-0.6, -0.4, 0.0), (0.3, 0.5, 0.9), (3, 3, 3), inward=False)
    scenes.mesh_object("Block", v, f, scenes.material("Red", (0.7, 0.1, 0.1)))
    key = scenes.add_light("POINT", (1.0, 1.0, 2.0), 600.0)
    fill = scenes.add_light("AREA", (-1.2, -1.0, 2.3), 300.0)
    kwargs = dict(grid=(3, 3, 2), cube_size=16, bounces=3)
    assert bpy.ops.cubegi.bake(**kwargs) == {"FINISHED"}
    assert not [n for n in bpy.data.meshes["Room"].attributes.keys() if n.startswith("CubeGI_group_")]  # none asked for
    view_layer = bpy.context.view_layer
    for name in ("key", "fill light"):
        view_layer.lightgroups.add(name=name)
    key.lightgroup, fill.lightgroup = "key", "fill light"

    def read(name, mesh="Room"):
        return attributes.read(bpy.data.meshes[mesh], name)

    def alone(on):
        energies = {key: 600.0, fill: 300.0}
        for lamp, energy in energies.items():
            lamp.data.energy = energy if lamp is on else 0.0
        assert bpy.ops.cubegi.bake(**kwargs) == {"FINISHED"}
        out = read("CubeGI_total")
        for lamp, energy in energies.items():
            lamp.data.energy = energy
        return out

    only_key, only_fill = alone(key), alone(fill)
    assert bpy.ops.cubegi.bake(**kwargs) == {"FINISHED"}
    total, g_key, g_fill = read("CubeGI_total"), read("CubeGI_group_key"), read("CubeGI_group_fill light")
    peak = total.max()
    np.testing.assert_allclose(g_key + g_fill, total, rtol=0, atol=1e-6 * peak)  # each its share of the total
    # Measured: means +1.5% (key) and -3.0% (fill), at most 0.7% of the peak apart at a vertex: the
    # balance scales each bounce by the whole scene's factor, a bake of one group by its own.
    for got, want in ((g_key, only_key), (g_fill, only_fill)):
        assert np.abs(got - want).max() < 0.05 * peak and abs(got.mean() / want.mean() - 1) < 0.04
    # Update Light after the key's power is halved: the key's layer halves, the fill's stays.
    key.data.energy = 300.0
    assert bpy.ops.cubegi.update_light() == {"FINISHED"}
    np.testing.assert_allclose(read("CubeGI_group_key"), 0.5 * g_key, rtol=0, atol=2e-3 * peak)
    np.testing.assert_allclose(read("CubeGI_group_fill light"), g_fill, rtol=0, atol=2e-3 * peak)
    np.testing.assert_allclose(read("CubeGI_group_key") + read("CubeGI_group_fill light"), read("CubeGI_total"), rtol=0,
                               atol=1e-6 * peak)
    # The fill lamp moved to no group: its layer empties (its light is the total's rest).
    fill.lightgroup = ""
    assert bpy.ops.cubegi.update_light() == {"FINISHED"}
    assert read("CubeGI_group_fill light").max() == 0.0
    fill.lightgroup = "fill light"
    assert bpy.ops.cubegi.update_light() == {"FINISHED"}
    # The export: one float attribute per group, as baked.
    path = tmp_path / "groups.glb"
    assert bpy.ops.cubegi.export_gltf(filepath=str(path)) == {"FINISHED"}
    doc, blob = read_glb(path)
    groups = doc["asset"]["extras"]["cubegi"]["groups"]
    assert groups == {"fill light": "_CUBEGI_LIGHT_FILL_LIGHT", "key": "_CUBEGI_LIGHT_KEY"}
    mesh = bpy.data.meshes["Room"]
    ours = np.array([v.co for v in mesh.vertices])[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0])
    (prim,) = next(m for m in doc["meshes"] if m["name"] == "Room")["primitives"]
    positions = accessor(doc, blob, prim["attributes"]["POSITION"])
    same_place = ((positions[:, None, :] - ours[None, :, :]) ** 2).sum(-1) < 1e-10
    for group, attr in groups.items():
        exported, baked = accessor(doc, blob, prim["attributes"][attr]), read(f"CubeGI_group_{group}")
        match = same_place & (np.abs(exported[:, None] - baked[None]).max(-1) <= 1e-6 * peak)
        assert match.any(axis=1).all() and match.any(axis=0).all(), group
    assert max(read("CubeGI_group_key").max(), read("CubeGI_group_fill light").max()) > 1.0
    # The groups changed since the bake: the update refuses; a bake without groups drops the layers.
    view_layer.lightgroups.add(name="rim")
    with pytest.raises(RuntimeError, match="light groups changed since the bake"):
        bpy.ops.cubegi.update_light()
    for name in ("key", "fill light", "rim"):
        view_layer.lightgroups.remove(view_layer.lightgroups[name])
    assert bpy.ops.cubegi.bake(**kwargs) == {"FINISHED"}
    assert not [n for n in mesh.attributes.keys() if n.startswith("CubeGI_group_")]
