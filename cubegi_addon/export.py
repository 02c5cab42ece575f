"""The baked light in a glTF binary (.glb) that keeps it above 1.

Blender's glTF exporter writes a colour attribute as ``COLOR_0``, normalised 16-bit and so
clamped to [0, 1]; CubeGI's light is linear and often well above 1 (a plainly lit room
exports as 1.0 almost everywhere). glTF lets an application add vertex attributes whose
names start with an underscore, and Blender's exporter writes a mesh attribute so named
(with Export Attributes on), as float. A CubeGI export holds, per vertex:

| glTF attribute | type | what |
|---|---|---|
| ``_CUBEGI_LIGHT`` | VEC3 float | all the light (``CubeGI_total``: direct + indirect), linear, irradiance / pi |
| ``_CUBEGI_INDIRECT`` | VEC3 float | the indirect light alone (``CubeGI``) |
| ``COLOR_0`` | VEC4 | the light scaled by ``2^exposure`` and clamped to [0, 1], for a viewer that shows vertex colours |
| ``_CUBEGI_LIGHT_<GROUP>`` | VEC3 float | per light group of the view layer (``CubeGI_group_<name>``): that group's light alone, linear |

``asset.extras.cubegi`` holds ``exposure`` (chosen so that 99% of the vertices' light is at most 1
in ``COLOR_0``) and the attribute names (``groups``: light group -> its attribute). An engine lights a diffuse surface as
``base_color * _CUBEGI_LIGHT`` (``docs/export.md``).

The user's meshes are as they were afterwards: the attributes the export adds are removed
again, also when it fails.
"""

import json
import math
import re
import struct

import bpy
import numpy as np

from ..cubegi_engine.errors import BakeError
from . import attributes

LIGHT, INDIRECT = "_CUBEGI_LIGHT", "_CUBEGI_INDIRECT"
DISPLAY = "CubeGI_export_display"  # the colour attribute that becomes COLOR_0, for the export's time
# COLOR_0 is scaled so that this share of the vertices' light (their brightest channel) fits
# in [0, 1]; the brightest 1% clip there (and only there).
DISPLAY_QUANTILE = 0.99
_GLB_JSON, _GLB_BIN = 0x4E4F534A, 0x004E4942


def baked_meshes(scene):
    """The meshes of the scene's objects that hold a bake's light, each once."""
    found = {}
    for ob in scene.objects:
        if ob.type == "MESH" and {attributes.TOTAL, attributes.INDIRECT} <= attributes.owned(ob.data):
            found.setdefault(ob.data.name_full, ob.data)
    return list(found.values())


def display_exposure(lights):
    """The exposure (stops) that maps the :data:`DISPLAY_QUANTILE` of the light to 1."""
    brightest = np.concatenate([v.max(axis=1) for v in lights]) if lights else np.zeros(0)
    level = float(np.quantile(brightest, DISPLAY_QUANTILE)) if len(brightest) else 0.0
    return -math.log2(level) if level > 0 and math.isfinite(level) else 0.0


def group_attributes(groups):
    """``{light group: glTF attribute}``: ``_CUBEGI_LIGHT_`` and the name in capitals, anything
    but letters and digits as ``_`` (a number added where two would be the same)."""
    out, used = {}, set()
    for group in sorted(groups):
        name = LIGHT + "_" + re.sub(r"[^A-Za-z0-9]", "_", group).upper()
        candidate, k = name, 2
        while candidate in used:
            candidate, k = f"{name}_{k}", k + 1
        used.add(candidate)
        out[group] = candidate
    return out


def write_glb(context, path):
    """Export the scene to the glTF binary ``path`` with the baked light (module docstring);
    returns the exposure. A BakeError if nothing in the scene holds a bake."""
    meshes = baked_meshes(context.scene)
    if not meshes:
        raise BakeError("nothing in the scene holds CubeGI's light: bake first")
    lights = {m.name_full: attributes.read(m, attributes.TOTAL) for m in meshes}
    exposure = display_exposure(list(lights.values()))
    prefix = attributes.GROUP_PREFIX
    groups = group_attributes({n[len(prefix):] for m in meshes for n in attributes.owned(m) if n.startswith(prefix)})
    added = []
    try:
        for mesh in meshes:
            light = lights[mesh.name_full]
            layers = [(LIGHT, light), (INDIRECT, attributes.read(mesh, attributes.INDIRECT))]
            layers += [(groups[n[len(prefix):]], attributes.read(mesh, n)) for n in sorted(attributes.owned(mesh)) if n.startswith(prefix)]
            for name, values in layers:
                mesh.attributes.new(name, "FLOAT_VECTOR", "POINT").data.foreach_set("vector", values.astype(np.float32).ravel())
                added.append((mesh, name))
            rgba = np.ones((len(light), 4), dtype=np.float32)
            rgba[:, :3] = np.clip(light * 2.0 ** exposure, 0.0, 1.0)
            names = attributes.colour_names(mesh)
            mesh.attributes.new(DISPLAY, "FLOAT_COLOR", "POINT").data.foreach_set("color", rgba.ravel())
            added.append((mesh, DISPLAY))
            attributes.put_colour_names(mesh, names)
        result = bpy.ops.export_scene.gltf(
            filepath=path, export_format="GLB", export_attributes=True, export_vertex_color="NAME",
            export_vertex_color_name=DISPLAY, export_all_vertex_colors=False,
        )
        if result != {"FINISHED"}:
            raise BakeError("Blender's glTF exporter did not finish")
    finally:
        for mesh, name in reversed(added):
            if name in mesh.attributes:
                names = attributes.colour_names(mesh)
                mesh.attributes.remove(mesh.attributes[name])
                attributes.put_colour_names(mesh, names)
    _add_asset_extras(path, {"cubegi": {
        "exposure": exposure, "light": LIGHT, "indirect": INDIRECT, "groups": groups,
        "color_0": f"{LIGHT} x 2^exposure, clamped to [0, 1]",
        "units": "diffuse light (irradiance / pi), linear: a surface shows base_color x light",
    }})
    return exposure


def read_glb(path):
    """``(document, binary chunk)`` of a .glb file."""
    with open(path, "rb") as fh:
        data = fh.read()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF" or version != 2 or length != len(data):
        raise BakeError(f"{path!r} is not a glTF 2.0 binary")
    json_len, json_type = struct.unpack_from("<II", data, 12)
    doc = json.loads(data[20 : 20 + json_len])
    blob = b""
    if 20 + json_len < len(data):
        bin_len, bin_type = struct.unpack_from("<II", data, 20 + json_len)
        if bin_type == _GLB_BIN:
            blob = data[28 + json_len : 28 + json_len + bin_len]
    return doc, blob


def _add_asset_extras(path, extras):
    """Rewrite the .glb at ``path`` with ``extras`` merged into ``asset.extras``."""
    doc, blob = read_glb(path)
    doc.setdefault("asset", {}).setdefault("extras", {}).update(extras)
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)  # chunks are 4-byte aligned; JSON pads with spaces
    chunks = struct.pack("<II", len(text), _GLB_JSON) + text
    if blob:
        blob += b"\0" * (-len(blob) % 4)
        chunks += struct.pack("<II", len(blob), _GLB_BIN) + blob
    with open(path, "wb") as fh:
        fh.write(struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks)
