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

from dataclasses import dataclass, replace

import numpy as np

from . import cubemap
from .geometry import POINT_CHUNK, chunks, cut_planes, edge_neighbours, triangle_planes

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


def visibility_weights(grid, probe_pos, probe_dist, probe_valid, points, normals, index, weight, cover=None, both=False,
                       sheet=None):
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

    ``cover`` (a :class:`Cover` of the triangles the probes drew) adds a
    test the depth map's tolerance is too coarse for: a triangle of another object (or of
    the same object, facing away from the point: the far side of a thin wall) that the
    probe's texel sees towards the point, whose plane the exact ray from the probe crosses
    in front of the point, inside that triangle, covers the point (a rug over a floor, a
    thin wall between rooms). A point that every probe misses and some other object covers
    gets no probe light, instead of falling back to its plain weights. ``sheet``: ``(s,)``
    bool, points of two-sided sheets, which only probes in front of their plane light.
    """
    if len(points) > POINT_CHUNK:
        parts = [visibility_weights(grid, probe_pos, probe_dist, probe_valid, points[sl], normals[sl], index[sl], weight[sl],
                                    None if cover is None else cover.rows(sl), both, None if sheet is None else sheet[sl])
                 for sl in chunks(len(points))]
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
    eyes = probe_pos[index]
    # How far each probe stands in front of the point's tangent plane.
    height = np.einsum("skc,sc->sk", eyes - points[:, None, :], normals)
    if sheet is not None:
        # A point of a two-sided sheet: a probe behind its plane is on the sheet's other side,
        # whose own twin point it lights (the depth test cannot tell the two apart).
        visible &= ~sheet[:, None] | (height > 0)
    valid = probe_valid[index]
    covered = np.zeros_like(visible)
    if cover is not None:
        # The pairs that light the point are asked first; a point that none of them lights
        # after that is dark if any other probe's ray to it is covered too (see ``dark``).
        ask = visible & valid & (weight > 0)
        covered = _covered(cover, eyes, points, normals, index, face, row, col, n, cell, ask)
        unlit = np.flatnonzero((weight * (ask & ~covered)).sum(axis=1) <= 1e-9)
        if len(unlit):
            covered[unlit] |= _covered(cover.rows(unlit), eyes[unlit], points[unlit], normals[unlit], index[unlit],
                                      face[unlit], row[unlit], col[unlit], n, cell[unlit], ~ask[unlit])
        visible &= ~covered
    # A probe more than BEHIND cells behind the point's tangent plane sees its hemisphere from
    # the far side: at a convex edge nothing hides it.
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
COVER_RINGS, RING_CHUNK = 2, 65536


@dataclass(frozen=True)
class Cover:
    """What the cover test of :func:`visibility_weights` asks: the triangle each probe
    texel saw ``probe_tid (p, 6, n, n)`` (-1: none), each triangle's object ``(t,)``, its
    :func:`~.geometry.triangle_planes` ``(t, 4, 3)`` and :func:`~.geometry.edge_neighbours`
    ``(t, 3)``, and each point's object ``(s,)``."""

    probe_tid: np.ndarray
    triangle_object: np.ndarray
    planes: np.ndarray
    neighbours: np.ndarray
    point_object: np.ndarray

    @classmethod
    def of(cls, probe_tid, triangles, vertices, triangle_object, point_object):
        return cls(probe_tid, triangle_object, triangle_planes(triangles, vertices), edge_neighbours(triangles), point_object)

    def rows(self, sl):
        """The same cover for the points ``sl``."""
        return replace(self, point_object=self.point_object[sl])


def _blocks(cover, tid, point_object, normals):
    """Whether triangles ``tid`` may cover points of ``point_object`` facing ``normals``:
    another object's, or the far side of a thin part of the same one (facing away)."""
    safe = np.maximum(tid, 0)
    facing_away = np.einsum("...c,...c->...", cover.planes[safe, 1], normals) < -0.5
    return (cover.triangle_object[safe] != point_object) | facing_away


