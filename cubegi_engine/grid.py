"""Uniform probe grid: probe positions, trilinear weights, and visibility-aware weights.

Pure numpy; must not import bpy.

Probes sit at the centres of the ``nx x ny x nz`` cells that divide the grid's box, as in
the paper ("render a cube map at the center of each volume"). Probe ``(ix, iy, iz)`` has the
flat index ``ix + nx * (iy + ny * iz)``. A point outside the box of probe centres takes the
nearest face of that box (clamped trilinear), so every point gets weights summing to 1.

Three kinds of grid share one protocol, so callers never ask which kind they hold:
:class:`ProbeGrid` (one box), :class:`GridSet` (several, each point using one) and
:class:`ProbeSubset` (the probes of either that a bake captures). Each has ``count``,
``positions()``, ``trilinear(points)``, ``point_cell_edge(points)`` and:

- ``parts()``: ``[(ProbeGrid, first probe index)]``, its boxes in probe order;
- ``whole()``: the grid whose probes it numbers a subset of (itself if none);
- ``kept()``: the indices of the whole grid's probes it holds, in its order;
- ``displacements()``: ``(count, 3)``, where each probe was moved from its cell centre;
- ``uniform_cell()``: the cell size ``(3,)`` where every probe has the same, else None.
"""

from dataclasses import dataclass

import numpy as np

from . import cubemap
from .geometry import POINT_CHUNK, chunks, cut_triangles

__all__ = ["ProbeGrid", "GridSet", "ProbeSubset", "fit_bounds", "visibility_weights", "probes_in_front", "probes_used"]


class _WholeGrid:
    """The Grid protocol's part for a grid that numbers all its own probes, each at its cell
    centre (a ProbeGrid, a GridSet)."""

    def whole(self):
        return self

    def kept(self):
        return np.arange(self.count)

    def displacements(self):
        return np.zeros((self.count, 3))


@dataclass(frozen=True)
class ProbeGrid(_WholeGrid):
    """A box ``lo``..``hi`` (world units) cut into ``resolution`` cells, one probe in each."""

    lo: tuple
    hi: tuple
    resolution: tuple

    def __post_init__(self):
        res = tuple(int(r) for r in self.resolution)
        if len(res) != 3 or min(res) < 1:
            raise ValueError(f"grid resolution must be three integers >= 1, got {self.resolution}")
        lo = np.asarray(self.lo, dtype=np.float64)
        hi = np.asarray(self.hi, dtype=np.float64)
        if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError("grid bounds must be two finite 3-vectors")
        if np.any(hi <= lo):
            raise ValueError(f"grid bounds are empty: lo={lo.tolist()} hi={hi.tolist()}")
        object.__setattr__(self, "resolution", res)
        object.__setattr__(self, "lo", tuple(lo.tolist()))
        object.__setattr__(self, "hi", tuple(hi.tolist()))

    @property
    def count(self):
        nx, ny, nz = self.resolution
        return nx * ny * nz

    @property
    def cell_size(self):
        """Cell edge lengths ``(3,)`` float64."""
        return (np.asarray(self.hi) - np.asarray(self.lo)) / np.asarray(self.resolution)

    def point_cell_edge(self, points):
        """The smallest cell edge of the grid each point uses, ``(s,)`` float64."""
        return np.full(len(points), float(np.min(self.cell_size)))

    # The Grid protocol (see the module docstring), for every kind of grid alike.
    def parts(self):
        return [(self, 0)]

    def uniform_cell(self):
        return self.cell_size

    def positions(self):
        """Probe centres ``(count, 3)`` float64, x fastest."""
        lo, h = np.asarray(self.lo), self.cell_size
        axes = [lo[a] + (np.arange(self.resolution[a]) + 0.5) * h[a] for a in range(3)]
        z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
        return np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)

    def trilinear(self, points):
        """The 8 surrounding probes of every point and their trilinear weights.

        points: ``(s, 3)``. Returns ``(index (s, 8) int64, weight (s, 8) float64)``; weights are
        non-negative and sum to 1 per point.
        """
        p = np.asarray(points, dtype=np.float64)
        res = np.asarray(self.resolution)
        # Per axis, contiguous rows (3, s); corner k = bx + 2 by + 4 bz, built as (8, s).
        t = ((p - np.asarray(self.lo)) / self.cell_size - 0.5).T.copy()
        np.clip(t, 0.0, (res - 1.0)[:, None], out=t)
        i0 = np.minimum(t.astype(np.int64), np.maximum(res - 2, 0)[:, None])
        f = t - i0
        g = 1.0 - f
        i1 = np.minimum(i0 + 1, (res - 1)[:, None])
        r0, r01 = int(res[0]), int(res[0] * res[1])
        wxy = (g[0] * g[1], f[0] * g[1], g[0] * f[1], f[0] * f[1])
        ixy = (i0[0] + r0 * i0[1], i1[0] + r0 * i0[1], i0[0] + r0 * i1[1], i1[0] + r0 * i1[1])
        z0, z1 = r01 * i0[2], r01 * i1[2]
        w = np.empty((8, len(p)), dtype=np.float64)
        idx = np.empty((8, len(p)), dtype=np.int64)
        for k in range(4):
            np.multiply(wxy[k], g[2], out=w[k])
            np.multiply(wxy[k], f[2], out=w[k + 4])
            np.add(ixy[k], z0, out=idx[k])
            np.add(ixy[k], z1, out=idx[k + 4])
        return np.ascontiguousarray(idx.T), np.ascontiguousarray(w.T)


