"""Light gathered by rays at the points that stand for a large share of the surface.

Pure numpy; must not import bpy.

A vertex's light is spread over all of its faces: a room modelled as a few large quads has a
handful of vertices, each standing for square metres of wall, and its light is what a render
shows over all of them. Such vertices often sit where the probes see least well: at a
room's edges, where walls meet, or a few centimetres past the next wall (a floor running under
the walls, a wall's end outside the room), where the outside's sky and sun reach them. In
the Breakfast Room 57 of its 143K vertices stand for 89% of its surface, and they held most of
its error against Cycles.

So a point standing for at least GATHER_SHARE of the scene's surface (:func:`large_points`)
is lit as Cycles bakes a vertex: from each of its triangles' corners, nudged into the
triangle (:class:`Corners`), GATHER_RAYS cosine-weighted rays go out to the nearest surface
(the host's :class:`~cubegi_engine.rays.RayCaster`: Blender's BVH tree). A ray that leaves
the scene sees the sky (the point's direct sky light, exact); one that meets a surface
takes its light, each bounce from the bounce before (a final gather of the whole view, as the
near field is of its near part: the hits are rows of a
:class:`~cubegi_engine.nearfield.NearField` whose probe light is all taken away), from the
corners of the hit triangle that the hit point sees along it (:func:`_seen_corners`: a floor
runs under the walls into the sun outside, where its corners there are lit); a light's
shadow there is one ray per corner towards it (:func:`light_visibility`). The points' light
is then what their own view holds, not the probes' estimate from up to a cell away.
"""

import time
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from . import cubemap, geometry, lights, sh
from .hemisphere import TURN_HASH, hemisphere_rays
from .nearfield import NearField
from .penumbra import SUN_DISK_RAYS, disk_directions
from .rays import RayCaster, caster_for
from .spatial import resting
from .working import made_once

__all__ = ["large_points", "Corners", "Gathered", "gather", "gathered_for", "kept_nbytes", "light_visibility", "near_caster", "scene_caster",
           "front_triangles", "scene_occluders", "same_side", "scene_inward", "caster_made_by", "GATHER_SHARE", "GATHER_RAYS"]

# A point whose area is at least GATHER_SHARE of the scene's (front) surface, and at least
# GATHER_OUTLIER times a point's mean, is gathered by rays: at most 1 / GATHER_SHARE points,
# the coarse parts of a scene that has fine parts too (a room of a few quads round detailed
# furniture); a mesh evenly cut, however coarse, keeps the probes' light (its points' rays
# would only add their noise: the benchmark's Cornell box at 128 rays a corner, indirect
# 7.1% -> 12.6%).
GATHER_SHARE, GATHER_OUTLIER = 1.0 / 2000.0, 10.0
# Rays per corner (cosine-weighted): the sky's share at a corner to about 2% (one sigma of a
# stratified pattern).
GATHER_RAYS = 128
# A corner's rays start this share of the scene's size from the vertex into its triangle (a
# ray from the edge between two walls would otherwise leave through the other's plane), and
# this share off its plane.
INSET, LIFT = 1e-5, 1e-6
# Shadow rays per corner and light at most (an area light's sample points, a soft light's).
LIGHT_EYES = 16
# A hit's rays towards its triangle's corners run this share of the scene's size off the
# triangle, and stop short of the corner by SEEN_SHORT of their length (see _seen_corners).
SEEN_LIFT, SEEN_SHORT = 1e-5, 1e-3


def large_points(scene, share=GATHER_SHARE) -> np.ndarray:
    """``(s,)`` bool: the points (front sides, not set aside) whose area is at least ``share``
    of the scene's front surface."""
    areas = np.asarray(scene.point_areas(), dtype=np.float64)
    front = np.ones(len(areas), dtype=bool)
    if scene.back is not None:
        front &= ~np.asarray(scene.back, dtype=bool)
    if scene.dark is not None:
        front &= ~np.asarray(scene.dark, dtype=bool)
    total = float(areas[front].sum())
    if total <= 0:
        return np.zeros(len(areas), dtype=bool)
    mean = total / max(int(front.sum()), 1)
    return front & (areas > 0) & (areas >= share * total) & (areas >= GATHER_OUTLIER * mean)


