"""The lit colour reaches a glTF file as COLOR_0, through Blender's bundled exporter."""

import json
import struct

import bpy
import numpy as np
import pytest

import scenes

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
