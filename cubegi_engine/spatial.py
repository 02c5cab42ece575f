"""Triangles listed by the voxels they overlap (:class:`VoxelIndex`), and rays traced
against them: the near field's rays (:mod:`cubegi_engine.nearfield`) and the probes'
placement (:mod:`cubegi_engine.placement`). Pure numpy; must not import bpy."""

import weakref

import numpy as np

from .geometry import all_three, chunks, cross, in_box, in_pieces, planes_of, ray_cut, run_offsets, sorted_unique
from .working import checkpoint, once

__all__ = ["VoxelIndex", "Corners", "corners_of", "voxel_index", "forget_indexes", "resting", "intersect_pairs",
           "over_triangles", "SLACK", "COORD_SLACK", "BARY_SLACK", "MAX_NEARBY"]

# Segments whose voxels are listed at a time, points whose candidate voxels are (27 voxels
# and their triangles each: temporaries that stay in cache), and (pair, ray) tests at a time.
VOXEL_CHUNK = 4096
CANDIDATE_CHUNK = 512
TEST_CHUNK = 1 << 21
# A point with more triangles than this listed in the voxels around it is left out as
# crowded (dense, folded geometry), before its pairs are made.
MAX_NEARBY = 1024
# Tolerances: a ray starts SLACK x reach + COORD_SLACK x |coordinates| off its surface (see
# cubegi_engine.nearfield.build); a hit within BARY_SLACK outside a triangle's edge counts
# (a ray along an edge).
SLACK, COORD_SLACK, BARY_SLACK = 1e-5, 4e-6, 1e-5
# A back face is a ray's nearest hit only where it is nearer than a front face by more than
# this share of the ray's reach: which of two coincident faces float rounding puts first must
# not decide (see VoxelIndex.trace).
TIE = 1e-9


def over_triangles(x, a, b, c, unit):
    """Whether points ``x`` project into triangles ``a, b, c`` (unit normals ``unit``), with
    BARY_SLACK at the edges."""
    e = BARY_SLACK
    inside = np.ones(len(x), dtype=bool)
    for p, q in ((a, b), (b, c), (c, a)):
        edge = q - p
        side = np.einsum("ij,ij->i", cross(edge, x - p), unit)
        inside &= side >= -e * np.einsum("ij,ij->i", edge, edge)
    return inside


def intersect_pairs(o, d, planes, reach, start):
    """Paired rays ``o + t d`` (``d`` unit) and triangles (their :func:`~.geometry.planes_of`),
    by the one kernel :func:`~.geometry.ray_cut`: ``(t, u, v, hit, front)``. A hit lies
    within BARY_SLACK of the triangle and ``start < t < reach``; a ray that starts on a
    triangle's plane (within ``start``: where two surfaces meet) is stopped by it only if it
    heads into its front."""
    t, u, v, ok, front = ray_cut(o, d, planes, grazing=0.0)  # any cut: see geometry.GRAZING
    e = BARY_SLACK  # a ray along a triangle's edge (from a point where surfaces meet) hits it
    with np.errstate(invalid="ignore"):
        hit = ok & (u >= -e) & (v >= -e) & (u + v <= 1 + e) & (t < reach) & ((t > start) | ((t >= -start) & front))
    return t, u, v, hit, front


class Corners:
    """Triangles' corners ``a, b, c`` (each ``(t, 3)``) and what the voxel indexes' tests ask
    of each triangle, made when first asked (a scene whose every point is crowded never
    does) and shared by every index of the same triangles (see :func:`corners_of`)."""

    def __init__(self, a, b, c, arrays=None):
        self.a, self.b, self.c = a, b, c
        self.arrays = arrays  # the (points, triangles) they were made of, held (see corners_of)

    @once
    def centre(self):
        return (self.a + self.b + self.c) / 3.0

    @once
    def lo(self):
        return np.minimum(np.minimum(self.a, self.b), self.c)

    @once
    def hi(self):
        return np.maximum(np.maximum(self.a, self.b), self.c)

    @once
    def radius(self):
        """``(t,)`` each triangle's bounding sphere about its centre (the squares summed by
        columns, in np.sum's order: a sum along an axis of three is slow)."""
        def squared(v):
            d = v - self.centre
            return (d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2]

        return np.sqrt(np.maximum(np.maximum(squared(self.a), squared(self.b)), squared(self.c)))

    @once
    def unit(self):
        """``(t, 3)`` each triangle's unit normal."""
        normal = cross(self.b - self.a, self.c - self.a)
        return normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)

    @once
    def offset(self):
        """``(t,)`` each triangle's plane's offset along :attr:`unit`."""
        return np.einsum("ij,ij->i", self.unit, self.a)

    @once
    def planes(self):
        """``(t, 4, 3)``: :func:`~.geometry.planes_of` each triangle."""
        return planes_of(self.a, self.b, self.c)


