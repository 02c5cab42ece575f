"""Rays cast against a scene's triangles, each to its nearest hit: the protocol the bake asks
of its host, and a plain numpy caster.

Pure numpy; must not import bpy. The add-on passes its own
(``cubegi_addon.gpu_capture.GpuRenderer.rays``: a compute shader walking a
:mod:`~cubegi_engine.boxtree`, or Blender's BVH tree); :class:`NumpyRays` tests every
triangle against every ray (the engine's tests, and
hosts without a caster of their own, on small scenes).
"""

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .geometry import planes_of, ray_cut, triangles_at

__all__ = ["Hits", "RayCaster", "NumpyRays", "caster_for", "hits_from_distances", "near_hits_again"]


@dataclass(frozen=True)
class Hits:
    """The nearest hit of each of ``n`` rays: ``t (n,)`` its distance (inf: none),
    ``triangle (n,)`` the caster's triangle index (-1: none), ``bary (n, 3)`` the hit's
    weights of the triangle's corners, ``front (n,)`` whether the ray meets the triangle's
    front (its corners wound counter-clockwise as the ray sees them)."""

    t: np.ndarray
    triangle: np.ndarray
    bary: np.ndarray
    front: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.triangle >= 0


class RayCaster(Protocol):
    """``cast(origins (n, 3), dirs (n, 3) unit, reach (n,) or None) -> Hits``: each ray's
    nearest hit among the caster's triangles, no farther than its reach (None: any);
    ``blocked(...) -> (n,) bool``: only whether it meets one (a shadow ray)."""

    def cast(self, origins, dirs, reach=None) -> Hits: ...

    def blocked(self, origins, dirs, reach=None) -> np.ndarray: ...


def hits_from_distances(points, triangles, origins, dirs, t, triangle) -> Hits:
    """The :class:`Hits` of rays whose nearest hit's distance ``t`` and triangle (indices into
    ``triangles (k, 3)`` over ``points``) a caster found: the barycentric weights and the
    side met, from the triangle's plane."""
    t = np.asarray(t, dtype=np.float64)
    triangle = np.asarray(triangle, dtype=np.int64)
    bary = np.zeros((len(t), 3))
    front = np.zeros(len(t), dtype=bool)
    hit = triangle >= 0
    if hit.any():
        corners = np.asarray(triangles, dtype=np.int64)[triangle[hit]]
        p = np.asarray(points, dtype=np.float64)
        planes = planes_of(p[corners[:, 0]], p[corners[:, 1]], p[corners[:, 2]])
        x = np.asarray(origins, dtype=np.float64)[hit] + t[hit, None] * np.asarray(dirs, dtype=np.float64)[hit]
        rel = x - planes[:, 0]
        b = np.clip(np.einsum("ij,ij->i", rel, planes[:, 2]), 0.0, 1.0)
        c = np.clip(np.einsum("ij,ij->i", rel, planes[:, 3]), 0.0, 1.0)
        scale = np.maximum(b + c, 1.0)  # a hit just past an edge (float rounding) back onto it
        b, c = b / scale, c / scale
        bary[hit] = np.stack([1.0 - b - c, b, c], axis=1)
        front[hit] = np.einsum("ij,ij->i", np.asarray(dirs, dtype=np.float64)[hit], planes[:, 1]) < 0
    return Hits(np.where(hit, t, np.inf), np.where(hit, triangle, -1), bary, front)


# A hit nearer than this share of the scene's size is tested again in float64 against the
# triangles at the hit triangle's corners (:func:`near_hits_again`), and one of them taken
# in its place if it is at most NEAR_SLACK of the scene's size farther (float32's error).
NEAR_AGAIN, NEAR_SLACK = 1e-3, 1e-5


