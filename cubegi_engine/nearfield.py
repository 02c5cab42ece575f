"""The near field: what a point's own short-range surroundings send it, gathered by rays.

Pure numpy; must not import bpy.

A probe sees a point's surroundings from up to a cell away. Where surfaces meet (a floor
along a wall, the underside of a block standing 2 cm above the floor, the floor under it)
it sees them from the wrong place and spreads light too evenly: the underside of the block
gets the bright floor around it. So each point with a surface close in front of it casts
``rays`` cosine-weighted rays into its hemisphere, up to ``reach`` (a share of its cell).
A ray that hits a surface within reach takes that surface's outgoing light (none from a
back face); for the directions whose rays leave, the probes' light is kept (each probe's
radiance in the hit directions is taken off the point's diffuse light). With cosine-weighted
rays the diffuse light is the mean of the radiance the rays see, so a point's light is

    l(x) = (the probes' light over the open directions) + (1 / rays) sum over hits B(hit)

It is linear like every other step: the hits are a sparse matrix over the points (the
barycentric weights of each hit triangle's corners), the open part a per-point change of
the SH basis the probes are evaluated with. It is a final gather: the probes keep seeing
the bounces as interpolated (so the kept probe field, and relighting it, stay in probe
space), and every bounce's light at the points is gathered once more from the bounce
before, near field included (:meth:`NearField.delta` per bounce, :meth:`NearField.settle` for
the tail; :mod:`cubegi_engine.series`).

What it costs, and what it leaves out: a point's candidates are the triangles within reach
with a corner in front of its tangent plane (its own flat surface never is one), so a
point in the open casts no rays. A point with more than MAX_CANDIDATES candidates, or more
than MAX_NEARBY (:mod:`.spatial`) triangles in the voxels (of edge ``reach``) around it (dense, folded
geometry: the inside of a sculpt's ear), is left out, and so is the whole near field of a scene whose
candidate pairs would exceed MAX_PAIRS (estimated from a sample first); the report names
both. Left-out points keep the probes' light. Where the host has a ray caster of its own
(Blender's BVH tree), the crowded points of the smallest objects are not left out: one point
per small cluster of them casts its rays through it, with a longer reach, and the cluster's
points gather what it gathers (the inside of a white cup or teapot, lit by itself many times
over: the probes never see in). So do the points of objects smaller than a probe cell
(SMALL_OBJECT: a table lamp's base inside its shade), and the light of the points the caster
gathers is theirs whole: the near field's balance neither counts nor scales it.
"""

import time
from dataclasses import dataclass

import numpy as np

from . import convergence, working
from .nearhits import gap_ratios, hidden_points, uncover
from .nearrays import CASTER_RAYS, cast_points, clusters, host_rays, shared_rows
from .spatial import voxel_index

__all__ = ["NearField", "Traced", "build", "trace", "started", "finish", "NEAR_REACH", "NEAR_RAYS", "MAX_CANDIDATES", "MAX_PAIRS"]

# Reach of the rays, as a share of the point's cell edge (measured on the benchmark's Cornell
# box when it was chosen: 16.2% indirect error without, 10.1% at 0.25, 9.9% at 0.5 and 1.0,
# at 6-30x the cost from 0.25 to 1.0); rays per point.
NEAR_REACH = 0.25
NEAR_RAYS = 32
# A point with more candidate triangles than this is left out; a scene with more candidate
# pairs in all than MAX_PAIRS gets no near field (each pair costs ``rays`` ray tests).
MAX_CANDIDATES = 256
MAX_PAIRS = 2_000_000
# The sample that estimates a scene's pairs; an object with at least CROWDED_SAMPLE points
# in it, all crowded, is crowded whole.
SAMPLE, CROWDED_SAMPLE = 2048, 8
# What a row keeps at most of the light it gathers in the near field's sum of bounces: a
# point all of whose rays met white surfaces has seen no opening, but 16 rays do not show
# one narrower than about 1/18 of its view (the rule of succession).
MAX_LOOP_GAIN = 1.0 - 1.0 / (CASTER_RAYS + 2)
# The sum stops once the light it estimates is left is at most this share of the brightest row's.
NEAR_SUM_TOLERANCE = 1e-4
# The points of an object smaller than this many probe cells cast their rays through the
# host's caster too, as crowded points do, with its reach (a table lamp's base inside its
# shade: the probes never see the shade's lit inside, and the near field's reach of a
# quarter cell saw little of it); 0: only the crowded points. Indirect rel. RMSE against
# Cycles, 0 -> 1: a hand-made living room at night 137.8 -> 108.3% (the lamp's base -89 ->
# -14%), the Breakfast Room 26.87 -> 25.57% (15.0 -> 15.5 s), a kitchen 395.9 -> 396.2%;
# the benchmark's five scenes, a hand-made flat and at 0.5 cells the Breakfast Room
# (26.66%): the same or within 0.01%.
SMALL_OBJECT = 1.0
# A hit on a triangle with a corner closed in and one in the open casts OPENNESS_RAYS rays of
# its own to weigh its corners' light (:func:`~.nearhits.gap_ratios`; 0: off).
OPENNESS_RAYS = 16


