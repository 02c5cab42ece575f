"""Where another object's surface crosses a cell of the probes' simplified copy of the scene
(:mod:`.proxy`): which points lie in such a cell, and on which side of what crosses it.

Pure numpy; must not import bpy.
"""

import numpy as np

from .geometry import all_three, corner_box, corner_triangles, cross, in_box, listed_ranks, near_any_triangle, run_offsets, triangles_at
from .working import checkpoint, once

__all__ = ["Prepared", "contact", "PARALLEL", "AROUND", "SIDE_PLANES"]

# A finest crossed cell's points are clustered on each side of the surfaces crossing it apart
# (see _sides): the weightiest this many of them. A point within ON_PLANE cells of a plane
# counts as in front of it (a wall's foot on a floor).
SIDE_PLANES, ON_PLANE = 4, 1e-6
# How many cells around a crossed one hold what can cross its halves (see _finer_candidates).
AROUND = 2
# The most cells of an object's lattice that _finer_candidates flags one by one (a byte each).
LISTED_AT_MOST = 1 << 25
# The coarse lattice that finds the points in a box (see Prepared.points_in): about this many
# points a cell, and at most this many cells along a side.
BUCKET_POINTS, BUCKETS_ALONG = 256, 128


class Prepared:
    """What every clustering round of one scene reads: the points (and their areas), each
    object's points, the triangles' boxes, sizes and normals, and lookups by place."""

    def __init__(self, points, normals, tris, owner, objects, areas):
        self.points, self.normals, self.tris, self.owner, self.areas = points, normals, tris, owner, areas
        self.origin = points.min(axis=0) if len(points) else np.zeros(3)
        self.rel = points - self.origin  # cells are counted from the scene's lowest corner
        self.members = np.split(np.argsort(owner, kind="stable"), np.cumsum(np.bincount(owner, minlength=objects))[:-1])
        self.tri_owner = owner[tris[:, 0]]
        corners = points[tris]
        self.tri_lo, self.tri_hi = corner_box(corners)
        size = self.tri_hi - self.tri_lo
        self.tri_extent = np.maximum(np.maximum(size[:, 0], size[:, 1]), size[:, 2])
        n = cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        length = np.linalg.norm(n, axis=1)
        self.tri_area = 0.5 * length
        self.tri_normal = n / np.maximum(length, 1e-300)[:, None]

    def points_in(self, lo, hi):
        """The points that may lie in the box ``lo, hi`` (more, not fewer): those of the
        cells of a coarse lattice (about BUCKET_POINTS a cell) that the box reaches."""
        order, start, edge, shape = self._buckets
        first = np.clip(np.floor((lo - self.origin) / edge), 0, shape - 1).astype(np.int64)
        last = np.clip(np.floor((hi - self.origin) / edge), -1, shape - 1).astype(np.int64)
        if np.any(last < first):
            return order[:0]
        cells = np.ravel_multi_index(np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(first, last)], indexing="ij"), shape).ravel()
        count = start[cells + 1] - start[cells]
        return order[np.repeat(start[cells], count) + run_offsets(count)]

    @once
    def _buckets(self):
        """The points by their cell of a coarse lattice: ``(order, start, edge, shape)``, the
        points of cell ``k`` being ``order[start[k]:start[k + 1]]``."""
        span = np.maximum(self.rel.max(axis=0), 1e-300) if len(self.rel) else np.ones(3)
        cells = max(len(self.rel) / BUCKET_POINTS, 1.0)
        edge = max(float(np.cbrt(np.prod(span) / cells)), float(span.max()) / BUCKETS_ALONG)
        shape = np.minimum(np.floor(span / edge).astype(np.int64) + 1, BUCKETS_ALONG + 1)
        key = np.ravel_multi_index(np.minimum(np.floor(self.rel / edge).astype(np.int64), shape - 1).T, shape)
        order = np.argsort(key, kind="stable")
        return order, np.searchsorted(key[order], np.arange(int(np.prod(shape)) + 1)), edge, shape

    def triangles_in(self, lo, hi):
        """The triangles whose boxes may reach the box ``lo, hi`` (more, not fewer): the
        largest, and those of the others whose lowest X lies within the largest's size of it."""
        huge, by_lo, lo_x, reach = self._by_lowest_x
        slab = by_lo[np.searchsorted(lo_x, lo[0] - reach) : np.searchsorted(lo_x, hi[0], side="right")]
        return np.concatenate([huge, slab])

    @once
    def _by_lowest_x(self):
        """The largest triangles (a hundredth of them: walls, floors), the others by their
        boxes' lowest X, those X, and the others' largest size."""
        reach = float(np.quantile(self.tri_extent, 0.99)) if len(self.tri_extent) else 0.0
        huge = np.flatnonzero(self.tri_extent > reach)
        rest = np.flatnonzero(self.tri_extent <= reach)
        by_lo = rest[np.argsort(self.tri_lo[rest, 0], kind="stable")]
        return huge, by_lo, self.tri_lo[by_lo, 0], reach

    @once
    def corner_triangles(self):
        """Each point's triangles (:func:`~.geometry.corner_triangles`)."""
        return corner_triangles(self.tris, len(self.points))


