"""Direct light from Blender's light types, in Cycles' units, as diffuse light (E / pi).

Pure numpy; must not import bpy.

Formulas (matched against Cycles 5.0 bakes; the measurements are in tests/blender/test_cycles.py):

* Point of power P (W) and radius r, colour c: ``c P cos / (4 pi^2 (d^2 + r^2))``.
* Spot: the point formula times Cycles' cone attenuation
  ``smoothstep((cos_axis - cos_half) / ((1 - cos_half) * blend))`` (``spot.h``); radiant
  intensity does not depend on the cone angle (P / 4 pi, as for a point light).
* Sun of strength S (W/m^2): ``c S cos / pi``.
* Area of power P and area A, one-sided along its local -Z: radiance ``L = c P / (pi A)``,
  diffuse light ``L * F`` with F the exact form factor of the light's polygon (Lambert's
  formula), after clipping the polygon to the receiver's upper hemisphere. Disks and
  ellipses are regular 32-gons of the same area.

Shadows come from depth cube maps rendered at the light (see :func:`shadow_visibility`).
"""

from dataclasses import dataclass, field, fields

import numpy as np

from . import cubemap
from .geometry import cross, cut_triangles, in_pieces, piece_size
from .lifts import LIFT, map_points, ray_starts
from .working import made_once

__all__ = ["Light", "area_polygon", "area_samples", "spot_attenuation", "polygon_form_factor", "unshadowed", "shadow_visibility",
           "ortho_visibility", "DepthMap", "Receivers", "Occluders", "OrthoView"]

DISK_SEGMENTS = 32


@dataclass
class Light:
    """One light in world space.

    kind: 'POINT', 'SPOT', 'SUN' or 'AREA'. colour: linear RGB times power (W for point,
    spot, area; W/m^2 for sun). direction: unit vector the light faces (local -Z).
    polygon: ``(k, 3)`` world corners of an area light, counter-clockwise seen from the side
    it lights. samples: ``(m, 3)`` points on the light from which shadows are rendered.
    name: what notes and reports call it. key: its identity among the scene's lights,
    assigned once by the scene reader (each instance of a light its own; see
    :func:`light_keys`), the key of its direct light and of its source in relighting.
    shadow_size: its shadow maps' edge in texels (0: the bake settings' for its kind).
    group: the light group it belongs to ("" for none; see the add-on's light groups).
    angle: a sun's angular diameter in radians (its Angle; 0: sharp shadows).
    """

    kind: str
    colour: np.ndarray
    position: np.ndarray
    direction: np.ndarray
    radius: float = 0.0
    spot_size: float = np.pi
    spot_blend: float = 0.0
    polygon: np.ndarray | None = None
    area: float = 0.0
    casts_shadow: bool = True
    name: str = ""
    samples: np.ndarray | None = field(default=None)
    key: str = ""
    shadow_size: int = 0
    group: str = ""
    angle: float = 0.0

    @property
    def shadow_key(self) -> str:
        """What the light's kept shadow maps are found by: its key (its name where it has
        none), which a rename keeps."""
        return self.key or self.name


def light_keys(lights):
    """Each light's source key, in order: its own :attr:`Light.key`, or ``"light:#k"`` by
    position for a light made without one. Two lights never share a key: instances of one
    lamp are as many lights (ValueError if a reader gave two lights one key)."""
    keys = [light.key or f"light:#{k}" for k, light in enumerate(lights)]
    if len(set(keys)) != len(keys):
        shared = sorted({k for k in keys if keys.count(k) > 1})
        raise ValueError(f"two lights share the key {shared[0]!r}")
    return keys


def area_polygon(shape, size_x, size_y):
    """Local-space corners ``(k, 3)`` of an area light shape (light faces -Z).

    Ordered so that the polygon winds clockwise seen from +Z, i.e. counter-clockwise seen
    from the lit side (-Z). Disks and ellipses are scaled so their area is exact.
    """
    if shape in ("SQUARE", "RECTANGLE"):
        hx, hy = 0.5 * size_x, 0.5 * (size_y if shape == "RECTANGLE" else size_x)
        pts = np.array([[-hx, -hy], [-hx, hy], [hx, hy], [hx, -hy]], dtype=np.float64)
    elif shape in ("DISK", "ELLIPSE"):
        rx, ry = 0.5 * size_x, 0.5 * (size_y if shape == "ELLIPSE" else size_x)
        a = -np.arange(DISK_SEGMENTS) * (2.0 * np.pi / DISK_SEGMENTS)
        # A regular k-gon inscribed in the unit circle has area k/2 sin(2 pi / k); scale to pi.
        k = DISK_SEGMENTS
        s = np.sqrt(np.pi / (0.5 * k * np.sin(2.0 * np.pi / k)))
        pts = np.stack([rx * s * np.cos(a), ry * s * np.sin(a)], axis=1)
    else:
        raise ValueError(f"unknown area light shape {shape!r}")
    return np.concatenate([pts, np.zeros((len(pts), 1))], axis=1)