class GridSet(_WholeGrid):
    """Several probe grids baked together; each point uses one of them.

    The rule for a point: of the grids whose boxes contain it, the one with the smallest
    cell volume (the finest); on a tie, the first given. A point inside no grid uses the
    grid whose box is nearest (the finest of those at the same distance), with clamped
    trilinear weights at that box's faces. A grid's probes that lie inside a finer grid's
    box are left out of its points' weights (that region is the finer grid's: a coarse probe
    inside a room must not light the ground outside it); a point left with no probe gets
    all-zero weights (no probe light; the bake notes how many).
    Probes are numbered grid after grid.
    """

    def __init__(self, grids):
        self.grids = tuple(grids)
        if not self.grids:
            raise ValueError("a grid set needs at least one probe grid")
        counts = [g.count for g in self.grids]
        self.first_probe = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)  # (grids,) each one's first
        self.count = int(sum(counts))

    def parts(self):
        return list(zip(self.grids, (int(f) for f in self.first_probe)))

    def uniform_cell(self):
        return None  # cells differ between grids

    def positions(self):
        return np.concatenate([g.positions() for g in self.grids])

    def assign(self, points):
        """Which grid each point uses, ``(s,)`` int64 (the rule above)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        gap = np.stack(
            [np.linalg.norm(np.maximum(np.maximum(np.asarray(g.lo) - p, p - np.asarray(g.hi)), 0.0), axis=1) for g in self.grids],
            axis=1,
        )  # (s, g): distance from each point to each grid's box (0 inside)
        volume = np.array([float(np.prod(g.cell_size)) for g in self.grids])
        nearest = gap <= gap.min(axis=1, keepdims=True)
        # Among the nearest boxes, the smallest cells; argmin picks the first on a tie.
        return np.argmin(np.where(nearest, volume[None, :], np.inf), axis=1)

    def trilinear(self, points):
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        which = self.assign(p)
        index = np.zeros((len(p), 8), dtype=np.int64)
        weight = np.zeros((len(p), 8), dtype=np.float64)
        volume = [float(np.prod(g.cell_size)) for g in self.grids]
        for g, grid in enumerate(self.grids):
            sel = which == g
            if not sel.any():
                continue
            i, w = grid.trilinear(p[sel])
            pos = grid.positions()
            covered = np.zeros(grid.count, dtype=bool)
            for h, other in enumerate(self.grids):
                if volume[h] < volume[g] or (volume[h] == volume[g] and h < g):
                    covered |= np.all((pos >= np.asarray(other.lo)) & (pos <= np.asarray(other.hi)), axis=1)
            if covered.any():
                kept = w * ~covered[i]
                total = kept.sum(axis=1, keepdims=True)
                w = kept / np.maximum(total, 1e-300)
            index[sel], weight[sel] = i + self.first_probe[g], w
        return index, weight

    def point_cell_edge(self, points):
        edges = np.array([float(np.min(g.cell_size)) for g in self.grids])
        return edges[self.assign(points)]


class ProbeSubset:
    """The probes of ``grid`` (a ProbeGrid or GridSet) that ``keep`` ``(grid.count,)`` bool
    names, numbered in their order: what a bake captures when the rest light no point (or
    sit inside geometry). A left-out probe takes no weight (a point whose probes are all
    left out gets none). ``displacement`` ``(grid.count, 3)``: where a probe was moved from
    its cell centre (out of geometry: :mod:`cubegi_engine.placement`); it still takes its
    centre's trilinear weights."""

    def __init__(self, grid, keep, displacement=None):
        self.grid = grid
        self.keep = np.flatnonzero(np.asarray(keep, dtype=bool))
        self.count = len(self.keep)
        self._number = np.full(grid.count, -1, dtype=np.int64)
        self._number[self.keep] = np.arange(self.count)
        moved = displacement is not None and np.any(displacement)
        self._displacement = np.asarray(displacement, dtype=np.float64)[self.keep] if moved else None

    def parts(self):
        return self.grid.parts()

    def whole(self):
        return self.grid

    def kept(self):
        return self.keep

    def displacements(self):
        return np.zeros((self.count, 3)) if self._displacement is None else self._displacement

    def uniform_cell(self):
        return None  # placement decides on whole grids; a subset's probes use their cubic edge

    @property
    def moved(self) -> int:
        return int(np.count_nonzero(np.any(self.displacements() != 0.0, axis=1)))

    @property
    def left_out(self) -> int:
        return int(self.grid.count - self.count)

    def positions(self):
        pos = self.grid.positions()[self.keep]
        return pos if self._displacement is None else pos + self._displacement

    def trilinear(self, points):
        index, weight = self.grid.trilinear(points)
        mine = self._number[index]
        return np.maximum(mine, 0), np.where(mine >= 0, weight, 0.0)

    def point_cell_edge(self, points):
        return self.grid.point_cell_edge(points)

    def expand(self, values, fill=0):
        """Per-probe ``values`` of this subset as the whole grid's (``fill`` for the rest)."""
        values = np.asarray(values)
        out = np.full((self.grid.count,) + values.shape[1:], fill, dtype=values.dtype)
        out[self.keep] = values
        return out