def near_hits_again(points, triangles, corners, scale, origins, dirs, reach, which, t):
    """``(which, t)`` of a float32 caster's nearest hits, those nearer than NEAR_AGAIN of the
    scene's size tested again in float64 against the triangles that share a corner with the
    one met, the nearest taken (of two at one distance the lower index), as testing every
    triangle takes it. A ray from a crease meets its two surfaces within float32's error of
    one another a tenth of a millimetre off: the Breakfast Room's near field took the other
    of them for 18 of 65K rays, and its indirect light moved by 0.8%.

    ``corners``: the triangles at each point (:func:`~.geometry.corner_triangles`);
    ``scale``: the scene's size."""
    near = np.flatnonzero((which >= 0) & (t < NEAR_AGAIN * scale))
    if not len(near):
        return which, t
    tri, per = triangles_at(corners, triangles[which[near]].ravel())
    ray = np.repeat(np.repeat(near, 3), per)
    p = points[triangles[tri]]
    cut, b, c, ok, _ = ray_cut(origins[ray], dirs[ray], planes_of(p[:, 0], p[:, 1], p[:, 2]), grazing=0.0)
    limit = np.inf if reach is None else np.broadcast_to(np.asarray(reach, dtype=np.float64), (len(which),))[ray]
    with np.errstate(invalid="ignore"):
        inside = ok & (b >= 0) & (c >= 0) & (b + c <= 1) & (cut > 0) & (cut <= limit)
    ray, tri, cut = ray[inside], tri[inside], cut[inside]
    if not len(ray):  # (float64 finds none of them met: the caster's hits stand)
        return which, t
    first = np.lexsort((tri, cut, ray))
    keep = first[np.append(True, ray[first][1:] != ray[first][:-1])]
    # Only a cut no farther than the caster's (within float32's error): one beyond it may lie
    # past a triangle that shares no corner, which the caster's walk no longer tested.
    keep = keep[cut[keep] <= t[ray[keep]] + NEAR_SLACK * scale]
    which, t = which.copy(), t.copy()
    which[ray[keep]], t[ray[keep]] = tri[keep], cut[keep]
    return which, t


# (ray, triangle) tests at a time in NumpyRays.
PAIRS_AT_ONCE = 1 << 22


class NumpyRays:
    """A :class:`RayCaster` that tests every ray against every triangle (``triangles (k, 3)``
    over ``points (s, 3)``): exact, and linear in rays x triangles (small scenes)."""

    def __init__(self, points, triangles):
        self.points = np.asarray(points, dtype=np.float64)
        self.triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        p, tri = self.points, self.triangles
        self.planes = planes_of(p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]])

    def cast(self, origins, dirs, reach=None) -> Hits:
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        n, k = len(origins), len(self.triangles)
        limit = np.full(n, np.inf) if reach is None else np.broadcast_to(np.asarray(reach, dtype=np.float64), (n,))
        best = np.full(n, np.inf)
        which = np.full(n, -1, dtype=np.int64)
        step = max(1, PAIRS_AT_ONCE // max(k, 1))
        for lo in range(0, n if k else 0, step):
            sl = slice(lo, lo + step)
            t, b, c, ok, _ = ray_cut(origins[sl, None, :], dirs[sl, None, :], self.planes[None, :, :, :], grazing=0.0)
            with np.errstate(invalid="ignore"):
                inside = ok & (b >= 0) & (c >= 0) & (b + c <= 1) & (t > 0) & (t <= limit[sl, None])
            t = np.where(inside, t, np.inf)
            j = np.argmin(t, axis=1)
            near = t[np.arange(len(j)), j]
            best[sl] = near
            which[sl] = np.where(np.isfinite(near), j, -1)
        return hits_from_distances(self.points, self.triangles, origins, dirs, best, which)

    def blocked(self, origins, dirs, reach=None) -> np.ndarray:
        return self.cast(origins, dirs, reach).hit


def caster_for(make, points, triangles) -> RayCaster:
    """The host's caster over ``triangles`` (``make``: a renderer's ``rays``, where it has
    one), else a :class:`NumpyRays`."""
    return make(points, triangles) if make is not None else NumpyRays(points, triangles)