@dataclass
class NearField:
    """The near field of a bake's points (see the module docstring).

    rows: ``(m,)`` the points that have one; open_basis: ``(m, 9)`` what their diffuse
    basis loses to the hit directions; hit_row ``(h,)`` (index into rows), hit_corner
    ``(h, 3)`` point indices and hit_weight ``(h, 3)`` (barycentric / rays; zero for a
    back face): the hits. ``reach``: the longest ray; ``pairs``: (point, triangle) pairs
    tested; ``crowded``: points left out for too many candidates; ``skipped``: why the
    whole near field was left out ("" where it was not); ``share``: ``(m,)`` the
    cosine-weighted share of each row's view its hits cover; ``hidden``: the covered points
    counted as hidden from the hits (closed in, or resting on another surface), or None.
    """

    rows: np.ndarray
    open_basis: np.ndarray
    hit_row: np.ndarray
    hit_corner: np.ndarray
    hit_weight: np.ndarray
    rays: int
    reach: float = 0.0
    pairs: int = 0
    crowded: int = 0
    skipped: str = ""
    seconds: float = 0.0
    share: np.ndarray | None = None
    hidden: np.ndarray | None = None
    alias: tuple | None = None  # (rows (a,), theirs (a,)): rows (places) that gather what other rows gather
    crowded_objects: tuple = ()  # the objects (``owner`` indices) of the crowded points left out
    # (points (w,), whether each emitted (w,)): the points whose emitting or not decides which
    # points are hidden (:func:`~.nearhits.hidden_points`), or None where nothing was decided
    emitters: tuple | None = None
    # The points the host's caster gathers (crowded, or of a small object: SMALL_OBJECT): the
    # probes do not see what lights them (a cup's inside, a lamp's base inside its shade), so
    # the near field's balance neither counts nor scales their light (else a lamp's base,
    # lit by its shade 8x what the probes give, scaled the whole room's down 6-16%).
    whole: np.ndarray | None = None

    def emitters_changed(self, emitting) -> np.ndarray:
        """The points :attr:`hidden` depends on that started or stopped emitting, where the
        points ``emitting (s,)`` bool emit (none: it still holds)."""
        if self.emitters is None:
            return np.zeros(0, dtype=np.int64)
        watched, was = self.emitters
        return watched[np.asarray(emitting, dtype=bool)[watched] != was]

    def enclosed(self, count, at_least=0.5):
        """``(count,)`` bool: points whose near surroundings cover at least ``at_least`` of
        their view (a floor under a rug, a block's underside on the ground)."""
        out = np.zeros(count, dtype=bool)
        if self.count and self.share is not None:
            out[self.rows] = self.share >= at_least
        return out

    def replaced_rows(self, other):
        """This near field with the rows of ``other`` (of the same points) put in place of
        its own rows for those points (its reach, pairs and crowded points stay this one's:
        what a report says of the near field)."""
        if not other.count:
            return self
        drop = np.isin(self.rows, other.rows)
        keep_rows = np.flatnonzero(~drop)
        renumber = np.full(self.count, -1, dtype=np.int64)
        renumber[keep_rows] = np.arange(len(keep_rows))
        hits = renumber[self.hit_row] >= 0
        n = len(keep_rows)
        share = None if self.share is None else np.concatenate([self.share[keep_rows], other.share])
        alias = None
        for mine in (None if self.alias is None else tuple(renumber[x] for x in self.alias),
                     None if other.alias is None else tuple(x + n for x in other.alias)):
            if mine is not None:
                both = (mine[0] >= 0) & (mine[1] >= 0)  # a row whose rep is replaced gathers its own hits (none)
                mine = (mine[0][both], mine[1][both])
                alias = mine if alias is None else (np.concatenate([alias[0], mine[0]]), np.concatenate([alias[1], mine[1]]))
        return NearField(
            np.concatenate([self.rows[keep_rows], other.rows]), np.concatenate([self.open_basis[keep_rows], other.open_basis]),
            np.concatenate([renumber[self.hit_row[hits]], other.hit_row + n]), np.concatenate([self.hit_corner[hits], other.hit_corner]),
            np.concatenate([self.hit_weight[hits], other.hit_weight]), self.rays, self.reach,
            self.pairs, self.crowded, self.skipped, self.seconds + other.seconds, share,
            self.hidden, alias, self.crowded_objects, self.emitters, self.whole,
        )

    @classmethod
    def empty(cls, rays, reason="", seconds=0.0):
        z = np.zeros(0, dtype=np.int64)
        return cls(z, np.zeros((0, 9)), z, np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3)), rays, skipped=reason, seconds=seconds)

    @property
    def count(self):
        return len(self.rows)

    def _matrix(self):
        """The hits as a sparse matrix, rows x points: ``(row (e,), corner (e,), local corner
        (e,), weight (e,))``, a (row, corner) pair once, its weights summed; made once."""
        cached = self.__dict__.get("_csr")
        if cached is None:
            span = int(self.hit_corner.max(initial=0)) + 1
            key = np.repeat(self.hit_row, 3) * span + self.hit_corner.ravel()
            uniq, inverse = np.unique(key, return_inverse=True)
            weight = np.bincount(inverse.ravel(), self.hit_weight.ravel(), minlength=len(uniq))
            row, corner = uniq // span, uniq % span
            cached = (row, corner, np.searchsorted(self.support, corner), weight)
            self.__dict__["_csr"] = cached
        return cached

    def _gather(self, radiance, local):
        """Each row's light from its hits: ``(m, c)`` for radiance ``(points or support, c)``."""
        row, corner, corner_local, weight = self._matrix()
        by_channel = np.asarray(radiance, dtype=np.float64).T  # one bincount a channel: 3x a reduceat of (e, c)
        at = corner_local if local else corner
        summed = np.stack([np.bincount(row, weight * np.ascontiguousarray(x)[at], minlength=self.count) for x in by_channel], axis=1)
        if self.alias is not None:
            summed[self.alias[0]] = summed[self.alias[1]]
        return summed

    def gather(self, radiance):
        """``(m, 3)``: each row's light from its hits, for point radiance ``(s, 3)``."""
        return self._gather(radiance, local=False)

    def correct(self, light, probe_part, radiance):
        """``light (s, 3)``, the probes' light, with the rows' near field (:meth:`delta`, from
        what the surfaces send, ``radiance (s, 3)``), clamped at zero: a new float64 array."""
        out = np.array(light, dtype=np.float64, copy=True)
        if self.count:
            sup = self.support
            out[sup] = np.maximum(out[sup] + self.delta(out[sup], probe_part, np.asarray(radiance)[sup]), 0.0)
        return out

    @property
    def support(self):
        """``(u,)`` the points the near field reads or writes (its rows and the hits'
        corners), sorted; made once."""
        cached = self.__dict__.get("_support")
        if cached is None:
            cached = np.unique(np.concatenate([self.rows, self.hit_corner.ravel()]))
            self.__dict__["_support"] = cached
        return cached

    def _support_rows(self):
        """The rows' places on :attr:`support`."""
        return np.searchsorted(self.support, self.rows)

    def delta(self, base, probe_part, radiance):
        """What the near field adds to light ``base (u, c)`` on :attr:`support` (the probes'
        light there): less ``probe_part (m, c)`` (the probes' light in the hit directions:
        ``Transport.interpolate_rows`` of ``open_basis``), plus the hits' light from
        ``radiance (u, c)`` there (what the surfaces send). ``(u, c)``, zero off the rows;
        linear, unclamped (relighting sums it over sources, ``c``: 3 channels per source,
        side by side)."""
        out = np.zeros(np.shape(base))
        if self.count:
            out[self._support_rows()] = self._gather(radiance, local=True) - probe_part
        return out

    def settle(self, base, probe_part, albedo, before, clamp=True):
        """The near field of a sum of bounces on :attr:`support` (all ``(u, c)``): ``base``,
        the probes' light of bounces N+1, N+2, ... (``probe_part`` as in :meth:`delta`), each
        gathering from the one before, ``L' = base - probe_part + G albedo (before + L')``
        with ``before`` bounce N's light; clamped at zero on the rows where ``clamp``. What
        it adds to ``base``, ``(u, c)``. Jacobi steps until settled (``G albedo`` takes at
        most the albedo of the light it gathers: the steps shrink like it;
        :func:`~cubegi_engine.convergence.fixed_point`)."""
        light = np.array(base, dtype=np.float64, copy=True)
        if not self.count:
            return np.zeros_like(light)
        rows = self._support_rows()
        start = light[rows] - probe_part
        albedo = np.asarray(albedo, dtype=np.float64)
        damp = self._damping(albedo)

        def step(rows_light):
            light[rows] = rows_light
            new = start + damp * self._gather(albedo * (before + light), local=True)
            return np.maximum(new, 0.0) if clamp else new

        light[rows], _ = convergence.fixed_point(step, light[rows], tol=NEAR_SUM_TOLERANCE, gain=MAX_LOOP_GAIN)
        return light - base

    def _damping(self, albedo):
        """``(m, 1)``: what each row's gather is scaled by in :meth:`settle` so that it keeps
        at most MAX_LOOP_GAIN of the light it gathers from ``albedo (u, c)`` (on the support).
        A point whose rays all met white surfaces (a pocket under a white saucer's rim, every
        ray meeting the saucer) would otherwise return all of it: a closed loop, summed without
        end, makes any light that reaches it (a shadow map's leak) as bright as the room."""
        gain = self._gather(np.max(albedo, axis=1, keepdims=True), local=True)[:, 0]
        return np.minimum(1.0, MAX_LOOP_GAIN / np.maximum(gain, 1e-300))[:, None]

    def correct_sum(self, light, probe_part, albedo, before):
        """:meth:`settle` over every point ``(s, 3)``, clamped: ``light`` with its near field
        summed to the end (a new float64 array)."""
        out = np.array(light, dtype=np.float64, copy=True)
        if self.count:
            sup = self.support
            out[sup] += self.settle(out[sup], probe_part, np.asarray(albedo)[sup], np.asarray(before)[sup])
        return out