@dataclass(frozen=True)
class Corners:
    """Where gathered points' rays start: one row per (point, triangle) corner, ``row (c,)``
    the point's place among the gathered rows, ``origin (c, 3)``, ``normal (c, 3)`` the
    point's shading normal, ``weight (c,)`` the corner's share of its point (1 / its corners)."""

    row: np.ndarray
    origin: np.ndarray
    normal: np.ndarray
    weight: np.ndarray
    inset: np.ndarray  # (c, 3): the corner nudged into its triangle, on its plane (before the lift)

    def __len__(self) -> int:
        return len(self.row)

    def kept(self, keep) -> "Corners":
        """The corners ``keep (c,)`` bool, each point's weight shared among its own that are left."""
        row = self.row[keep]
        count = np.bincount(row, minlength=int(self.row.max(initial=-1)) + 1)
        return Corners(row, self.origin[keep], self.normal[keep], 1.0 / np.maximum(count[row], 1), self.inset[keep])


def corners(scene, rows) -> Corners:
    """The :class:`Corners` of the points ``rows (g,)``: each triangle that has the point as
    a corner gives one, nudged INSET of the scene's size towards the triangle's centre and
    LIFT off its plane (Cycles bakes each face corner of a vertex and takes their mean)."""
    rows = np.asarray(rows, dtype=np.int64)
    tri = np.asarray(scene.triangles, dtype=np.int64).reshape(-1, 3)
    place = np.full(len(scene.points), -1, dtype=np.int64)
    place[rows] = np.arange(len(rows))
    t, k = np.nonzero(place[tri] >= 0)
    row = place[tri[t, k]]
    p = np.asarray(scene.points, dtype=np.float64)
    at = p[tri[t, k]]
    corners_ = p[tri[t]]  # (c, 3, 3)
    to_centre = corners_.mean(axis=1) - at
    to_centre /= np.maximum(np.linalg.norm(to_centre, axis=1, keepdims=True), 1e-300)
    face = geometry.cross(corners_[:, 1] - corners_[:, 0], corners_[:, 2] - corners_[:, 0])
    face /= np.maximum(np.linalg.norm(face, axis=1, keepdims=True), 1e-300)
    scale = scene.scale
    inset = at + INSET * scale * to_centre
    origin = inset + LIFT * scale * face
    order = np.argsort(row, kind="stable")
    row, origin, inset = row[order], origin[order], inset[order]
    count = np.bincount(row, minlength=len(rows))
    normal = np.asarray(scene.normals, dtype=np.float64)[rows][row]
    return Corners(row, origin, normal, 1.0 / np.maximum(count[row], 1), inset)


@dataclass
class Gathered:
    """The gathered points of a scene: ``rows (g,)``, their hits as a
    :class:`~cubegi_engine.nearfield.NearField` (``near``; every probe light of theirs taken
    away), ``sky (g, 3)`` the diffuse light of a unit sky (its pattern, if any) along their
    rays that leave the scene, their :class:`Corners`, ``rays`` per corner."""

    rows: np.ndarray
    near: NearField
    sky: np.ndarray
    corners: Corners
    rays: int
    seconds: float = 0.0

    @property
    def count(self) -> int:
        return len(self.rows)

    @property
    def nbytes(self) -> int:
        n = self.near
        return int(sum(a.nbytes for a in (self.rows, self.sky, n.hit_row, n.hit_corner, n.hit_weight, n.open_basis,
                                          self.corners.origin, self.corners.inset)))


def sky_pattern(scene, dirs):
    """The sky's radiance over its mean in directions ``dirs (k, 3)``: ``(k, 3)``."""
    sky_map = getattr(scene, "sky_map", None)
    if sky_map is None:
        return np.ones((len(dirs), 3))
    return cubemap.sample_image(np.asarray(sky_map, dtype=np.float64), cubemap.equirect_uv(dirs))


