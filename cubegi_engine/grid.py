"""Uniform probe grid: probe positions and trilinear weights (the probes that see a point:
:mod:`.visibility`).

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
from typing import Protocol

import numpy as np

__all__ = ["Grid", "ProbeGrid", "GridSet", "ProbeSubset", "fit_bounds", "probes_used", "PointCells", "points_by_cell"]


class Grid(Protocol):
    """The protocol every kind of grid implements (see the module docstring)."""

    @property
    def count(self) -> int: ...

    def positions(self) -> np.ndarray: ...

    def trilinear(self, points) -> tuple[np.ndarray, np.ndarray]: ...

    def point_cell_edge(self, points) -> np.ndarray: ...

    def parts(self) -> list: ...

    def whole(self) -> "Grid": ...

    def kept(self) -> np.ndarray: ...

    def displacements(self) -> np.ndarray: ...

    def uniform_cell(self) -> np.ndarray | None: ...


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
        return self.of_whole(*self.grid.trilinear(points))

    def of_whole(self, index, weight):
        """:meth:`trilinear` from the whole grid's ``(index, weight)`` of the same points
        (``weight`` is taken over: the left-out probes' set to zero in place)."""
        mine = self._number[index]
        weight[mine < 0] = 0.0
        return np.maximum(mine, 0, out=mine), weight

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


@dataclass
class PointCells:
    """The points in groups that share their 8 probes (a cell of the grid): ``order (s,)``
    the points group by group, ``bounds (g + 1,)`` each group's span in it, ``probes (g, 8)``
    each group's probes, ``rank (s,)`` each point's place in ``order``."""

    order: np.ndarray
    bounds: np.ndarray
    probes: np.ndarray
    rank: np.ndarray


# Rows checked at a time against their group's probes (points_by_cell).
CHECK_CHUNK = 65536
_PROBE_HASH = np.random.default_rng(0x5EED).integers(1, 2**62, 8, dtype=np.int64) | 1
# Points are interpolated cell by cell (:meth:`~.transport.Transport.interpolate`) (two matrix products each, where one per
# point was 3x slower at a million points) where their groups average at least this many points.
CELL_POINTS = 256


def points_by_cell(index):
    """:class:`PointCells` of points whose 8 probes are ``index (s, 8)``, or None where the
    groups would average fewer than CELL_POINTS points (few points, or scattered probes)."""
    s = len(index)
    if s < CELL_POINTS:
        return None
    index = np.asarray(index)
    # Grouped by a hash of the 8 probes (int64, wrapping), checked row by row in chunks (no
    # second (s, 8) array): rows that differ under one hash leave the points ungrouped.
    key = np.asarray(index, dtype=np.int64) @ _PROBE_HASH[: index.shape[1]]
    order = np.argsort(key, kind="stable")
    starts = np.flatnonzero(key[order[1:]] != key[order[:-1]]) + 1
    if (len(starts) + 1) * CELL_POINTS > s:
        return None
    bounds = np.concatenate([[0], starts, [s]])
    probes = index[order[bounds[:-1]]]
    group = np.repeat(np.arange(len(probes)), np.diff(bounds))
    for a in range(0, s, CHECK_CHUNK):
        if not np.array_equal(index[order[a:a + CHECK_CHUNK]], probes[group[a:a + CHECK_CHUNK]]):
            return None
    rank = np.empty(s, dtype=np.int64)
    rank[order] = np.arange(s)
    return PointCells(order, bounds, probes, rank)