def build(points, normals, reach, triangles, *, rays=NEAR_RAYS, max_pairs=MAX_PAIRS, hidden=None, lit_if_open=None, which=None,
          hidden_as_given=False, sheets=None, owner=None, keep_index=True, caster=None, emitting=None, clustered=True):
    """The near field of ``points``/``normals`` ``(s, 3)`` among ``triangles (t, 3)``
    (indices into points), rays reaching ``reach`` (one length, or ``(s,)``). ``hidden``:
    ``(s,)`` bool, points covered by another object (their light is no sample of the
    surface around them; a hit takes its triangle's other corners where it can).
    ``lit_if_open``: ``(s,)`` bool, covered points that the probes light after all where
    their near field does not close them in (see ``Transport``): hidden only where closed in.
    ``which``: ``(s,)`` bool, the points that cast rays (all by default). ``hidden_as_given``:
    ``hidden`` is already the hidden set (a near field's :attr:`NearField.hidden`), not the
    covered points to decide it from. ``sheets``: the scene's two-sided objects
    (:class:`~cubegi_engine.scene.Sheets`): a ray meets a sheet's twin's front where it meets
    its back, so back faces of sheets are not hit, and a ray from a sheet never meets the
    sheet's own far side (a slightly bent wall's twin lies in front of its points); a sheet's
    back side, and a covered point whose rays meet one, are never hidden; nor, across a gap,
    are ``emitting (s,)`` points and those whose rays meet one (:func:`~.nearhits.hidden_points`). ``owner``: each
    point's object (see :func:`_candidate_pairs`); ``keep_index``: see :func:`~.spatial.voxel_index`.
    ``caster``: where given, a callable giving ``(RayCaster, its triangles' indices among
    triangles)``, the host's ray caster over the scene (the GPU module's, or Blender's BVH
    tree): every ray goes through it, and (unless not ``clustered``) the crowded
    points of the smallest objects are not left out but share the rays of one point per
    cluster, cast through it (:func:`~.nearrays.clusters`).

    It is :func:`trace` (the rays, which need only the geometry) then :func:`finish` (what
    the hits take, which needs ``hidden``): a bake traces while it tests which probes see
    each point."""
    traced = trace(points, normals, reach, triangles, rays=rays, max_pairs=max_pairs, which=which, sheets=sheets, owner=owner,
                   keep_index=keep_index, caster=caster, clustered=clustered)
    return finish(traced, hidden=hidden, lit_if_open=lit_if_open, hidden_as_given=hidden_as_given, emitting=emitting)


