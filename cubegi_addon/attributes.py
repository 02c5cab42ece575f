"""CubeGI's colour attributes on meshes: names, ownership, writing, clearing.

Output contract: FLOAT_COLOR attributes on the POINT domain, ``CubeGI_direct``,
``CubeGI_bounce_1`` .. ``CubeGI_bounce_N``, ``CubeGI`` (the sum of the bounces: the indirect
light) and ``CubeGI_total`` (direct plus indirect), holding diffuse light (irradiance / pi);
optionally ``CubeGI_lit``, the lit colour (albedo times direct plus indirect light) for
display and export. Where the view layer has light groups, ``CubeGI_group_<name>`` per group:
the light (direct plus indirect) of that group's lights, world and emitters. A bake with a Cycles reference also writes ``CubeGI_ref_direct`` and
``CubeGI_ref_indirect`` (the same quantities from Cycles); a bake without one leaves
earlier reference attributes alone.

Ownership: CubeGI touches only what it made. Every attribute it writes is listed in the
mesh's hidden ID property ``_cubegi_attributes``; it replaces and removes only listed
attributes (of its own type and domain). Anything else of the mesh with one of CubeGI's
names (an attribute of the user's, a UV map, a vertex group) is a clash: the bake is
refused before it starts, naming the mesh and the clash (:func:`check_clashes`).
"""

import re
from enum import StrEnum

import numpy as np

from ..cubegi_engine.errors import BakeError

DIRECT = "CubeGI_direct"
INDIRECT = "CubeGI"
TOTAL = "CubeGI_total"
LIT = "CubeGI_lit"
REF_DIRECT = "CubeGI_ref_direct"
REF_INDIRECT = "CubeGI_ref_indirect"
OWNED_KEY = "_cubegi_attributes"
TYPE, DOMAIN = "FLOAT_COLOR", "POINT"
_OWN = re.compile(r"^CubeGI(_direct|_total|_lit|_bounce_\d+|_group_.+)?$")
GROUP_PREFIX = "CubeGI_group_"
_REF = re.compile(r"^CubeGI_ref_(direct|indirect)$")


class LitMode(StrEnum):
    """Whether a bake writes ``CubeGI_lit``, and of what light: none; albedo times all light
    (the complete lighting, for export); albedo times the indirect light (for engines that
    light directly themselves). False for NONE."""

    NONE = "NONE"
    ALL = "ALL"
    INDIRECT = "INDIRECT"

    def __bool__(self):
        return self is not LitMode.NONE

    @classmethod
    def of(cls, value) -> "LitMode":
        """The mode of ``value``: a LitMode, its name in any case, or None (none); else BakeError."""
        if value is None or isinstance(value, cls):
            return cls.NONE if value is None else value
        try:
            return cls(str(value).upper())
        except ValueError:
            raise BakeError(f"lit colour must be one of ALL, INDIRECT or none, got {value!r}") from None


# The Lit Color setting's items (the panel, the bake operator): (mode, label, help).
LIT_ITEMS = (
    (LitMode.NONE.value, "None", "Write no lit colour"),
    (LitMode.ALL.value, "Direct + Indirect", "CubeGI_lit = albedo x (direct + indirect light): the complete lighting, for export"),
    (LitMode.INDIRECT.value, "Indirect Only", "CubeGI_lit = albedo x indirect light: for engines that light directly themselves"),
)


def bounce_name(k):
    return f"CubeGI_bounce_{k}"


def group_name(group):
    """The attribute of light group ``group``'s light."""
    return GROUP_PREFIX + group


def is_own(name):
    """True for the names a bake writes (and a new bake replaces)."""
    return bool(_OWN.match(name))


def is_reference(name):
    """True for the Cycles reference attributes (replaced only by a bake with a reference)."""
    return bool(_REF.match(name))


def is_any(name):
    return is_own(name) or is_reference(name)


def owned(mesh):
    """Names of the attributes of ``mesh`` that CubeGI wrote (listed, and of its type)."""
    listed = set(mesh.get(OWNED_KEY, ()))
    return {a.name for a in mesh.attributes if a.name in listed and a.data_type == TYPE and a.domain == DOMAIN}


def _mark(mesh, names):
    if names:
        mesh[OWNED_KEY] = sorted(names)
    elif OWNED_KEY in mesh:
        del mesh[OWNED_KEY]