def probes_used(grid, points) -> np.ndarray:
    """``(grid.count,)`` bool: the probes that give any of ``points`` a trilinear weight."""
    index, weight = grid.trilinear(points)
    used = np.zeros(grid.count, dtype=bool)
    used[index[weight > 0]] = True
    return used


def fit_bounds(lo, hi, spacing=None, max_probes=4096):
    """A grid resolution for the box ``lo``..``hi`` with cells of about ``spacing``.

    Without a spacing, one is chosen so that the longest side gets about 8 cells. The
    resolution is capped so that the probe count stays at or below ``max_probes``.
    """
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    size = np.maximum(hi - lo, 1e-12)
    if spacing is None:
        spacing = size.max() / 8.0
    res = np.maximum(1, np.round(size / spacing)).astype(np.int64)
    while np.prod(res) > max_probes:
        res = np.maximum(1, np.floor(res * 0.9)).astype(np.int64)
    return tuple(int(r) for r in res)


# How far behind a point's tangent plane (in cells) a probe may stand and still light it.
BEHIND = 0.1


def probes_in_front(probe_pos, probe_valid, points, normals, index, weight):
    """``(s, 8)``: the weights ``weight`` of each point's valid probes in front of its
    tangent plane, whether they see it or not, normalised (zeros where there is none)."""
    height = np.einsum("skc,sc->sk", probe_pos[index] - points[:, None, :], normals)
    w = weight * probe_valid[index] * (height > 0)
    return w / np.maximum(w.sum(axis=1, keepdims=True), 1e-300)