@dataclass
class Traced:
    """The near field's rays and hits, before what each hit takes is decided (:func:`trace`;
    :func:`finish` makes the :class:`NearField`)."""

    index: object  # the voxel index of the triangles (its tests ask it again)
    points: np.ndarray
    normals: np.ndarray
    tri: np.ndarray
    sheets: object
    rays: int
    reach: np.ndarray
    longest: float  # the longest finite reach
    pairs: int
    crowded: np.ndarray
    crowded_objects: tuple
    members: np.ndarray
    member_of: np.ndarray
    by_caster: np.ndarray
    cast: np.ndarray
    traced: int
    hits: object
    rch: np.ndarray
    turn: np.ndarray
    openness: np.ndarray
    gap: tuple | None  # (ask (a,), ratio (a, 3)): the hits in a gap and their corners' scales (gap_ratios), or None
    caster: object  # as given to trace (see build)
    seconds: float


def trace(points, normals, reach, triangles, *, rays=NEAR_RAYS, max_pairs=MAX_PAIRS, which=None, sheets=None, owner=None,
          keep_index=True, caster=None, clustered=True):
    """The rays of :func:`build` and their hits (arguments as there): a :class:`Traced`, or a
    NearField where there is none (nothing asked, or the scene over the pairs' budget)."""
    t0 = time.perf_counter()
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    s = len(points)
    reach = np.broadcast_to(np.asarray(reach, dtype=np.float64), (s,)).copy()
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    asked = np.arange(s) if which is None else np.flatnonzero(which)
    # A point at NaN or Inf, or without a normal (a face with such a corner), casts nothing.
    asked = asked[np.isfinite(points[asked]).all(axis=1) & (np.linalg.norm(normals[asked], axis=1) > 0.5) & np.isfinite(reach[asked])]
    if not len(asked) or not len(tri) or reach[asked].max() <= 0:
        return NearField.empty(rays, seconds=time.perf_counter() - t0)
    index = voxel_index(points, tri, float(reach[asked].max()), sheets, keep_index)
    found = _candidate_pairs(index, points, normals, reach, asked, sheets, max_pairs,
                             None if owner is None else np.asarray(owner, dtype=np.int64))
    if isinstance(found, str):
        return NearField.empty(rays, found, time.perf_counter() - t0)
    pair_p, pair_t, crowded = found
    sharing = caster if clustered else None
    small = _small_objects(points, owner, reach, asked) if sharing is not None and SMALL_OBJECT > 0 else np.zeros(s, dtype=bool)
    by_caster, members, member_of, caster_reach = clusters(crowded | small, points, normals, owner, reach, CASTER_RAYS, sharing)
    crowded[members] = False
    if small.any():  # the small objects' points the caster takes cast no rays of their own through the index
        keep = np.ones(s, dtype=bool)
        keep[members] = False
        pair_p, pair_t = pair_p[keep[pair_p]], pair_t[keep[pair_p]]
    crowded_objects = () if owner is None else tuple(int(k) for k in np.unique(np.asarray(owner)[crowded]))
    cast, traced, hits, rch, turn = cast_points(index, points, normals, reach, pair_p, pair_t, by_caster, caster_reach, caster, tri, sheets, rays)
    openness = np.ones(s)
    openness[cast] = hits.openness
    openness[members] = openness[by_caster[member_of]]
    # How much light a hit in a gap gets through it needs only the geometry: asked here (of
    # the own points' hits: see finish).
    gap = gap_ratios(index, hits.corners, openness, hits.at, hits.triangle, hits.front & (hits.point < traced), rch[hits.point],
                     turn[hits.point], OPENNESS_RAYS, host_rays(caster)) if OPENNESS_RAYS else None
    longest = float(np.max(reach, where=np.isfinite(reach), initial=0.0))  # (a point's at NaN is none)
    return Traced(index, points, normals, tri, sheets, rays, reach, longest, len(pair_p), crowded, crowded_objects, members, member_of,
                  by_caster, cast, traced, hits, rch, turn, openness, gap, caster, time.perf_counter() - t0)