def area_samples(shape, size_x, size_y, per_side):
    """Stratified local points ``(per_side^2, 3)`` on an area light, for shadow maps."""
    g = (np.arange(per_side) + 0.5) / per_side
    u, v = np.meshgrid(g, g, indexing="ij")
    u, v = u.ravel(), v.ravel()
    if shape in ("SQUARE", "RECTANGLE"):
        sy = size_y if shape == "RECTANGLE" else size_x
        pts = np.stack([(u - 0.5) * size_x, (v - 0.5) * sy], axis=1)
    else:
        sy = size_y if shape == "ELLIPSE" else size_x
        r, a = np.sqrt(u), 2.0 * np.pi * v
        pts = np.stack([0.5 * size_x * r * np.cos(a), 0.5 * sy * r * np.sin(a)], axis=1)
    return np.concatenate([pts, np.zeros((len(pts), 1))], axis=1)


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def spot_attenuation(light, to_point):
    """Cycles' spot cone factor for unit directions ``to_point`` ``(s, 3)`` from the light."""
    cos_axis = to_point @ light.direction
    cos_half = np.cos(0.5 * light.spot_size)
    smooth = (1.0 - cos_half) * light.spot_blend
    if smooth <= 0.0:
        return (cos_axis > cos_half).astype(np.float64)
    return _smoothstep((cos_axis - cos_half) / smooth)


def polygon_form_factor(points, normals, polygon):
    """Form factor from receivers to a one-sided polygon, clipped to their hemispheres.

    points, normals: ``(s, 3)``; polygon: ``(k, 3)`` (or ``(s, k, 3)``, one per receiver) counter-clockwise
    seen from its lit side. Returns ``(s,)`` in [0, 1]: the cosine-weighted fraction of the
    hemisphere the polygon covers (Lambert's formula ``1/(2 pi) sum_i theta_i n . g_i``)."""
    each = np.ndim(polygon) == 3
    if len(points) > piece_size():  # its (s, 2k, 3) temporaries, a chunk of points at a time
        return np.concatenate(in_pieces(lambda sl: polygon_form_factor(points[sl], normals[sl], polygon[sl] if each else polygon), len(points)))
    s, k = len(points), np.shape(polygon)[-2]
    rel = (polygon if each else polygon[None, :, :]) - points[:, None, :]  # (s, k, 3)
    h = np.einsum("skc,sc->sk", rel, normals)  # height above the receiver's tangent plane
    nxt = np.roll(np.arange(k), -1)
    a, b = rel, rel[:, nxt]
    ha, hb = h, h[:, nxt]
    # Sutherland-Hodgman against the plane h >= 0, two candidate slots per edge.
    t = np.where(ha != hb, ha / np.where(ha != hb, ha - hb, 1.0), 0.0)
    cut = a + t[..., None] * (b - a)
    slots = np.stack([a, cut], axis=2).reshape(s, 2 * k, 3)
    keep = np.stack([ha >= 0, (ha >= 0) != (hb >= 0)], axis=2).reshape(s, 2 * k)
    order = np.argsort(~keep, axis=1, kind="stable")
    slots = np.take_along_axis(slots, order[..., None], axis=1)
    count = keep.sum(axis=1)
    j = np.arange(2 * k)[None, :]
    valid = j < count[:, None]
    nxt_j = np.where(j + 1 < count[:, None], j + 1, 0)
    u = slots / np.maximum(np.linalg.norm(slots, axis=-1, keepdims=True), 1e-30)
    w = np.take_along_axis(u, nxt_j[..., None], axis=1)
    turn = cross(w, u)  # counter-clockwise seen from the receiver: w x u faces it
    sin_t = np.linalg.norm(turn, axis=-1)
    cos_t = np.einsum("sjc,sjc->sj", u, w)
    theta = np.arctan2(sin_t, cos_t)
    g = turn / np.maximum(sin_t, 1e-30)[..., None]
    term = theta * np.einsum("sjc,sc->sj", g, normals)
    f = np.where(valid & (count[:, None] >= 3), term, 0.0).sum(axis=1) / (2.0 * np.pi)
    return np.clip(f, 0.0, 1.0)