def visibility_weights(grid, probe_pos, probe_dist, probe_valid, points, normals, index, weight, cover=None, both=False):
    """Trilinear weights with probes that cannot see a point, or are invalid, left out.

    A probe is kept for a point if the point, lifted off its surface along the normal by a
    tenth of the smallest cell edge, is no farther from the probe than the first surface the
    probe's cube map records in that direction (the depth test of a shadow map), and the
    probe stands no more than BEHIND cells behind the point's tangent plane. This stops
    light leaking through walls thinner than a cell, and round convex edges (a probe just
    above a block's sunlit top would light the block's sides with it). If every probe of a
    point is left out, the point keeps its plain trilinear weights over the valid probes in
    front of its surface; with none, it gets no probe light (a block's underside below the
    lowest probes: the near field lights it). With ``both``, also the weights where such a
    point keeps the probes behind its plane that see it: ``(weights, kept behind)``.

    probe_pos: ``(p, 3)``; probe_dist: ``(p, 6, n, n)`` distance to the first surface (inf
    where the probe sees sky); probe_valid: ``(p,)`` bool; points, normals: ``(s, 3)``;
    index, weight: ``(s, 8)`` from :meth:`ProbeGrid.trilinear`. Returns new weights ``(s, 8)``.

    ``cover`` = ``(probe_tid (p, 6, n, n), triangles (t, 3), triangle_object (t,), vertices,
    point_object (s,), triangle_normals (t, 3), edge_neighbours (t, 3))`` (the triangles the
    probes drew, over ``vertices``) adds a
    test the depth map's tolerance is too coarse for: a triangle of another object (or of
    the same object, facing away from the point: the far side of a thin wall) that the
    probe's texel sees towards the point, whose plane the exact ray from the probe crosses
    in front of the point, inside that triangle, covers the point (a rug over a floor, a
    thin wall between rooms). A point that every probe misses and some other object covers
    gets no probe light, instead of falling back to its plain weights.
    """
    if len(points) > POINT_CHUNK:
        def part(sl):  # the cover's point_object is per point
            return None if cover is None else (*cover[:4], cover[4][sl], *cover[5:])

        parts = [visibility_weights(grid, probe_pos, probe_dist, probe_valid, points[sl], normals[sl], index[sl], weight[sl],
                                    part(sl), both) for sl in chunks(len(points))]
        if both:
            return tuple(np.concatenate(p) for p in zip(*parts))
        return np.concatenate(parts)
    n = probe_dist.shape[-1]
    cell = grid.point_cell_edge(points)[:, None]  # (s, 1)
    q = points[:, None, :] + 0.1 * cell[..., None] * normals[:, None, :]  # (s, 1, 3)
    v = q - probe_pos[index]  # (s, 8, 3)
    dist = np.linalg.norm(v, axis=-1)
    face, row, col, _, _ = cubemap.direction_to_texel(np.where(dist[..., None] > 0, v, 1.0), n)
    seen = probe_dist[index, face, row, col]
    # Tolerance: two texels' worth of angle at that distance plus a hundredth of a cell.
    tol = dist * (4.0 / n) + 0.01 * cell
    visible = dist <= seen + tol
    covered = np.zeros_like(visible)
    if cover is not None:
        covered = _covered(cover, probe_pos[index], points, normals, index, face, row, col, n, cell)
        visible &= ~covered
    valid = probe_valid[index]
    # A probe more than BEHIND cells behind the point's tangent plane sees its hemisphere from
    # the far side: at a convex edge nothing hides it.
    height = np.einsum("skc,sc->sk", probe_pos[index] - points[:, None, :], normals)
    seen_by = weight * (visible & valid)
    w = seen_by * (height >= -BEHIND * cell)
    total = w.sum(axis=1, keepdims=True)
    # A point no probe sees takes the valid probes in front of its surface (a vertex in a
    # corner too tight for the grid); none behind it (the outer face of a wall, whose probes
    # are all inside the room: their light would leak out).
    fallback = probes_in_front(probe_pos, probe_valid, points, normals, index, weight)
    dark = (seen_by.sum(axis=1) <= 1e-9) & covered.any(axis=1)  # no probe, on either side, sees it

    def settled(fallback):
        out = np.where(total > 1e-9, w, fallback)
        out = out / np.maximum(out.sum(axis=1, keepdims=True), 1e-300)  # a point with no probe at all keeps zeros
        out[dark] = 0.0
        return out

    if not both:
        return settled(fallback)
    return settled(fallback), settled(np.where(fallback.sum(axis=1, keepdims=True) > 1e-9, fallback, seen_by))


# How many edges away from a seen triangle the cover test looks for the one the ray crosses,
# and how many (point, probe) pairs it searches at a time.
COVER_RINGS, RING_CHUNK = 2, 16384


def _blocks(tid, tri_object, tri_normals, point_object, normals):
    """Whether triangles ``tid`` may cover points of ``point_object`` facing ``normals``:
    another object's, or the far side of a thin part of the same one (facing away)."""
    safe = np.maximum(tid, 0)
    nrm = tri_normals[safe]
    facing_away = np.einsum("...c,...c->...", nrm, normals) < -0.5 * np.linalg.norm(nrm, axis=-1)
    return (tri_object[safe] != point_object) | facing_away