def started(scene, grid, caster):
    """:func:`trace` of ``scene``'s near field on ``grid`` (its points' reach: NEAR_REACH of
    their cells), started in a thread (:func:`~.working.start`): its rays need only the
    geometry, so they are traced while the probes are drawn and their visibility is tested;
    what their hits take is decided after (:func:`finish`), from the points the probes leave
    covered. ``caster``: see :func:`build`."""
    sheets = scene.sheets()  # made here, once, before that thread asks for it
    return working.start(trace, scene.points, scene.normals, NEAR_REACH * grid.point_cell_edge(scene.points),
                         scene.triangles, owner=scene.point_object, sheets=sheets, keep_index=False, caster=caster)


def _small_objects(points, owner, reach, asked):
    """``(s,)`` bool: the ``asked`` points of the objects whose size is under SMALL_OBJECT
    probe cells (``reach``: a share NEAR_REACH of the points' cells)."""
    out = np.zeros(len(points), dtype=bool)
    if owner is None or not len(asked):
        return out
    obj = np.asarray(owner, dtype=np.int64)[asked]
    order = np.argsort(obj, kind="stable")
    starts = np.flatnonzero(np.r_[True, obj[order][1:] != obj[order][:-1]])
    p = points[asked][order]
    size = np.linalg.norm(np.maximum.reduceat(p, starts) - np.minimum.reduceat(p, starts), axis=1)
    cell = np.maximum.reduceat(reach[asked][order], starts) / NEAR_REACH
    small = np.zeros(len(asked), dtype=bool)
    small[order] = np.repeat(size < SMALL_OBJECT * cell, np.diff(np.r_[starts, len(order)]))
    out[asked] = small
    return out