class VoxelIndex:
    """Triangles ``a, b, c`` listed in the voxels (edge ``voxel``) their boxes overlap;
    ``sheets``: the scene's two-sided objects (see :func:`cubegi_engine.nearfield.build`)."""

    def __init__(self, a, b, c, voxel, sheets=None):
        self._over(Corners(a, b, c), voxel, sheets)

    @classmethod
    def over(cls, corners, voxel, sheets=None):
        """An index of the triangles of ``corners`` (a :class:`Corners`, shared: what each
        triangle's tests ask is made once for every index of them)."""
        index = cls.__new__(cls)
        index._over(corners, voxel, sheets)
        return index

    def _over(self, corners, voxel, sheets):
        self.corners = corners
        self.sheets = sheets
        lo, hi = self.lo, self.hi
        self.origin = lo.min(axis=0) - voxel
        self.h = max(voxel, float(np.max(hi.max(axis=0) - lo.min(axis=0))) / 256.0, 1e-12)
        self.dims = np.floor((hi.max(axis=0) - self.origin) / self.h).astype(np.int64) + 3
        self._made_list = False  # tri, keys, start, end, content_lo, content_hi made (_list)

    def __getattr__(self, name):
        if name in ("a", "b", "c", "centre", "lo", "hi", "radius", "unit", "offset", "planes"):
            return getattr(self.corners, name)
        raise AttributeError(name)

    def _list(self):
        """List each triangle in the voxels its box overlaps (once)."""
        if self._made_list:
            return
        lo, hi = self.lo, self.hi
        # The listing's temporaries in 32 bits where they fit (a voxel's coordinates are
        # under 260 each way, and its key under 260^3): at two million triangles they were
        # the bake's high-water mark of memory.
        box_lo = np.floor((lo - self.origin) / self.h).astype(np.int32)
        span = np.floor((hi - self.origin) / self.h).astype(np.int32) - box_lo + 1
        count = np.prod(span, axis=1, dtype=np.int64)
        small = np.int32 if count.sum() < 2**31 else np.int64
        tri = np.repeat(np.arange(len(lo), dtype=small), count)
        k = np.arange(len(tri), dtype=small) - np.repeat((np.cumsum(count) - count).astype(small), count)
        sx, sy = span[tri, 0], span[tri, 1]
        key = self._key(box_lo[tri, 0] + k % sx, box_lo[tri, 1] + (k // sx) % sy, box_lo[tri, 2] + k // (sx * sy), small)
        del k, sx, sy
        order = np.argsort(key, kind="stable")
        key, self.tri = key[order].astype(np.int64), tri[order].astype(np.int64)
        del order
        self.start = np.flatnonzero(np.concatenate([[True], key[1:] != key[:-1]])) if len(key) else np.zeros(0, dtype=np.int64)
        self.keys = key[self.start]
        self.end = np.append(self.start[1:], len(key))
        # Per occupied voxel, the box of its triangles (a voxel whose triangles all lie in a
        # point's own plane is passed over whole: see candidates).
        self.content_lo = np.minimum.reduceat(lo[self.tri], self.start, axis=0) if len(key) else np.zeros((0, 3))
        self.content_hi = np.maximum.reduceat(hi[self.tri], self.start, axis=0) if len(key) else np.zeros((0, 3))
        self._made_list = True

    @once
    def _centre_keys(self):
        """The sorted voxel keys of the triangles' centres, each clipped into its box."""
        at = np.floor((np.clip(self.centre, self.lo, self.hi) - self.origin) / self.h).astype(np.int64)
        return np.sort(self._key(at[:, 0], at[:, 1], at[:, 2]))

    def _centre_count(self, key):
        """How many triangles have their centre in each voxel ``key``: no more than the
        triangles listed there (a triangle's box holds its centre), and made without listing
        them."""
        return np.searchsorted(self._centre_keys, key, side="right") - np.searchsorted(self._centre_keys, key, side="left")

    def trace(self, points, normals, dirs, reach, slack, pair_p, pair_t):
        """The nearest hit of every ray ``points + slack normals + t dirs`` (``dirs (s, k, 3)``)
        within ``reach`` among the candidate pairs: ``(t (s, k) inf where none, triangle (s, k)
        -1 where none, (u, v) (s, k, 2), front (s, k))``. Only the rays inside the cone around a
        triangle's bounding sphere are tested against it."""
        s, rays = dirs.shape[:2]
        best = np.full((s, rays), np.inf)
        best_key = np.full((s, rays), np.inf)
        hit_tri = np.full((s, rays), -1, dtype=np.int64)
        hit_uv = np.zeros((s, rays, 2))
        hit_front = np.zeros((s, rays), dtype=bool)
        step = max(1, TEST_CHUNK // rays)
        start = points + slack[:, None] * normals  # each point's rays' origin
        for lo in range(0, len(pair_p), step):
            pp, tt = pair_p[lo : lo + step], pair_t[lo : lo + step]
            to = self.centre[tt] - points[pp]
            dist = np.linalg.norm(to, axis=1)
            cos_cone = np.sqrt(np.clip(1.0 - (self.radius[tt] / np.maximum(dist, 1e-300)) ** 2, 0.0, 1.0))
            cos_cone[dist <= self.radius[tt]] = -1.0
            along = np.einsum("pkc,pc->pk", dirs[pp], to) / np.maximum(dist, 1e-300)[:, None]
            pi, ki = np.nonzero(along >= cos_cone[:, None] - 1e-9)
            p, t_ = pp[pi], tt[pi]
            t, u, v, hit, front = intersect_pairs(start[p], dirs[p, ki], self.planes[t_], reach[p], 2.0 * slack[p])
            if self.sheets is not None:
                # A sheet is met on the side a ray comes from: its back faces are its twin's
                # fronts. A ray from a point on a sheet's plane (a wall's foot on a floor) is
                # stopped there by the sheet's front only, not by the twin behind it.
                hit &= (front | ~self.sheets.triangles[t_]) & ((t > 2.0 * slack[p]) | ~self.sheets.triangle_back[t_])
            p, k, t_, t, u, v, front = p[hit], ki[hit], t_[hit], t[hit], u[hit], v[hit], front[hit]
            # Two hits as near as each other (a surface and a coincident twin facing the other
            # way, the faces meeting at a turned wall's edge) go to the front: a back face is
            # the nearest hit only where it is nearer by more than TIE of the reach.
            key = t + np.where(front, 0.0, TIE * reach[p])
            order = np.lexsort((key, p * rays + k))
            p, k, t_, t, u, v, front, key = (x[order] for x in (p, k, t_, t, u, v, front, key))
            head = np.ones(len(p), dtype=bool)
            head[1:] = (p[1:] != p[:-1]) | (k[1:] != k[:-1])
            p, k, t_, t, u, v, front, key = (x[head] for x in (p, k, t_, t, u, v, front, key))
            nearer = key < best_key[p, k]
            p, k = p[nearer], k[nearer]
            best_key[p, k] = key[nearer]
            best[p, k], hit_tri[p, k] = t[nearer], t_[nearer]
            hit_uv[p, k] = np.stack([u[nearer], v[nearer]], axis=1)
            hit_front[p, k] = front[nearer]
        return best, hit_tri, hit_uv, hit_front

    def _key(self, ix, iy, iz, dtype=np.int64):
        """Each voxel's key (its index in the grid of :attr:`dims`), as ``dtype``."""
        d0, d1, d2 = (int(x) for x in self.dims)
        ix, iy, iz = (np.asarray(i).astype(dtype, copy=False) for i in (ix, iy, iz))
        return (np.clip(iz, 0, d2 - 1) * d1 + np.clip(iy, 0, d1 - 1)) * d0 + np.clip(ix, 0, d0 - 1)

    def _voxels(self, pt, key):
        """The points ``pt`` and the slots (indices into :attr:`keys`) of their voxel ``key``s
        that hold triangles; empty voxels dropped."""
        self._list()
        slot = np.minimum(np.searchsorted(self.keys, key), len(self.keys) - 1)
        found = self.keys[slot] == key
        return pt[found], slot[found]

    def _listed(self, pt, slot):
        """Every (point, triangle) pair of points ``pt`` and the triangles listed in their
        voxels ``slot`` (indices into :attr:`keys`), one pair per listing."""
        count = self.end[slot] - self.start[slot]
        pp = np.repeat(pt, count)
        tt = self.tri[np.repeat(self.start[slot], count) + run_offsets(count)]
        return pp, tt

    def segment_candidates(self, starts, ends):
        """(segment, triangle) pairs: the triangles whose boxes meet the box of each segment
        ``starts``..``ends`` (``(m, 3)`` each, no longer than a voxel's edge: at most 2 x 2 x 2
        voxels hold it). What one ray along a normal needs, for an eighth of the voxels
        :meth:`candidates` asks."""
        lo = np.minimum(starts, ends)
        hi = np.maximum(starts, ends)
        first = np.floor((lo - self.origin) / self.h).astype(np.int64)
        last = np.floor((hi - self.origin) / self.h).astype(np.int64)
        offsets = np.array([[i >> 0 & 1, i >> 1 & 1, i >> 2 & 1] for i in range(8)], dtype=np.int64)
        out_p, out_t = [], []
        for sl in chunks(len(starts), VOXEL_CHUNK):
            at = sl.start
            idx = first[sl, None, :] + offsets[None]  # (m, 8, 3)
            use = all_three(idx <= last[sl, None, :])
            key = np.where(use, self._key(idx[..., 0], idx[..., 1], idx[..., 2]), -1)
            pt, col = np.nonzero(key >= 0)
            pt, slot = self._voxels(pt, key[pt, col])
            pp, tt = self._listed(pt, slot)
            pp += at
            keep = all_three((lo[pp] <= self.hi[tt]) & (hi[pp] >= self.lo[tt]))
            pair = sorted_unique(pp[keep] * len(self.a) + tt[keep])  # a triangle in several voxels, once
            out_p.append(pair // len(self.a))
            out_t.append(pair % len(self.a))
        if not out_p:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        return np.concatenate(out_p), np.concatenate(out_t)

    def candidates(self, points, normals, reach, touching=False):
        """(point, triangle) pairs a ray from the point into its hemisphere may hit within
        its reach (see :mod:`cubegi_engine.nearfield`), and ``(s,)`` bool: the points left out as
        crowded (their pairs are not made). ``touching``: instead, the triangles that lie in
        a point's plane, facing the other way, over it (see :func:`resting`)."""
        a, b, c = self.a, self.b, self.c
        base = np.floor((points - self.origin) / self.h).astype(np.int64)
        crowded = np.zeros(len(points), dtype=bool)
        offsets = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
        empty = np.zeros(0, dtype=np.int64)

        def piece(sl):
            lo = sl.start
            idx = base[sl, None, :] + offsets[None]  # (m, 27, 3)
            # Only the voxels within reach with a part in front of the point's tangent plane.
            rel = self.origin + (idx + 0.5) * self.h - points[sl, None, :]
            gap = np.maximum(np.abs(rel) - 0.5 * self.h, 0.0)
            ahead = np.einsum("mvc,mc->mv", rel, normals[sl]) + 0.5 * self.h * np.abs(normals[sl]).sum(axis=1)[:, None]
            use = (np.einsum("mvc,mvc->mv", gap, gap) <= reach[sl, None] ** 2) & (ahead >= -1e-9 * self.h)  # or touching it
            key = np.where(use, self._key(idx[..., 0], idx[..., 1], idx[..., 2]), -1)
            key = np.sort(key, axis=1)
            new = key >= 0
            new[:, 1:] &= key[:, 1:] != key[:, :-1]
            pt, col = np.nonzero(new)
            # Points with more triangles than MAX_NEARBY listed around them are left out
            # before their pairs are made (dense, folded geometry): first those with more
            # triangles' centres around them than that, without listing the triangles.
            many = np.bincount(pt, self._centre_count(key[pt, col]), minlength=len(idx)) > MAX_NEARBY
            pt, col = pt[~many[pt]], col[~many[pt]]
            if not len(pt):
                return empty, empty, many
            pt, slot = self._voxels(pt, key[pt, col])
            count = self.end[slot] - self.start[slot]
            many |= np.bincount(pt, count, minlength=len(idx)) > MAX_NEARBY
            pt, slot = pt[~many[pt]], slot[~many[pt]]
            # The voxels' own boxes first (the same tests as the triangles' boxes below, each
            # passed by every triangle the voxel holds that passes them).
            x, r = points[lo + pt], reach[lo + pt][:, None]
            fits = in_box(x, self.content_lo[slot] - r, self.content_hi[slot] + r)
            if not touching:
                fits &= _box_front(normals[lo + pt], self.content_lo[slot] - x, self.content_hi[slot] - x, x, r[:, 0])
            pp, tt = self._listed(pt[fits], slot[fits])
            pp += lo
            # Cheapest tests first: the boxes (within reach, and a corner of the box in front:
            # a wall's own triangles around its points are not, where it lies along an axis),
            # then the plane, then a corner of the triangle in front.
            x, r, box_lo, box_hi = points[pp], reach[pp][:, None], self.lo[tt], self.hi[tt]
            keep = in_box(x, box_lo - r, box_hi + r)
            if not touching:
                keep &= _box_front(normals[pp], box_lo - x, box_hi - x, x, r[:, 0])
            pp, tt, x, r = pp[keep], tt[keep], x[keep], r[keep, 0]
            keep = np.abs(np.einsum("ij,ij->i", x, self.unit[tt]) - self.offset[tt]) <= r
            pp, tt, x, r = pp[keep], tt[keep], x[keep], r[keep]
            nx = normals[pp]
            front = np.maximum(np.maximum(np.einsum("ij,ij->i", a[tt] - x, nx), np.einsum("ij,ij->i", b[tt] - x, nx)),
                               np.einsum("ij,ij->i", c[tt] - x, nx))
            slack = SLACK * r + COORD_SLACK * np.abs(x).max(axis=1)
            if touching:  # lying in the point's plane, facing the other way, over the point
                keep = (np.abs(np.einsum("ij,ij->i", x, self.unit[tt]) - self.offset[tt]) <= 2.0 * slack) & (
                    np.einsum("ij,ij->i", self.unit[tt], nx) < -0.5) & over_triangles(x, a[tt], b[tt], c[tt], self.unit[tt])
            else:
                keep = front > slack
            pair = sorted_unique(pp[keep] * len(a) + tt[keep])  # a triangle listed in several voxels, once
            return pair // len(a), pair % len(a), many
        self._list(), self._centre_keys, self.unit, self.offset  # made once, before the pieces share them
        parts = in_pieces(piece, len(points), CANDIDATE_CHUNK)
        if parts:
            crowded = np.concatenate([many for _, _, many in parts])
        none = [empty]
        return np.concatenate([p for p, _, _ in parts] or none), np.concatenate([t for _, t, _ in parts] or none), crowded


def _box_front(normals, to_lo, to_hi, x, reach):
    """Whether a box (its corners ``lo``, ``hi`` less the points ``x``) has a corner in front of
    each point's tangent plane by more than its ray's slack: true of every triangle in it that
    has one (a wall's own triangles, where it lies along an axis, have none)."""
    near_lo, near_hi = normals * to_lo, normals * to_hi
    height = np.maximum(near_lo, near_hi).sum(axis=1)
    # The exact test sums its terms in another order: a hair of rounding room, which grows
    # with a larger box (a voxel's box keeps every triangle its own box keeps).
    rounding = 1e-12 * np.maximum(np.abs(near_lo), np.abs(near_hi)).sum(axis=1)
    return height + rounding > SLACK * reach + COORD_SLACK * np.abs(x).max(axis=1)


# The voxel indexes last made, at most INDEXES_KEPT: [(key, arrays held, VoxelIndex)]; a
# bake lets them go when it ends (forget_indexes: each holds a few arrays per triangle).
_INDEXES: list = []
INDEXES_KEPT = 2


def forget_indexes():
    """Let go of the kept voxel indexes (the end of a bake)."""
    _INDEXES.clear()


def voxel_index(points, tri, voxel, sheets=None, keep=True):
    """A :class:`VoxelIndex` of ``tri (t, 3)`` over ``points``, made once per
    scene and voxel size (a bake asks for the same one several times: the near field's rays
    under covered points twice); the arrays are held while it is
    kept, so their addresses name them. ``keep=False``: one no later step asks for (the
    near field's own), not kept."""
    key = _arrays_key(points, tri) + (float(voxel), id(sheets))
    for entry in _INDEXES:
        if entry[0] == key:
            return entry[2]
    index = VoxelIndex.over(corners_of(points, tri), voxel, sheets)
    if keep:
        checkpoint()  # (a cancelled bake's thread keeps none past its end: forget_indexes)
        _INDEXES[:] = [(key, (points, tri, sheets), index)] + _INDEXES[: INDEXES_KEPT - 1]
    return index


def _arrays_key(*arrays):
    """What names arrays held alive: their memory's address, shape, type and strides (two
    views of one buffer differ in one of them)."""
    return tuple((a.__array_interface__["data"][0], a.shape, a.dtype.str, a.strides) for a in arrays)


# The triangles' corners that voxel indexes share: [(key, weak reference to the Corners)].
_CORNERS: list = []


def corners_of(points, tri):
    """The :class:`Corners` of ``tri (t, 3)`` over ``points``, shared while an index (or
    anything else) holds it: the near field's index, the ones :func:`resting` asks and the
    probes' placement's list the same triangles at other voxel sizes (a subdivided Breakfast
    Room's 2.1M triangles' planes were made four times). It holds the arrays, so their
    addresses name them while it lives; nothing is kept for its own sake (a million
    triangles' corners and planes are hundreds of MB)."""
    key = _arrays_key(points, tri)
    _CORNERS[:] = [entry for entry in _CORNERS if entry[1]() is not None]
    for entry_key, ref in _CORNERS:
        corners = ref()
        if entry_key == key and corners is not None:
            return corners
    corners = Corners(*(points[tri[:, k]] for k in range(3)), arrays=(points, tri))
    _CORNERS.append((key, weakref.ref(corners)))
    return corners


def resting(points, normals, triangles, scale, which, sheets=None, at=None):
    """``(k,)`` bool: whether the points ``which (k,)`` lie on another surface facing them
    (the underside of a block standing on the ground, a floor point under it): a triangle
    in the point's plane, facing the other way, over the point. ``triangles`` index
    ``points``; ``scale``: the scene's size; ``sheets``: the scene's two-sided objects
    (:class:`~cubegi_engine.scene.Sheets`), whose own other side is not another surface;
    ``at (k, 3)``: where to ask instead of the points themselves (a vertex's corner nudged
    into its face: a corner where a wall merely touches the vertex is not covered)."""
    points = np.asarray(points, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    which = np.asarray(which, dtype=np.int64)
    if not len(which) or not len(tri):
        return np.zeros(len(which), dtype=bool)
    reach = np.full(len(which), 1e-3 * scale)
    index = _resting_index(points, tri, scale)
    where = points[which] if at is None else np.asarray(at, dtype=np.float64)
    pp, tt, _ = index.candidates(where, np.asarray(normals, dtype=np.float64)[which], reach, touching=True)
    if sheets is not None:  # a sheet's own other side (its twin's triangles, wherever its points were cut)
        pp = pp[~sheets.other_side(which[pp], tt)]
    out = np.zeros(len(which), dtype=bool)
    out[pp] = True
    return out


# :func:`resting`'s index is kept (a bake asks it twice) for scenes of fewer triangles than
# this; past it, made each time (see _resting_index).
RESTING_KEPT_BELOW = 1_000_000


def _resting_index(points, tri, scale):
    """The voxel index :func:`resting` asks, coarse (a 64th of the scene: few entries to sort,
    and few points to ask). Kept for a small scene (the Breakfast Room asks it twice: 0.2-0.4 s
    each); not past RESTING_KEPT_BELOW triangles, where kept it held 0.2 GB past its use (the
    Room subdivided to a million vertices asks it once, 0.9 s: its peak 3.07 -> 2.87 GB)."""
    return voxel_index(points, tri, scale / 64.0, keep=len(tri) < RESTING_KEPT_BELOW)