def unshadowed(light, points, normals):
    """Diffuse light ``(s, 3)`` from one light at every receiver, without shadows."""
    colour = np.asarray(light.colour, dtype=np.float64)
    if light.kind == "SUN":
        cos = np.maximum(0.0, normals @ (-light.direction))
        return (cos / np.pi)[:, None] * colour
    if light.kind in ("POINT", "SPOT"):
        rel = light.position - points
        d2 = np.einsum("sc,sc->s", rel, rel)
        dirs = rel / np.sqrt(np.maximum(d2, 1e-300))[:, None]
        cos = np.maximum(0.0, np.einsum("sc,sc->s", normals, dirs))
        val = cos / (4.0 * np.pi**2 * (d2 + light.radius**2))
        if light.kind == "SPOT":
            val = val * spot_attenuation(light, -dirs)
        return val[:, None] * colour
    if light.kind == "AREA":
        if light.area <= 0.0:
            return np.zeros((len(points), 3))
        radiance = colour / (np.pi * light.area)
        front = (points - light.position) @ light.direction > 0.0
        ff = polygon_form_factor(points, normals, light.polygon) * front
        return ff[:, None] * radiance
    raise ValueError(f"unknown light kind {light.kind!r}")


# Shadow test margins (see _occluded): in texel footprints, as a share of the receiver's distance
# along the ray, and as a share of the scene's size (GPU float32 distances); the cosine below which
# the slope term stops growing.
BIAS_FOOTPRINTS, BIAS_OF_DEPTH, SLOPE_OF_SCALE, MIN_COS = 0.1, 1e-5, 1e-4, 0.2
OWN_PLANE = 1e-3  # a plane this share of the lift off either end of it passes through that end (_occluded)


@dataclass(frozen=True)
class DepthMap:
    """What a shadow map saw per texel, each ``(f, n, n)``: the triangle (``tid``, -1 where
    nothing), its distance (``dist``) and whether it was seen from behind (``back``); ``f``
    is 6 for a cube map, 1 for an orthographic map (a sun's)."""

    tid: np.ndarray
    dist: np.ndarray
    back: np.ndarray

    @property
    def size(self) -> int:
        return int(self.dist.shape[-1])

    @property
    def nbytes(self) -> int:
        return int(self.tid.nbytes + self.dist.nbytes + self.back.nbytes)


@dataclass(frozen=True)
class Receivers:
    """The points a shadow test asks about: ``points``, ``normals`` ``(s, 3)`` and ``ids``
    ``(s,)``, each one's index among the occluders' vertices (-1: not among them)."""

    points: np.ndarray
    normals: np.ndarray
    ids: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def __getitem__(self, which) -> "Receivers":
        return Receivers(self.points[which], self.normals[which], self.ids[which])


@dataclass(frozen=True)
class Occluders:
    """The geometry a shadow map was drawn of: ``triangles (t, 3)`` into ``vertices (v, 3)``,
    the scene's size ``scale`` and ``sides`` (``SceneArrays.sides()``: two-sided sheets, or
    None)."""

    triangles: np.ndarray
    vertices: np.ndarray
    scale: float
    sides: tuple | None = None
    # A callable giving the host's ray caster over the same surfaces (made when first needed), or
    # None: a receiver the map cannot decide is asked by one ray (see _occluded). It is a static
    # function (gather.scene_occluders: the host's ``rays``), so a kept shadow keeps no renderer.
    rays: object = None
    # A callable giving geometry.inward of these surfaces, made once per scene (not per light).
    inward: object = None


@dataclass(frozen=True)
class OrthoView:
    """An orthographic shadow map's view: ``view_proj (4, 4)``, looking along ``axis`` from
    ``eye``, ``half_width`` across."""

    view_proj: np.ndarray
    axis: np.ndarray
    eye: np.ndarray
    half_width: float


@dataclass(frozen=True)
class _Lookup:
    """Each receiver's place in a depth map (``face``, ``row``, ``col``), its ray (from
    ``origins`` along ``u``, ``depth`` long), its surface's ``cos`` to the ray and its
    texel's ``footprint``."""

    face: np.ndarray
    row: np.ndarray
    col: np.ndarray
    origins: np.ndarray
    u: np.ndarray
    depth: np.ndarray
    cos: np.ndarray
    footprint: np.ndarray

    def __getitem__(self, which) -> "_Lookup":
        return _Lookup(*(getattr(self, f.name)[which] for f in fields(self)))


