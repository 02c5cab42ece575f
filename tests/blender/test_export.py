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