# Another object's surface within this of parallel to a cell's (|cos|) lies along it (a rug on
# a floor), not across it: the cell is clustered all the same.
PARALLEL = 0.9


def contact(prep, cell, ijk, which=None, within=None, sides=False):
    """``((s,) bool, within, side)``: points of simplified objects (``which (s,)`` bool: of
    those alone) whose cell (in their object's lattice: ``cell`` per object, ``ijk`` per
    point) also holds another object's surface running across it: a wall's foot on a floor, a
    floor under a wall. Such a cell is halved, and its finest halves are clustered on each side
    of what crosses them (see :func:`.proxy._cluster`), so that no cluster averages light from
    both sides of another surface (a floor running under a wall between a lit and a dark room)
    and nothing lifts off what it stands on. A surface lying along the cell's (a rug on a
    floor) does not count: both are clustered, each on its own.
    ``side (s,)``: on which side of the surfaces crossing its cell each of those points
    lies (:func:`_sides`: bits), asked for the finest cells alone (``sides``; else zeros).

    ``within``: per object, ``(points, triangles)`` of other objects that can cross its
    cells, from the coarser level these cells halve (what this call returns for its crossed
    cells: see :func:`_finer_candidates`); None: all."""
    points, normals, owner, rel = prep.points, prep.normals, prep.owner, prep.rel
    out = np.zeros(len(points), dtype=bool)
    side = np.zeros(len(points), dtype=np.int64)
    simplified = np.flatnonzero(cell > 0)
    finer = {}
    for obj in simplified:
        checkpoint()  # (a cancelled bake's simplification stops here)
        mine = prep.members[obj] if which is None else prep.members[obj][which[prep.members[obj]]]
        if not len(mine) or (within is not None and obj not in within):
            continue
        h = cell[obj]
        # The box and lattice reach AROUND cells past the object's own: what can cross the
        # halves of its cells (see _finer_candidates).
        lo, hi = points[mine].min(axis=0) - (AROUND + 1) * h, points[mine].max(axis=0) + (AROUND + 1) * h
        base = ijk[mine].min(axis=0) - AROUND
        shape = ijk[mine].max(axis=0) - base + AROUND + 1
        key = np.ravel_multi_index((ijk[mine] - base).T, shape)
        cells, first = np.unique(key, return_index=True)
        cell_normal = normals[mine[first]]
        # Other objects' points in this object's cells, across the cell's surface.
        if within is None:
            near = prep.points_in(lo, hi)
            near = near[owner[near] != obj]
            big = prep.triangles_in(lo, hi)  # (of every object: the others' are kept below)
        else:
            near, big = within[obj]
        q = points[near]
        box = in_box(q, lo, hi)
        near = near[box]
        theirs = np.floor((q[box] - prep.origin) / h).astype(np.int64) - base  # (rel[near], gathered once)
        inside = in_box(theirs, np.zeros(3, dtype=np.int64), shape - 1)
        near, theirs = near[inside], np.ravel_multi_index(theirs[inside].T, shape)
        at = np.searchsorted(cells, theirs)
        found = at < len(cells)
        found[found] = cells[at[found]] == theirs[found]
        across = np.abs(np.einsum("sc,sc->s", normals[near[found]], cell_normal[at[found]])) < PARALLEL
        crossing, crossed = near[found][across], at[found][across]
        touched = np.zeros(len(cells), dtype=bool)
        touched[crossed] = True
        planes = _point_planes(prep, crossing, crossed) if sides else None
        # Other objects' triangles larger than a cell, whose vertices may lie far outside.
        big = big[prep.tri_extent[big] > h]
        big = np.sort(big[prep.tri_owner[big] != obj])
        big = big[all_three(prep.tri_lo[big] <= hi) & all_three(prep.tri_hi[big] >= lo)]
        if len(big):
            centres = points[mine[first]] - rel[mine[first]] + (ijk[mine[first]] + 0.5) * h
            c = points[prep.tris[big]]
            hit, least = near_any_triangle(centres, 0.5 * np.sqrt(3.0) * h, c[:, 0], c[:, 1], c[:, 2],
                                           centre_normals=cell_normal, across=PARALLEL, least=True)
            touched |= hit
            if sides:
                cut = (np.flatnonzero(hit), c[least[hit], 0], prep.tri_normal[big[least[hit]]], np.full(int(hit.sum()), len(points)))
                planes = [np.concatenate([a, b]) for a, b in zip(planes, cut)]
        if touched.any():
            inside = np.isin(key, cells[touched])
            members, slot = mine[inside], np.searchsorted(cells, key[inside])
            out[members] = True
            if sides:
                side[members] = _sides(points[members], slot, len(cells), planes, h)
            finer[obj] = _finer_candidates(prep, obj, near, theirs, cells[touched], shape, big, h)
    return out, finer, side