def _covered(cover, eyes, points, normals, index, face, row, col, n, cell, ask):
    """``(s, 8)``: another object's triangle lies between each probe and point (see above),
    for the pairs ``ask (s, 8)`` (False elsewhere).

    The texel towards the point and its 8 neighbours are asked which triangles they see;
    the exact ray from the probe to the point is cut with each one's plane, and it covers
    the point if the cut lies inside that triangle or one across its edges, in front of the
    point. (At a grazing angle the texels around the ray may all see neighbours of the
    triangle it really crosses, near a rug's edge; a cut near but outside the other object
    must not count, or the floor around a rug would go dark.)
    """
    q = points[:, None, :] + 1e-3 * cell[..., None] * normals[:, None, :]
    ray = q - eyes
    d = np.linalg.norm(ray, axis=-1)
    u = ray / np.maximum(d, 1e-300)[..., None]
    depth = d - 1e-4 * cell  # a cut this far along the ray lies in front of the point
    covered = np.zeros(index.shape, dtype=bool)
    # Per pair and texel: a seen candidate of another object the ray's plane cut lies ahead of
    # but outside of.
    missed = np.full(index.shape + (9,), -1, dtype=np.int32)
    for j, (dr, dc) in enumerate((dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)):
        tid = cover.probe_tid[index, face, np.clip(row + dr, 0, n - 1), np.clip(col + dc, 0, n - 1)]
        candidate = ask & (tid >= 0) & ~covered
        rows = np.nonzero(candidate)[0]
        candidate[candidate] = _blocks(cover, tid[candidate], cover.point_object[rows], normals[rows])
        pick = np.nonzero(candidate)
        if not len(pick[0]):
            continue
        t, inside = cut_planes(eyes[pick], u[pick], tid[pick], cover.planes)
        ahead = (t > 0) & (t < depth[pick])
        covered[pick] = inside & ahead
        # Another object's triangles only (a rug over a floor): a thin part's far side is seen
        # whole by the texels around the ray.
        miss = ahead & ~inside & (cover.triangle_object[tid[pick]] != cover.point_object[pick[0]])
        missed[pick[0][miss], pick[1][miss], j] = tid[pick][miss]
    # Where no seen triangle holds the cut: the same objects' triangles up to COVER_RINGS edges
    # around the seen ones, each tried once per pair.
    need = np.nonzero(~covered & (missed >= 0).any(axis=2))
    for start in range(0, len(need[0]) if COVER_RINGS else 0, RING_CHUNK):  # bounded temporaries
        pairs = (need[0][start : start + RING_CHUNK], need[1][start : start + RING_CHUNK])
        found = _ring_search(cover, missed[pairs], eyes[pairs], u[pairs], depth[pairs])
        covered[pairs[0][found], pairs[1][found]] = True
    return covered


def _ring_search(cover, seen, eye, u, depth):
    """``(m,)``: whether each ray ``eye + t u`` (0 < t < depth) crosses a triangle up to
    COVER_RINGS edges from its ``seen (m, k)`` ones (-1: none) and of the same object.
    The (ray, triangle) pairs are kept flat, as keys ``ray * t + triangle``."""
    count = np.int64(len(cover.planes))
    rows, cols = np.nonzero(seen >= 0)
    tried = _sorted_unique(rows * count + seen[rows, cols])
    frontier = tried
    found = np.zeros(len(seen), dtype=bool)
    for _ in range(COVER_RINGS):
        ray, parent = np.divmod(frontier, count)
        ring = cover.neighbours[parent]  # (f, 3)
        keep = (ring >= 0) & (cover.triangle_object[np.maximum(ring, 0)] == cover.triangle_object[parent][:, None])
        keep &= ~found[ray][:, None]
        keys = _sorted_unique(ray[:, None].repeat(3, axis=1)[keep] * count + ring[keep])
        keys = keys[~_in_sorted(keys, tried)]
        if not len(keys):
            break
        ray, tid = np.divmod(keys, count)
        t, inside = cut_planes(eye[ray], u[ray], tid, cover.planes)
        found[ray[inside & (t > 0) & (t < depth[ray])]] = True
        tried = _sorted_unique(np.concatenate([tried, keys]))
        frontier = keys
    return found


def _in_sorted(keys, sorted_keys):
    """Whether each of ``keys`` is in the sorted array ``sorted_keys``."""
    at = np.minimum(np.searchsorted(sorted_keys, keys), max(len(sorted_keys) - 1, 0))
    return sorted_keys[at] == keys if len(sorted_keys) else np.zeros(len(keys), dtype=bool)


def _sorted_unique(keys):
    """``np.unique`` of an int array by sorting (numpy's hashed unique is many times slower
    on millions of keys)."""
    keys = np.sort(keys, kind="stable")  # timsort: the keys come in sorted runs
    return keys[np.concatenate([[True], keys[1:] != keys[:-1]])] if len(keys) else keys