def finish(traced, *, hidden=None, lit_if_open=None, hidden_as_given=False, emitting=None, lying=None):
    """The :class:`NearField` of ``traced`` (a :class:`Traced`; a NearField is handed back as
    it is), with the hidden points decided (arguments as in :func:`build`; ``lying``: as in
    :func:`~.nearhits.hidden_points`)."""
    if isinstance(traced, NearField):
        return traced
    t0 = time.perf_counter()
    hits, cast, members, points, tri, index = traced.hits, traced.cast, traced.members, traced.points, traced.tri, traced.index
    point = hits.point  # local
    local_rows, hit_row = np.unique(point, return_inverse=True)
    rows = cast[local_rows]
    uv = np.clip(hits.uv, 0.0, 1.0)
    weight = np.stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], axis=1)
    corners = hits.corners
    # The clusters' hits (in dense geometry) are not asked whether they lie covered: their
    # hidden corners' weight goes to the others (and trace asked no gap of them), as when
    # those tests went through the voxel index, where they took minutes.
    own = point < traced.traced
    emitters = None
    if hidden is not None:
        hidden = np.asarray(hidden, dtype=bool).copy()
        if not hidden_as_given:
            hidden, emitters = hidden_points(hidden, traced.openness, lit_if_open, traced.sheets, cast[point], corners, points, traced.normals,
                                             tri, emitting, lying)
        hidden[members] = False  # lit by their own rays: a surface's light
        weight = uncover(index, weight, corners, hidden, hits.triangle, traced.rch[point], own, host_rays(traced.caster))
    if traced.gap is not None:  # a hit in a gap takes what the gap lets in (worked out with the rays)
        ask, ratio = traced.gap
        weight[ask] *= ratio  # (weight is this call's own: stacked above, or uncover's copy)
    weight *= (hits.front * hits.weight)[:, None]  # a back face occludes and sends nothing
    open_basis, share, hit_row = hits.open_basis, hits.share, hit_row.astype(np.int64).ravel()
    alias = None
    if len(members):
        rows, open_basis, share, alias = shared_rows(rows, open_basis, share, members, traced.by_caster[traced.member_of],
                                                     traced.normals)
    return NearField(rows.astype(np.int64), open_basis, hit_row, corners, weight,
                     traced.rays, traced.longest, traced.pairs, int(traced.crowded.sum()), "",
                     traced.seconds + time.perf_counter() - t0, share,
                     None if hidden is None else np.flatnonzero(hidden), alias, traced.crowded_objects, emitters,
                     _whole(members, rows))