def shadow_visibility(receivers: Receivers, occluders: Occluders, eye, depth: DepthMap, reach=1, turn=None):
    """Whether each receiver sees ``eye``, from the depth cube map ``depth`` drawn at ``eye``
    of ``occluders``. ``reach``: how many texels around the receiver's own are asked (0: its
    own only); ``turn``: ``(3, 3)`` the cube map's rotation, if it was drawn turned.

    The receiver is lifted off its surface by a quarter of a texel's footprint and looked up
    in the map (see :func:`_occluded`); where the map cannot vouch for it, one ray decides
    (``occluders.rays``; :func:`_doubtful`). Returns ``(s,)`` float64 in {0, 1}.
    """
    if len(receivers) > piece_size():
        return np.concatenate(in_pieces(lambda sl: shadow_visibility(receivers[sl], occluders, eye, depth, reach, turn), len(receivers)))
    points, normals = receivers.points, receivers.normals
    n = depth.size
    rel = points - eye
    d = np.linalg.norm(rel, axis=1)
    footprint = d * (2.0 / n)
    lifted = points + normals * (LIFT * footprint)[:, None]
    rel2 = lifted - eye
    d2 = np.linalg.norm(rel2, axis=1)
    u = rel2 / np.maximum(d2, 1e-300)[:, None]
    local = rel2 if turn is None else rel2 @ turn  # the cube's own frame
    face, row, col, _, _ = cubemap.direction_to_texel(np.where(d2[:, None] > 0, local, 1.0), n)
    cos = np.abs(np.einsum("sc,sc->s", normals, rel / np.maximum(d, 1e-300)[:, None]))
    lookup = _Lookup(face, row, col, np.broadcast_to(eye, u.shape), u, d2, cos, footprint)
    occluded, doubt = _occluded(depth, lookup, receivers.ids, occluders, reach)
    _ask_rays(occluded, doubt, receivers, occluders, footprint, eye=eye)
    return (~occluded).astype(np.float64)


