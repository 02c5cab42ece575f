"""Probes inside geometry, found before the capture: moved out of it, or left out.

Pure numpy; must not import bpy.

A probe whose cube map would see back faces over much of the sphere sits inside a solid (a
wall, a block, furniture) and lights nothing it should. The capture's own test finds that
only after drawing it (:data:`cubegi_engine.transport.INSIDE_BACKFACE_SHARE`). Here the same
question is asked first, cheaply: PROBE_RAYS rays from each probe (a Fibonacci sphere),
traced against the triangles within PROBE_REACH cells (a voxel index, as the near field's).
A probe is inside when more than INSIDE_SHARE of its rays meet a back face first. The voxel
index leaves out as crowded a probe with more than MAX_NEARBY triangles around it (dense,
finely cut geometry): where the host has a ray caster of its own (:class:`HostRays`), such
a probe's rays are cast through it.

Such a probe is moved out, as RTXGI's probe relocation does: each back face one of its rays
met is a way out (BEYOND cells beyond it, within MAX_SHIFT of the cell centre on every axis);
each way out is asked again, and the probe goes to the one that leaves it outside with the
most room to the nearest surface (at least MARGIN cells: a probe hugging a surface sees it
as half its sphere; a way out that stops among crowded geometry is not taken, its room
unknown). With no such way it is left out before the capture (it would be drawn and then
thrown away). A crowded probe found inside is left out, not moved: the probes around it
light its points better than it does from where its ways out lead (a white cup's inside
under the Cornell box's lamp, its four probes in the cup's 6 mm wall: +3.0% against Cycles
left out, +22.6% moved into its hollow, +8.7% moved just outside it). Where every probe
reads as inside (a mesh whose normals all point the wrong way) none is moved or left out:
the capture's test and the bake's note on back faces take over. The interpolation keeps
the grid's trilinear weights (DDGI's choice); what the probe sees, and which points it can
see, come from where it now stands. A probe deeper inside a solid than PROBE_REACH is not
seen by this test; the capture's own test still leaves it out.
"""

import time
from dataclasses import dataclass

import numpy as np

from . import sh
from .geometry import sorted_unique
from .spatial import VoxelIndex, corners_of
from .transport import INSIDE_BACKFACE_SHARE as INSIDE_SHARE  # the capture's own test, asked first

__all__ = ["Placement", "HostRays", "place", "trace", "inside", "PROBE_RAYS", "PROBE_REACH", "INSIDE_SHARE", "MAX_SHIFT", "MARGIN", "BEYOND"]

PROBE_RAYS = 64
PROBE_REACH = 1.0  # in cell edges
MAX_SHIFT = 0.45  # of the cell edge, per axis
MARGIN = 0.1  # of the cell edge, beyond the surface passed through
WAYS_OUT = 8  # back faces tried per probe, nearest first
# How far beyond each back face a way out may stop, in cell edges (the room test picks).
# Only MARGIN made probes stop a tenth of a cell from a wall they had been inside, where
# they see it as half their sphere: the benchmark's thin wall at 5 and 7 cells went 6.9 ->
# 7.5% and 5.7 -> 6.0% moved, against 6.6% and 5.3% with these.
BEYOND = (0.1, 0.2, 0.3, 0.4)


@dataclass
class Placement:
    """What :func:`place` decided: ``keep (p,)`` bool (probes captured), ``displacement (p, 3)``
    (each kept probe's move from its cell centre; zero for most), ``moved`` and
    ``left_out`` counts (``crowded`` of them: among finely cut geometry, never moved), and the
    seconds it took."""

    keep: np.ndarray
    displacement: np.ndarray
    moved: int
    left_out: int
    seconds: float = 0.0
    crowded: int = 0  # of ``left_out``: crowded probes, not moved (see the module docstring)


def _rays():
    return sh.fibonacci_sphere(PROBE_RAYS)


class HostRays:
    """The probes' rays through the host's :class:`~cubegi_engine.rays.RayCaster` (``caster``),
    ``sheet (k,)`` bool over its triangles (None: none): those of two-sided objects, met
    from behind as their twin's front."""

    def __init__(self, caster, sheet=None):
        self.caster, self.sheet = caster, sheet

    def trace(self, positions, cell, dirs):
        """:func:`trace`'s ``(t, back)`` of probes at ``positions (p, 3)``."""
        p, k = len(positions), len(dirs)
        origins = np.repeat(np.asarray(positions, dtype=np.float64), k, axis=0)
        reach = np.repeat(PROBE_REACH * np.asarray(cell, dtype=np.float64), k)
        hits = self.caster.cast(origins, np.tile(dirs, (p, 1)), reach)
        back = hits.hit & ~hits.front
        if self.sheet is not None:
            back &= ~self.sheet[np.maximum(hits.triangle, 0)]
        return hits.t.reshape(p, k), back.reshape(p, k)


def trace(positions, index, cell, dirs=None):
    """Rays from probes at ``positions (p, 3)`` among the triangles of ``index`` (a voxel
    index), reaching ``cell (p,)`` x PROBE_REACH: ``(t (p, k) hit distance, inf where none;
    back (p, k) the hit is a back face; crowded (p,) the probes the index left out, whose
    rays meet nothing)`` for the ``k`` directions ``dirs`` (PROBE_RAYS)."""
    dirs = _rays() if dirs is None else dirs
    p = len(positions)
    reach = PROBE_REACH * np.asarray(cell, dtype=np.float64)
    # Two half-spaces make the whole sphere of candidates.
    up = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (p, 3))
    found = [index.candidates(positions, n, reach) for n in (up, -up)]
    pair = sorted_unique(np.concatenate([pp * len(index.a) + tt for pp, tt, _ in found]))
    pair_p, pair_t = pair // len(index.a), pair % len(index.a)
    rays = np.broadcast_to(dirs, (p,) + dirs.shape)
    t, tri, _, front = index.trace(positions, up, rays, reach, np.zeros(p), pair_p, pair_t)
    return t, (tri >= 0) & ~front, found[0][2] | found[1][2]