def clashes(mesh, names, vertex_groups=()):
    """What of ``mesh`` (and its object's ``vertex_groups`` names) not made by CubeGI bears
    one of ``names``: a list of descriptions, empty if none."""
    mine = owned(mesh)
    uv = {u.name for u in mesh.uv_layers}
    found = []
    for name in names:
        attr = mesh.attributes.get(name)
        if attr is not None and name not in mine:
            kind = "UV map" if name in uv else f"attribute ({attr.data_type} on {attr.domain})"
            found.append(f"{kind} {name!r}")
        if name in vertex_groups:
            found.append(f"vertex group {name!r}")
    return found


def check_clashes(pairs, names):
    """Refuse (BakeError) if any ``(object, mesh)`` of ``pairs`` has data of the user's under a
    name in ``names``; one line naming the first mesh and clash (and how many more)."""
    problems = []
    for ob, mesh in pairs:
        for clash in clashes(mesh, names, {g.name for g in ob.vertex_groups}):
            problems.append(f"mesh {mesh.name!r} (object {ob.name!r}) has a {clash} that CubeGI did not make")
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise BakeError(f"{problems[0]}{more}; CubeGI writes only its own attributes: rename it, then bake again")


def bake_names(bounces, lit=False, reference=False, groups=()):
    """Every name a bake with these options may write."""
    names = [DIRECT, INDIRECT, TOTAL] + [bounce_name(k) for k in range(1, int(bounces) + 1)] + [group_name(g) for g in groups]
    if lit:
        names.append(LIT)
    if reference:
        names += [REF_DIRECT, REF_INDIRECT]
    return names


def light_layers(direct, indirect, bounces=(), albedo=None, lit=LitMode.NONE):
    """The light layers of points (every value ``(s, 3)``): name -> values. ``CubeGI_direct``,
    ``CubeGI``, ``CubeGI_total``, ``CubeGI_bounce_k`` for each of ``bounces``, and with
    ``lit`` (a :class:`LitMode`) ``CubeGI_lit``: ``albedo`` times all light, or the indirect
    light alone. The one place that knows which light each layer holds."""
    lit = LitMode.of(lit)
    layers = {DIRECT: direct}
    layers.update((bounce_name(k), b) for k, b in enumerate(bounces, start=1))
    layers[INDIRECT] = indirect
    layers[TOTAL] = direct + indirect
    if lit:
        layers[LIT] = albedo * (indirect if lit == LitMode.INDIRECT else direct + indirect)
    return layers


def write_targets(targets, meshes, layers):
    """Write point ``layers`` (name -> ``(s, 3)``) to each target's mesh, in place (a mesh
    None, gone or changed since the bake, is skipped)."""
    for target, mesh in zip(targets, meshes):
        if mesh is None:
            continue
        for name, values in layers.items():
            put(mesh, name, vertex_values(target, values))
        mesh.update()


def vertex_values(target, point_values):
    """Per-vertex ``(v, 3)`` mean over each vertex's corners of per-point values ``(s, 3)``
    (zero for a vertex with no corner)."""
    vertex, point, weight = _vertex_mean(target)
    values = np.asarray(point_values, dtype=np.float64)
    if weight is None:  # one point per vertex: its value
        out = np.zeros((target.vertex_count, 3))
        out[vertex] = values[point]
        return out
    part = values[point] * weight[:, None]
    return np.stack([np.bincount(vertex, part[:, c], minlength=target.vertex_count) for c in range(3)], axis=1)