def gather(scene, rows, caster: RayCaster, rays=GATHER_RAYS) -> Gathered:
    """Cast the gathered points' rays (see the module docstring): a :class:`Gathered`.
    ``caster``: over the scene's triangles but the back sides' (:func:`scene_caster`)."""
    t0 = time.perf_counter()
    rows = np.asarray(rows, dtype=np.int64)
    at = corners(scene, rows)
    # A corner resting on another surface (a block's underside on the ground) is covered:
    # Cycles gives it no light, and a ray lifted off it would leave under the ground. It is
    # asked where it stands nudged into its face (a wall that only touches the vertex along
    # an edge does not cover it); a point all of whose corners are covered keeps the probes'
    # treatment.
    covered = resting(scene.points, scene.normals, scene.triangles, scene.scale, rows[at.row], scene.sheets(), at=at.inset)
    lit = np.unique(at.row[~covered])
    place = np.full(len(rows), -1, dtype=np.int64)
    place[lit] = np.arange(len(lit))
    at = at.kept(~covered)
    at = Corners(place[at.row], at.origin, at.normal, at.weight, at.inset)
    rows = rows[lit]
    if not len(rows):
        return Gathered(rows, NearField.empty(rays), np.zeros((0, 3)), at, rays, time.perf_counter() - t0)
    front_tri = front_triangles(scene)
    turn = 2.0 * np.pi * ((at.origin / scene.scale * 1e3) @ TURN_HASH % 1.0)
    dirs = hemisphere_rays(at.normal, rays, turn)  # (c, rays, 3)
    flat_dirs = dirs.reshape(-1, 3)
    origins = np.repeat(at.origin, rays, axis=0)
    hits = caster.cast(origins, flat_dirs)
    w = np.repeat(at.weight / rays, rays)  # each ray's share of its point
    row = np.repeat(at.row, rays)
    g = len(rows)
    # What the rays that leave see: the sky.
    leave = ~hits.hit
    sky = np.zeros((g, 3))
    np.add.at(sky, row[leave], w[leave, None] * sky_pattern(scene, flat_dirs[leave]))
    share = 1.0 - np.bincount(row[leave], w[leave], minlength=g)
    # What the rays that meet a surface take: its front's light; a sheet's back side is its
    # twin's front; a closed object's inside sends nothing.
    hit = np.flatnonzero(hits.hit)
    tri = np.asarray(scene.triangles, dtype=np.int64)[front_tri[hits.triangle[hit]]]
    front = hits.front[hit]
    twins = scene.twins()
    sends = front.copy()
    if twins is not None:
        turned = ~front & (twins[tri[:, 0]] >= 0)
        tri[turned] = twins[tri[turned]]
        sends |= turned
    hit, tri = hit[sends], tri[sends]
    at_hit = origins[hit] + hits.t[hit, None] * flat_dirs[hit]
    weight = _seen_corners(caster, scene.points, tri, at_hit, hits.bary[hit], scene.scale) * w[hit, None]
    normals = np.asarray(scene.normals, dtype=np.float64)[rows]
    near = NearField(rows, sh.diffuse_basis(normals), row[hit], tri, weight, rays * max(1, int(np.max(np.bincount(at.row), initial=1))),
                     share=share)
    return Gathered(rows, near, sky, at, rays, time.perf_counter() - t0)


