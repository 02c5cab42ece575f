"""CubeGI's colour attributes on meshes: names, writing, clearing.

Output contract: FLOAT_COLOR attributes on the POINT domain, ``CubeGI_direct``,
``CubeGI_bounce_1`` .. ``CubeGI_bounce_N``, ``CubeGI`` (the sum of the bounces: the indirect
light) and ``CubeGI_total`` (direct plus indirect), holding diffuse light (irradiance / pi);
optionally ``CubeGI_lit``, the lit colour (albedo times
direct plus indirect light) for display and export. A bake with a Cycles reference also
writes ``CubeGI_ref_direct`` and ``CubeGI_ref_indirect`` (the same quantities from Cycles);
a bake without one leaves earlier reference attributes alone. Nothing else of the mesh is
touched.
"""

import re

import numpy as np

PREFIX = "CubeGI"
DIRECT = "CubeGI_direct"
TOTAL = "CubeGI"
TOTAL_LIGHT = "CubeGI_total"
LIT = "CubeGI_lit"
REF_DIRECT = "CubeGI_ref_direct"
REF_INDIRECT = "CubeGI_ref_indirect"
_OWN = re.compile(r"^CubeGI(_direct|_total|_lit|_bounce_\d+)?$")
_REF = re.compile(r"^CubeGI_ref_(direct|indirect)$")


def bounce_name(k):
    return f"CubeGI_bounce_{k}"


def is_own(name):
    """True for the names a bake writes (and a new bake replaces)."""
    return bool(_OWN.match(name))


def is_reference(name):
    """True for the Cycles reference attributes (replaced only by a bake with a reference)."""
    return bool(_REF.match(name))


def is_any(name):
    return is_own(name) or is_reference(name)


def vertex_values(target, point_values):
    """Per-vertex ``(v, 3)`` mean over each vertex's corners of per-point values ``(s, 3)``."""
    corner = point_values[target.loop_point]
    count = np.bincount(target.loop_vertex, minlength=target.vertex_count).astype(np.float64)
    out = np.stack(
        [np.bincount(target.loop_vertex, corner[:, c], minlength=target.vertex_count) for c in range(3)], axis=1
    )
    return out / np.maximum(count, 1.0)[:, None]


def sanitise(values):
    """No NaN, Inf or negative light reaches an attribute."""
    v = np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    return np.clip(v, 0.0, np.finfo(np.float32).max)


def _rgba(mesh, name, values):
    """Sanitised ``(v, 3)`` light as the flat float32 RGBA an attribute takes."""
    v = sanitise(values)
    if v.shape != (len(mesh.vertices), 3):
        raise ValueError(f"{mesh.name}: {name} has shape {v.shape}, mesh has {len(mesh.vertices)} vertices")
    rgba = np.ones((len(v), 4), dtype=np.float32)
    rgba[:, :3] = v
    return rgba


def clear(mesh, which=is_own):
    """Remove the attributes of ``mesh`` whose names ``which`` accepts; returns their names."""
    names = [a.name for a in mesh.attributes if which(a.name)]
    for name in names:
        mesh.attributes.remove(mesh.attributes[name])
    return names


def write(mesh, layers):
    """Replace CubeGI's attributes of ``mesh`` by ``layers``: a dict name -> ``(v, 3)``.

    The bake's own names are always replaced; the reference names only when ``layers`` has
    them."""
    prepared = {name: _rgba(mesh, name, values) for name, values in layers.items()}
    with_reference = any(is_reference(n) for n in prepared)
    clear(mesh, is_any if with_reference else is_own)
    for name, rgba in prepared.items():
        attr = mesh.attributes.new(name, "FLOAT_COLOR", "POINT")
        attr.data.foreach_set("color", rgba.ravel())


def put(mesh, name, values):
    """Create or overwrite the one layer ``name`` of ``mesh`` with ``values (v, 3)``."""
    rgba = _rgba(mesh, name, values)
    attr = mesh.attributes.get(name)
    if attr is None or attr.data_type != "FLOAT_COLOR" or attr.domain != "POINT":
        if attr is not None:
            mesh.attributes.remove(attr)
        attr = mesh.attributes.new(name, "FLOAT_COLOR", "POINT")
    attr.data.foreach_set("color", rgba.ravel())


def read(mesh, name):
    """An attribute's RGB values ``(v, 3)`` float64."""
    attr = mesh.attributes[name]
    data = np.empty(len(attr.data) * 4, dtype=np.float32)
    attr.data.foreach_get("color", data)
    return data.reshape(-1, 4)[:, :3].astype(np.float64)


def snapshot(mesh):
    """CubeGI's attributes of ``mesh`` as they are now, and which colour attributes are
    active and the default (render) ones, for :func:`restore`."""
    saved = []
    for a in mesh.attributes:
        if is_any(a.name):
            width = 4 if a.data_type in {"FLOAT_COLOR", "BYTE_COLOR"} else None
            key = "color" if width else "value"
            data = np.empty(len(a.data) * (width or 1), dtype=np.float32)
            a.data.foreach_get(key, data)
            saved.append((a.name, a.data_type, a.domain, key, data))
    colours = mesh.color_attributes
    return saved, colours.active_color_name, colours.default_color_name


def restore(mesh, snap):
    """Put back what :func:`snapshot` saw, removing anything CubeGI wrote since."""
    saved, active, default = snap
    clear(mesh, is_any)
    for name, data_type, domain, key, data in saved:
        attr = mesh.attributes.new(name, data_type, domain)
        attr.data.foreach_set(key, data)
    colours = mesh.color_attributes
    if active and active in colours:
        colours.active_color_name = active
    if default and default in colours:
        colours.default_color_name = default