def _occluded(depth_map: DepthMap, lookup: _Lookup, point_ids, occluders: Occluders, reach=1):
    """Whether something lies between the light and each (lifted) receiver.

    The map says which triangles lie towards the light in the receiver's texel and its
    neighbours within ``reach`` texels (on the same face); each one's depth is its plane cut by
    the receiver's exact ray, not the texel's depth. So an occluder closer to the receiver than
    a texel's footprint (a rug on a floor) still shadows it, and a receiver on the line where
    two surfaces meet is decided by the surface's plane, not by which side of a texel edge it
    falls. A triangle of the receiver's own never shadows it.

    * A front face in the receiver's own texel shadows it if its plane is nearer along the
      ray by more than a small slope-scaled bias (which keeps a curved surface from
      shadowing itself) and the texel's depth is not clearly behind the receiver. (Front
      faces in the neighbouring texels are not asked: they would widen every shadow.)
    * A back face: a receiver the light reaches faces it, so a texel that sees a surface from
      behind sees another surface; up to the receiver's depth that surface shadows it (a wall's
      edge under a ceiling, a floor's edge under a wall the light is behind), as it does a ray
      leaving that point.

    Returns ``(occluded, doubt)``, both ``(s,)`` bool: ``doubt`` marks the receivers the map
    cannot vouch for, where the occluders have a ray caster (:func:`_doubtful`; a shadow cast
    by a plane beside its triangle); none without one.
    """
    face, row, col, footprint, cos = lookup.face, lookup.row, lookup.col, lookup.footprint, lookup.cos
    triangles, sides = occluders.triangles, occluders.sides
    n = depth_map.size
    r, c = cubemap.texels_around(row, col, n, reach)
    f = face[:, None]
    tid = depth_map.tid[f, r, c]
    seen = depth_map.dist[f, r, c].astype(np.float64)
    back = depth_map.back[f, r, c]
    if sides is not None:
        # A sheet's face on the far side from the receiver's (a twin, for a receiver on the
        # front or on a one-sided mesh) stands where a one-sided sheet's back face would be
        # seen: the back-face rule holds for it.
        tri_side, point_side = sides
        ts = tri_side[np.maximum(tid, 0)]
        ps = np.where(point_ids >= 0, point_side[np.maximum(point_ids, 0)], 0)[:, None]
        back = back | ((tid >= 0) & (ts > 0) & ((ts == 2) != (ps == 2)))
    centre = (np.arange(r.shape[1]) == r.shape[1] // 2)[None, :]  # the receiver's own texel
    k, j = np.nonzero((tid >= 0) & (centre | back))  # the only pairs that can shadow (above): cut those alone
    plane, on, own = np.full(tid.shape, np.nan), np.zeros(tid.shape, dtype=bool), np.zeros(tid.shape, dtype=bool)
    plane[k, j], on[k, j] = cut_triangles(lookup.origins[k], lookup.u[k], tid[k, j], triangles, occluders.vertices)
    own[k, j] = np.any(triangles[tid[k, j]] == point_ids[k, None], axis=1)
    depth = lookup.depth[:, None]
    # ``nearer`` and ``depth`` are exact (float64 plane cuts): their margin is a tenth of a
    # texel's footprint (slope-scaled) and a hundred-thousandth of the receiver's own distance,
    # never a share of the whole scene (a 1 cm gap under a room on a 2 km plane must hold).
    # ``seen`` comes from the GPU's float32 distances in the scene's unit frame: its margin
    # keeps a ten-thousandth of the scene's size.
    bias = (BIAS_FOOTPRINTS * footprint / np.maximum(cos, MIN_COS) + BIAS_OF_DEPTH * depth[:, 0])[:, None]
    slope = (footprint / np.maximum(cos, MIN_COS) + SLOPE_OF_SCALE * occluders.scale)[:, None]
    nearer = np.where(np.isnan(plane), seen, plane)
    front_occ = centre & ~back & (nearer < depth - bias) & (seen < depth + slope)
    back_occ = back & (nearer < depth + bias)
    occluding = (tid >= 0) & ~own & (front_occ | back_occ)
    occluded = np.any(occluding, axis=1)
    if occluders.rays is None:
        return occluded, np.zeros(len(occluded), dtype=bool)
    # A front face shadows by its plane; where the receiver's ray cuts that plane beside the
    # triangle and a texel around sees past the receiver (a shadow's edge within the texel)
    # the map cannot vouch for the shadow either. (A dense mesh's ray passes beside the
    # small triangle its texel saw, through the next one of the same surface: the texels
    # around all see that surface before the receiver.)
    sure = np.any(occluding & (back_occ | on), axis=1)
    sure |= _around(depth_map, np.maximum)[face, row, col] < lookup.depth - bias[:, 0]
    # A front face between the lifted receiver and its own surface (a rug 5 mm over a floor a coarse map lifts 2 cm): a ray decides.
    lift = (LIFT * footprint / np.maximum(cos, MIN_COS))[:, None]
    under = ~occluded & np.any(centre & ~back & (tid >= 0) & ~own & (plane > depth + OWN_PLANE * lift) & (plane < depth + lift * (1 - OWN_PLANE)), 1)
    return occluded, _doubtful(depth_map, lookup, point_ids, occluders, occluded, bias[:, 0]) | (occluded & ~sure) | under


def _around(depth_map: DepthMap, pick) -> np.ndarray:
    """``(f, n, n)``: the nearest (``pick``: ``np.minimum``) or farthest (``np.maximum``)
    front face's distance in each texel and the 8 around it on its face (a texel that sees
    no front face: infinitely far); made once per map."""
    def make():
        seen = np.where((depth_map.tid >= 0) & ~depth_map.back, depth_map.dist, np.inf).astype(np.float32)
        return cubemap.square_filter(seen, 1, pick)

    return made_once(depth_map, "_around_" + pick.__name__, make)


def _doubtful(depth_map: DepthMap, lookup: _Lookup, point_ids, occluders: Occluders, occluded, bias):
    """``(s,)`` bool: the receivers the map leaves lit but cannot vouch for: a front face in
    their texel or one of the 8 around it (not one of their own triangles) lies before them
    by more than the bias, and its plane passes before them along their ray (the light and
    they on opposite sides of it; a plane through them is their own surface's, one behind
    them cannot shadow them): a fold's rim or a slat smaller than a texel, a shadow's edge.
    ``bias (s,)``: :func:`_occluded`'s margin. A ray decides them (:func:`_ask_rays`)."""
    ask = np.flatnonzero(~occluded & (_around(depth_map, np.minimum)[lookup.face, lookup.row, lookup.col] < lookup.depth - bias))
    doubt = np.zeros(len(occluded), dtype=bool)
    if not len(ask):
        return doubt
    n = depth_map.size
    r, c = cubemap.texels_around(lookup.row[ask], lookup.col[ask], n)
    f = lookup.face[ask, None]
    tid, depth, b = depth_map.tid[f, r, c], lookup.depth[ask, None], bias[ask, None]
    near = (tid >= 0) & ~depth_map.back[f, r, c] & (depth_map.dist[f, r, c] < depth - b)
    k, j = np.nonzero(near)  # only these (receiver, texel) pairs are asked further
    t = tid[k, j]
    theirs = ~np.any(occluders.triangles[t] == point_ids[ask[k], None], axis=1)  # not the receiver's own triangle
    k, t = k[theirs], t[theirs]
    plane, _ = cut_triangles(lookup.origins[ask[k]], lookup.u[ask[k]], t, occluders.triangles, occluders.vertices)
    with np.errstate(invalid="ignore"):
        cut = plane < depth[k, 0] - b[k, 0]
    doubt[ask[k[cut]]] = True
    return doubt


def ortho_visibility(receivers: Receivers, occluders: Occluders, view: OrthoView, depth: DepthMap, looked_up=None):
    """Like :func:`shadow_visibility` for a sun: one orthographic depth map (``view``).
    ``looked_up``: the receivers' :func:`ortho_lookup`, where the caller has it."""
    if len(receivers) > piece_size():
        part = (lambda sl: None) if looked_up is None else (lambda sl: (looked_up[0][sl], looked_up[1][sl]))
        return np.concatenate(in_pieces(lambda sl: ortho_visibility(receivers[sl], occluders, view, depth, part(sl)), len(receivers)))
    lookup, inside = ortho_lookup(receivers, view, depth.size, occluders) if looked_up is None else looked_up
    occluded, doubt = _occluded(depth, lookup, receivers.ids, occluders)
    _ask_rays(occluded, doubt & inside, receivers, occluders, lookup.footprint, along=-view.axis)
    return (~occluded | ~inside).astype(np.float64)


def ortho_lookup(receivers: Receivers, view: OrthoView, n, occluders):
    """Each receiver's place in an orthographic map of edge ``n`` (``view``) of ``occluders``,
    lifted off its surface as the shadow test lifts it (:func:`~.lifts.map_points`): ``(_Lookup, inside
    (s,) bool)``."""
    points, normals, axis = receivers.points, receivers.normals, view.axis
    footprint = np.full(len(points), 2.0 * view.half_width / n)
    lifted = map_points(receivers, occluders, footprint)
    clip = np.concatenate([lifted, np.ones((len(points), 1))], axis=1) @ view.view_proj.T
    ndc = clip[:, :2] / clip[:, 3:4]
    col = np.clip(((ndc[:, 0] + 1.0) * 0.5 * n).astype(np.int64), 0, n - 1)
    row = np.clip(((ndc[:, 1] + 1.0) * 0.5 * n).astype(np.int64), 0, n - 1)
    distance = (lifted - view.eye) @ axis
    lookup = _Lookup(np.zeros(len(points), dtype=np.int64), row, col, lifted - distance[:, None] * axis,
                     np.broadcast_to(axis, lifted.shape), distance, np.abs(normals @ axis), footprint)
    return lookup, (np.abs(ndc) <= 1.0).all(axis=1)


def _ask_rays(occluded, doubt, receivers, occluders, footprint, eye=None, along=None):
    """Decide the ``doubt`` receivers (``(s,)`` bool; their maps' texels ``footprint (s,)``
    across) by a ray each through ``occluders.rays``, in place into ``occluded``: to ``eye``
    (3,), ending just short of it, or along the unit ``along`` without end (a sun); nothing
    where there is no caster."""
    ask = np.flatnonzero(doubt)
    if occluders.rays is None or not len(ask):
        return
    start = ray_starts(receivers, occluders, footprint, ask)
    reach = None
    if eye is None:
        towards = np.broadcast_to(np.asarray(along, dtype=np.float64), start.shape)
    else:
        rel = np.asarray(eye, dtype=np.float64) - start
        dist = np.linalg.norm(rel, axis=1)
        towards = rel / np.maximum(dist, 1e-300)[:, None]
        reach = dist * (1.0 - 1e-6)
    occluded[ask] = occluders.rays().blocked(start, towards, reach)