def _vertex_mean(target):
    """How a target's vertex means are made of its points, made once per target:
    ``(vertex, point, weight)`` over the distinct (vertex, point) pairs of its corners, each
    weighted by its share of the vertex's corners; weight None where each vertex has one
    point (smooth shading: every corner of a vertex is one point)."""
    key = (id(target.loop_point), id(target.loop_vertex))
    cached = target.__dict__.get("_vertex_mean")
    if cached is not None and cached[0] == key:
        return cached[1]
    vertex = np.asarray(target.loop_vertex, dtype=np.int64)
    point = np.asarray(target.loop_point, dtype=np.int64)
    span = int(point.max()) + 1 if len(point) else 1
    pairs, corners = np.unique(vertex * span + point, return_counts=True)
    vertex, point = pairs // span, pairs % span
    per_vertex = np.bincount(vertex, minlength=target.vertex_count)
    weight = None if np.all(per_vertex[vertex] == 1) else corners / np.bincount(vertex, corners, minlength=target.vertex_count)[vertex]
    made = (vertex, point, weight)
    target.__dict__["_vertex_mean"] = (key, made)
    return made


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
    """Remove the attributes CubeGI made on ``mesh`` whose names ``which`` accepts; returns
    their names. Nothing of the user's is touched."""
    before = colour_names(mesh)
    mine = owned(mesh)
    names = [n for n in mine if which(n)]
    for name in names:
        mesh.attributes.remove(mesh.attributes[name])
    _mark(mesh, mine - set(names))
    put_colour_names(mesh, before)
    return names


def _create(mesh, name, rgba):
    # The first colour attribute of a mesh becomes its render colour attribute, which a
    # Color Attribute node with no name reads: CubeGI's light would become the next bake's
    # albedo. The render colour attribute stays the user's (or none).
    before = colour_names(mesh)
    attr = mesh.attributes.new(name, TYPE, DOMAIN)
    attr.data.foreach_set("color", rgba.ravel())
    put_colour_names(mesh, before)
    _mark(mesh, owned(mesh) | {name})


def write(mesh, layers):
    """Replace CubeGI's attributes of ``mesh`` by ``layers``: a dict name -> ``(v, 3)``.

    The bake's own names are always replaced; the reference names only when ``layers`` has
    them. The caller has checked for clashes (:func:`check_clashes`)."""
    prepared = {name: _rgba(mesh, name, values) for name, values in layers.items()}
    with_reference = any(is_reference(n) for n in prepared)
    clear(mesh, is_any if with_reference else is_own)
    for name, rgba in prepared.items():
        _create(mesh, name, rgba)


def put(mesh, name, values):
    """Create or overwrite CubeGI's one layer ``name`` of ``mesh`` with ``values (v, 3)``."""
    rgba = _rgba(mesh, name, values)
    if name in owned(mesh):
        mesh.attributes[name].data.foreach_set("color", rgba.ravel())
    else:
        _create(mesh, name, rgba)


def read(mesh, name):
    """An attribute's RGB values ``(v, 3)`` float64."""
    attr = mesh.attributes[name]
    data = np.empty(len(attr.data) * 4, dtype=np.float32)
    attr.data.foreach_get("color", data)
    return data.reshape(-1, 4)[:, :3].astype(np.float64)


def snapshot(mesh):
    """CubeGI's attributes of ``mesh`` as they are now, its ownership list, and which colour
    attributes are active and the default (render) ones, for :func:`restore`."""
    saved = []
    for name in owned(mesh):
        data = np.empty(len(mesh.attributes[name].data) * 4, dtype=np.float32)
        mesh.attributes[name].data.foreach_get("color", data)
        saved.append((name, data))
    listed = list(mesh[OWNED_KEY]) if OWNED_KEY in mesh else None
    return saved, listed, *colour_names(mesh)


def restore(mesh, snap):
    """Put back what :func:`snapshot` saw, removing anything CubeGI wrote since."""
    saved, listed, active, default = snap
    clear(mesh, is_any)
    for name, data in saved:
        mesh.attributes.new(name, TYPE, DOMAIN).data.foreach_set("color", data)
    if listed is None:
        _mark(mesh, set())
    else:
        mesh[OWNED_KEY] = listed
    put_colour_names(mesh, (active, default))


def colour_names(mesh):
    """``(active, render)``: the names of the mesh's active and render (default) colour
    attributes ("" for none)."""
    colours = mesh.color_attributes
    return colours.active_color_name, colours.default_color_name


def put_colour_names(mesh, names):
    """Make the colour attributes named ``(active, render)`` the active and the render ones,
    "" (none) where a name is empty or gone. Named outright, also where there was none: adding
    a mesh's first colour attribute makes it both; removing one hands its role to another on
    4.5 and leaves its name behind from 5.3."""
    colours = mesh.color_attributes
    active, render = names
    colours.active_color_name = active if active and active in colours else ""
    colours.default_color_name = render if render and render in colours else ""