def inside(t, back):
    """``(p,)`` bool: probes whose rays (from :func:`trace`) meet back faces first more than
    INSIDE_SHARE of the time."""
    return back.mean(axis=1) > INSIDE_SHARE


def place(grid, triangles_points, triangles, candidates=None, rays=None) -> Placement:
    """Decide, for the probes of ``grid`` (``candidates (p,)`` bool: the ones to ask; all by
    default), which sit inside the geometry ``triangles`` over ``triangles_points``, which
    of those move out and where (see the module docstring). ``rays``: None, or a callable
    giving a :class:`HostRays` over those triangles (asked only for crowded probes)."""
    t0 = time.perf_counter()
    positions = grid.positions()
    p = len(positions)
    keep = np.ones(p, dtype=bool) if candidates is None else np.asarray(candidates, dtype=bool).copy()
    displacement = np.zeros((p, 3))
    if not len(triangles) or not keep.any():
        return Placement(keep, displacement, 0, 0, time.perf_counter() - t0)
    cell = grid.point_cell_edge(positions)
    index = VoxelIndex.over(corners_of(np.asarray(triangles_points, dtype=np.float64), np.asarray(triangles)),
                            float(np.min(cell)) * PROBE_REACH)
    dirs = _rays()
    asked = np.flatnonzero(keep)
    t, back, crowded = trace(positions[asked], index, cell[asked], dirs)
    within = inside(t, back)
    crowded_inside = np.zeros(0, dtype=np.int64)
    if rays is not None and crowded.any():  # left out where found inside (see the module docstring)
        at = asked[crowded]
        crowded_inside = at[inside(*rays().trace(positions[at], cell[at], dirs))]
        keep[crowded_inside] = False
    stuck, t, back = asked[within], t[within], back[within]
    keep[stuck] = False
    if len(stuck):
        # The ways out: through the WAYS_OUT nearest back faces its rays met, the first of
        # BEYOND beyond each; then, along the way that leaves the most room, the farther ones.
        tb = np.where(back, t, np.inf)
        near = np.argsort(tb, axis=1)[:, :WAYS_OUT]
        row = np.repeat(np.arange(len(stuck)), near.shape[1])
        ray = near.ravel()
        real = np.isfinite(tb[row, ray])
        row, ray = row[real], ray[real]
        sizes = _cell_sizes(grid, positions, cell)

        def stops(row, ray, beyond):
            """The stops ``beyond`` (cells) past each way's back face that stay in the cell,
            and the room each leaves: ``(row, ray, step, clear)``."""
            probe = stuck[row]
            step = (t[row, ray] + beyond * cell[probe])[:, None] * dirs[ray]
            fits = np.all(np.abs(step) <= MAX_SHIFT * sizes[probe], axis=1)
            row, ray, probe, step = row[fits], ray[fits], probe[fits], step[fits]
            if not len(row):
                return row, ray, step, np.zeros(0)
            t2, back2, crowded = trace(positions[probe] + step, index, cell[probe], dirs)
            return row, ray, step, np.where(inside(t2, back2) | crowded, -np.inf, t2.min(axis=1))  # room to the nearest surface

        found = stops(row, ray, np.full(len(row), BEYOND[0]))
        best = _most_room(found[0], found[3])
        # Farther along the best way; for a probe no first stop leaves room, along every way.
        stuck_here = found[3][best] < MARGIN * cell[stuck[found[0][best]]]
        retry = np.isin(row, found[0][best][stuck_here]) | ~np.isin(row, found[0])
        ways = (np.concatenate([found[0][best][~stuck_here], row[retry]]), np.concatenate([found[1][best][~stuck_here], ray[retry]]))
        k = len(BEYOND) - 1
        farther = stops(np.repeat(ways[0], k), np.repeat(ways[1], k), np.tile(np.asarray(BEYOND[1:]), len(ways[0])))
        row, _, step, clear = (np.concatenate([x[best], y]) for x, y in zip(found, farther))
        best = _most_room(row, clear)
        probe = stuck[row[best]]
        ok = clear[best] >= MARGIN * cell[probe]  # clear of surfaces by at least MARGIN
        displacement[probe[ok]] = step[best[ok]]
        keep[probe[ok]] = True
    if not keep.any():  # every probe reads as inside (normals turned the wrong way): keep them
        return Placement(np.asarray(candidates if candidates is not None else np.ones(p), dtype=bool).copy(),
                         np.zeros((p, 3)), 0, 0, time.perf_counter() - t0)
    moved = int(np.count_nonzero(np.any(displacement != 0.0, axis=1)))
    return Placement(keep, displacement, moved, int(len(stuck) - moved + len(crowded_inside)), time.perf_counter() - t0,
                     len(crowded_inside))


def _most_room(row, clear):
    """Indices of the candidate with the most ``clear`` room per ``row`` (a probe)."""
    order = np.lexsort((-clear, row))
    first = np.ones(len(order), dtype=bool)
    first[1:] = row[order][1:] != row[order][:-1]
    return order[first]


def _cell_sizes(grid, positions, edge):
    """Per probe, its cell's edge lengths ``(k, 3)`` (a grid set: the cubic cell ``edge``)."""
    size = grid.uniform_cell()
    if size is not None:
        return np.broadcast_to(np.asarray(size, dtype=np.float64), (len(positions), 3))
    return np.repeat(np.asarray(edge, dtype=np.float64)[:, None], 3, axis=1)