def _point_planes(prep, crossing, crossed):
    """``(cell (p,), anchor (p, 3), facing (p, 3), weight (p,))``: the planes of the surfaces
    that the points ``crossing`` run across their cells ``crossed`` with: one per other object
    and main direction of its normal there (a wall's two faces and its end), through its
    point of least index in the cell (the same planes whatever order the points come in),
    weighed by how many of its points lie there."""
    n = prep.normals[crossing]
    axis = np.argmax(np.abs(n), axis=1)
    surface = prep.owner[crossing] * 6 + 2 * axis + (n[np.arange(len(n)), axis] > 0)
    order = np.lexsort((crossing, surface, crossed))
    cell, surface, point = crossed[order], surface[order], crossing[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = (cell[1:] != cell[:-1]) | (surface[1:] != surface[:-1])
    weight = np.diff(np.append(np.flatnonzero(first), len(order)))
    return [cell[first], prep.points[point[first]], prep.normals[point[first]], weight]


def _sides(points, slot, cells, planes, h):
    """``(m,)``: on which side of the planes crossing its cell (``slot (m,)`` of ``cells``)
    each of ``points (m, 3)`` lies, as bits (a point on a plane counts as in front of it):
    the SIDE_PLANES weightiest planes of each cell (a triangle larger than the cell first,
    then the surfaces with the most points there: a wall before the pegs at its foot).
    ``planes``: ``(cell, anchor, facing, weight)``, see :func:`_point_planes`."""
    cell, anchor, facing, weight = planes
    order = np.lexsort((-weight, cell))
    anchor, facing = anchor[order], facing[order]
    count = np.bincount(cell, minlength=cells)
    start = np.cumsum(count) - count
    code = np.zeros(len(points), dtype=np.int64)
    for k in range(SIDE_PLANES):
        has = np.flatnonzero(count[slot] > k)
        at = start[slot[has]] + k
        ahead = np.einsum("mc,mc->m", points[has] - anchor[at], facing[at]) > -ON_PLANE * h
        code[has] |= ahead.astype(np.int64) << k
    return code


def _finer_candidates(prep, obj, near, theirs, crossed, shape, big, h):
    """What can cross the halves of an object's ``crossed`` cells (keys in a lattice of
    ``shape``, edge ``h``): the other objects' points ``near`` (their keys ``theirs``) in
    those cells or up to AROUND cells from them, and the triangles larger than a half:
    ``big`` (those larger than a cell) and those with a corner among those points. A
    triangle no larger than a cell (its box at most ``h`` along each axis) that passes
    :func:`~.geometry.near_any_triangle` for a half's centre has that centre within its box
    grown by the half's radius (0.43 h), so each of its corners lies within 1.43 h of the
    crossed cell along each axis: within AROUND = 2 cells."""
    steps = np.stack(np.meshgrid(*[np.arange(-AROUND, AROUND + 1)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    around = np.array(np.unravel_index(crossed, shape)).T[:, None, :] + steps[None]
    ok = in_box(around, np.zeros(3, dtype=np.int64), shape - 1)
    keys = np.ravel_multi_index(around[ok].T, shape)
    if np.prod(shape.astype(np.float64)) <= LISTED_AT_MOST:  # a flag per cell of the lattice: no sort
        near = near[listed_ranks(keys, int(np.prod(shape)))[0][theirs]]
    else:
        near = near[np.isin(theirs, np.unique(keys))]
    tris, _ = triangles_at(prep.corner_triangles, near)
    tris = tris[(prep.tri_owner[tris] != obj) & (prep.tri_extent[tris] > 0.5 * h)]
    return near, np.union1d(big, tris)