def _seen_corners(caster, points, tri, at, bary, scale) -> np.ndarray:
    """The weights ``bary (h, 3)`` of hits at ``at (h, 3)`` on triangles ``tri (h, 3)``
    (corner points, wound to face the ray) over the corners each hit sees along its
    triangle, made whole again: a large triangle runs under a wall or out of the room (a
    floor past the walls, a skirting board past the window wall), and its corners there are
    lit by the outside's sun, which the hit point is not. A hit that sees none of its
    corners keeps them all."""
    p = np.asarray(points, dtype=np.float64)[tri]  # (h, 3 corners, 3)
    face = geometry.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    face /= np.maximum(np.linalg.norm(face, axis=1, keepdims=True), 1e-300)
    lift = SEEN_LIFT * scale
    start = np.repeat(at + lift * face, 3, axis=0)
    rel = (p + lift * face[:, None, :]).reshape(-1, 3) - start
    length = np.linalg.norm(rel, axis=1)
    towards = rel / np.maximum(length, 1e-300)[:, None]
    reach = length - np.maximum(SEEN_SHORT * length, 4.0 * lift)  # a corner on a wall's foot is seen
    ask = np.flatnonzero(reach > 0)
    blocked = np.zeros(len(start), dtype=bool)
    if len(ask):
        blocked[ask] = caster.blocked(start[ask], towards[ask], reach[ask])
    seen = np.where(blocked.reshape(-1, 3), 0.0, bary)
    total = seen.sum(axis=1, keepdims=True)
    return np.where(total > 0, seen * (bary.sum(axis=1, keepdims=True) / np.maximum(total, 1e-300)), bary)


def front_triangles(scene) -> np.ndarray:
    """The scene's triangles a caster needs: all but the back sides' (a sheet's back is met
    through its front's triangle)."""
    return np.flatnonzero(~scene.back_triangles())


def scene_caster(scene, renderer) -> RayCaster:
    """The host's ray caster over ``scene``'s triangles but the back sides' (the
    ``renderer``'s ``rays``, or none: :func:`caster_made_by`)."""
    return caster_made_by(scene, getattr(renderer, "rays", None))


def near_caster(scene, renderer):
    """What the near field's crowded points cast their rays through
    (:func:`~cubegi_engine.nearfield.build`'s ``caster``): a callable giving the host's caster
    over ``scene``, its triangles' indices and :func:`scene_inward`; None where the host has
    no caster of its own."""
    if getattr(renderer, "rays", None) is None:
        return None
    return lambda: (scene_caster(scene, renderer), front_triangles(scene), scene_inward(scene))


def scene_inward(scene) -> np.ndarray:
    """:func:`~cubegi_engine.geometry.inward` of ``scene``'s triangles, made once per snapshot
    (where its shadow rays start: :func:`~cubegi_engine.lifts.ray_starts`; and the near
    field's rays through the host's caster)."""
    return made_once(scene, "_inward", lambda: geometry.inward(np.asarray(scene.triangles), np.asarray(scene.points)),
                     key=(id(scene.points), id(scene.triangles)))


def scene_occluders(scene, renderer=None) -> lights.Occluders:
    """Every triangle of ``scene`` as shadow maps' occluders, with the ``renderer``'s ray
    caster over them where it has one (asked where a map cannot decide; made when first
    asked). The occluders hold the caster's maker, not the renderer (a kept shadow must not
    keep the GPU's copy of the scene)."""
    make = getattr(renderer, "rays", None)
    rays = None if make is None else partial(caster_made_by, scene, make)
    return lights.Occluders(scene.triangles, scene.points, scene.scale, scene.sides(), rays, partial(scene_inward, scene))


def caster_made_by(scene, make) -> RayCaster:
    """:func:`scene_caster` of the host's ``rays`` function itself (what a kept shadow holds:
    not the renderer), made once per snapshot and maker."""
    return made_once(scene, "_caster", lambda: caster_for(make, scene.points, np.asarray(scene.triangles)[front_triangles(scene)]),
                     key=(id(scene.points), id(scene.triangles), make))


def kept_nbytes(scene) -> int:
    """Memory ``scene`` holds for its gathered points: its ray caster and their rays."""
    total = 0
    for key in ("_caster", "_gathered"):
        cached = scene.__dict__.get(key)
        if cached is not None:
            value = cached[1]
            total += int(getattr(value, "nbytes", 0) or 0)
    return total