def _whole(members, rows):
    """:attr:`NearField.whole`: the caster's ``members`` that gather (have a row; one whose
    cluster met nothing keeps the probes' light, balanced as every point's is), or None."""
    whole = members[np.isin(members, rows)]
    return whole if len(whole) else None


def _candidate_pairs(index, points, normals, reach, asked, sheets, max_pairs, owner=None):
    """``(pair_p, pair_t, crowded (s,) bool)``: the (point, triangle) pairs the points
    ``asked`` test their rays against, without the crowded points' (more than
    MAX_CANDIDATES pairs, or too many triangles around); or, where the pairs are more than
    ``max_pairs`` (estimated first from a sample in a large scene), the reason in words.
    In a large scene, an object (``owner (s,)``: each point's) whose every sampled point is
    crowded is crowded whole, without asking its other points (a chair of 13K triangles,
    a subdivided room: most of a dense scene's time went to finding that out point by point)."""
    crowded = np.zeros(len(points), dtype=bool)
    if len(asked) > 16 * SAMPLE:  # estimate the pairs first: a dense scene's would take too long
        sample = asked[np.linspace(0, len(asked) - 1, SAMPLE).astype(np.int64)]
        pp, _, some = index.candidates(points[sample], normals[sample], reach[sample])
        estimate = int(len(pp) * len(asked) / SAMPLE)
        if estimate > max_pairs:
            return f"about {estimate:,} candidate pairs of points and triangles, more than {max_pairs:,}"
        if owner is not None:
            some |= np.bincount(pp, minlength=len(sample)) > MAX_CANDIDATES
            objects = int(owner.max()) + 1
            sampled = np.bincount(owner[sample], minlength=objects)
            dense = (sampled >= CROWDED_SAMPLE) & (np.bincount(owner[sample], some, minlength=objects) == sampled)
            if dense.any():
                skip = dense[owner[asked]]
                crowded[asked[skip]] = True
                asked = asked[~skip]
    pair_p, pair_t, some = index.candidates(points[asked], normals[asked], reach[asked])
    pair_p = asked[pair_p]
    if sheets is not None:
        near = ~sheets.other_side(pair_p, pair_t)
        pair_p, pair_t = pair_p[near], pair_t[near]
    crowded[asked] = some
    crowded |= np.bincount(pair_p, minlength=len(points)) > MAX_CANDIDATES
    if crowded.any():
        keep = ~crowded[pair_p]
        pair_p, pair_t = pair_p[keep], pair_t[keep]
    if len(pair_p) > max_pairs:
        return f"{len(pair_p):,} candidate pairs of points and triangles, more than {max_pairs:,}"
    return pair_p, pair_t, crowded