def _unique_per_row(ids, tried):
    """``ids (m, k)`` with each row's repeats, and the ids in ``tried``'s row, set to -1; the
    -1 entries moved to the end and the columns that are -1 in every row dropped."""
    both = np.concatenate([tried, ids], axis=1)
    order = np.argsort(both, axis=1, kind="stable")
    srt = np.take_along_axis(both, order, axis=1)
    dup = np.zeros_like(srt, dtype=bool)
    dup[:, 1:] = srt[:, 1:] == srt[:, :-1]
    # An id is new if it comes from ``ids`` and its first occurrence in the sorted row is from ``ids``.
    from_ids = order >= tried.shape[1]
    first = ~dup
    group_first_from_ids = np.maximum.accumulate(np.where(first, np.arange(srt.shape[1])[None, :], 0), axis=1)
    new = from_ids & np.take_along_axis(from_ids, group_first_from_ids, axis=1) & first & (srt >= 0)
    out = np.where(new, srt, -1)
    out = -np.sort(-out, axis=1)  # the new ids first, the -1s at the end
    keep = (out >= 0).any(axis=0)
    return out[:, keep] if keep.any() else out[:, :1]


def _covered(cover, eyes, points, normals, index, face, row, col, n, cell):
    """``(s, 8)``: another object's triangle lies between each probe and point (see above).

    The texel towards the point and its 8 neighbours are asked which triangles they see;
    the exact ray from the probe to the point is cut with each one's plane, and it covers
    the point if the cut lies inside that triangle or one across its edges, in front of the
    point. (At a grazing angle the texels around the ray may all see neighbours of the
    triangle it really crosses, near a rug's edge; a cut near but outside the other object
    must not count, or the floor around a rug would go dark.)
    """
    probe_tid, triangles, tri_object, vertices, point_object, tri_normals, neighbours = cover
    q = points[:, None, :] + 1e-3 * cell[..., None] * normals[:, None, :]
    ray = q - eyes
    d = np.linalg.norm(ray, axis=-1)
    u = ray / np.maximum(d, 1e-300)[..., None]
    eps = 1e-4 * cell
    covered = np.zeros(index.shape, dtype=bool)
    # Per pair and texel: a seen candidate the ray's plane cut lies ahead of but outside of.
    missed = np.full(index.shape + (9,), -1, dtype=np.int32)
    for j, (dr, dc) in enumerate((dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)):
        tid = probe_tid[index, face, np.clip(row + dr, 0, n - 1), np.clip(col + dc, 0, n - 1)]
        candidate = (tid >= 0) & ~covered & _blocks(tid, tri_object, tri_normals, point_object[:, None], normals[:, None, :])
        pick = np.nonzero(candidate)
        if not len(pick[0]):
            continue
        t, inside, _ = cut_triangles(eyes[pick], u[pick], tid[pick], triangles, vertices)
        ahead = (t > 0) & (t < d[pick] - eps[pick[0], 0])
        covered[pick] = inside & ahead
        # Another object's triangles only (a rug over a floor): a thin part's far side is seen
        # whole by the texels around the ray.
        miss = ahead & ~inside & (tri_object[tid[pick]] != point_object[pick[0]])
        missed[pick[0][miss], pick[1][miss], j] = tid[pick][miss]
    # Where no seen triangle holds the cut: the same objects' triangles up to COVER_RINGS edges
    # around the seen ones (each tried once per pair).
    need = np.nonzero(~covered & (missed >= 0).any(axis=2))
    for start in range(0, len(need[0]) if COVER_RINGS else 0, RING_CHUNK):  # bounded temporaries
        pairs = (need[0][start : start + RING_CHUNK], need[1][start : start + RING_CHUNK])
        frontier = missed[pairs]  # (m, 9)
        tried = frontier
        found = np.zeros(len(pairs[0]), dtype=bool)
        eye, ray_u, depth = eyes[pairs], u[pairs], d[pairs] - eps[pairs[0], 0]
        for _ in range(COVER_RINGS):
            parent = np.repeat(frontier, 3, axis=1)
            ring = neighbours[np.maximum(frontier, 0)].reshape(len(frontier), -1)  # (m, 3k)
            ring = np.where((parent >= 0) & (ring >= 0) & (tri_object[np.maximum(ring, 0)] == tri_object[np.maximum(parent, 0)]), ring, -1)
            ring = _unique_per_row(ring, tried)
            for k in range(ring.shape[1]):
                sel = np.flatnonzero((ring[:, k] >= 0) & ~found)
                if not len(sel):
                    continue
                t, inside, _ = cut_triangles(eye[sel], ray_u[sel], ring[sel, k], triangles, vertices)
                found[sel[inside & (t > 0) & (t < depth[sel])]] = True
            tried = np.concatenate([tried, ring], axis=1)
            frontier = ring
        covered[pairs[0][found], pairs[1][found]] = True
    return covered