def gathered_for(scene, renderer) -> Gathered | None:
    """The gathered points of ``scene`` (its ``gathered`` mask; None where it has none), their
    rays cast once per snapshot."""
    mask = getattr(scene, "gathered", None)
    if mask is None or not np.any(mask):
        return None
    key = (id(scene.points), id(scene.triangles), id(mask))
    cached = scene.__dict__.get("_gathered")
    if cached is None or cached[0] != key:
        cached = (key, gather(scene, np.flatnonzero(mask), scene_caster(scene, renderer)))
        scene.__dict__["_gathered"] = cached
    return cached[1] if cached[1].count else None  # every one resting on another surface: none


def light_visibility(gathered: Gathered, caster: RayCaster, light, eyes=None) -> np.ndarray:
    """``(g,)`` in [0, 1]: how much of ``light`` reaches each gathered point, by rays from its
    corners: towards a sun, or to ``eyes (k, 3)`` (the light's shadow eyes: an area light's
    sample points, a soft light's; at most LIGHT_EYES of them, spread over the list), each
    eye weighted by how much light it sends the corner; else to the light's position."""
    at = gathered.corners
    g = gathered.count
    if not len(at):
        return np.ones(g)
    if light.kind == "SUN":  # towards the sun's middle, or across its disk (its Angle)
        to_sun = -np.asarray(light.direction, dtype=np.float64)
        count = SUN_DISK_RAYS if light.angle > 0.0 else 1
        dirs = disk_directions(to_sun / np.linalg.norm(to_sun), light.angle, at.origin, 1e-3 * float(np.abs(at.origin).max()), count)
        seen = ~caster.blocked(np.repeat(at.origin, count, axis=0), dirs.reshape(-1, 3))
        return np.bincount(at.row, at.weight * seen.reshape(len(at), count).mean(axis=1), minlength=g)
    eyes = np.asarray(light.position, dtype=np.float64)[None] if eyes is None or not len(eyes) else np.asarray(eyes, dtype=np.float64)
    if len(eyes) > LIGHT_EYES:
        eyes = eyes[np.linspace(0, len(eyes) - 1, LIGHT_EYES).round().astype(np.int64)]
    rel = eyes[None, :, :] - at.origin[:, None, :]  # (c, k, 3)
    dist = np.linalg.norm(rel, axis=2)
    u = rel / np.maximum(dist, 1e-300)[..., None]
    cos_r = np.maximum(np.einsum("ckx,cx->ck", u, at.normal), 0.0)
    cos_l = np.maximum(-(u @ np.asarray(light.direction, dtype=np.float64)), 0.0) if light.kind == "AREA" else 1.0
    w = cos_r * cos_l / np.maximum(dist * dist, 1e-300) + 1e-12
    seen = ~caster.blocked(np.repeat(at.origin, len(eyes), axis=0), u.reshape(-1, 3), (dist * (1.0 - 1e-6)).ravel())
    seen = seen.reshape(len(at), len(eyes))
    vis = (w * seen).sum(axis=1) / w.sum(axis=1)
    return np.bincount(at.row, at.weight * vis, minlength=g)


def same_side(near, covered):
    """The gathered rows' hits (a NearField) taking their light from the corners of the hit
    triangle that lie on the gathering point's side of the walls: lit by the probes where it
    is, unlit by them (``covered (s,)``: outside the room, or under something) where it is
    not; all of them where none does. A floor running under a wall into the open has a
    corner outside, in the sun, and a wall's foot gathering from the floor beside it must not
    take that light (the Breakfast Room's walls: their corners' indirect light 50 times
    Cycles')."""
    if not near.count:
        return near
    same = covered[near.hit_corner] == covered[near.rows][near.hit_row][:, None]
    kept = near.hit_weight * same
    total, part = near.hit_weight.sum(axis=1), kept.sum(axis=1)
    weight = np.where(part[:, None] > 0, kept * (total / np.maximum(part, 1e-300))[:, None], near.hit_weight)
    return replace(near, hit_weight=weight)
