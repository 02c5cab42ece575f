"""Light transport on a probe grid: the paper's bounce loop as array arithmetic.

Pure numpy; must not import bpy.

For fixed geometry every step from the light leaving the surfaces to the light arriving at
them is linear. So each probe's cube map is captured once, recording for every texel what it
sees (a triangle and the barycentric weights of the point hit, a back face, or sky), not a
colour. A bounce is then:

1. gather: texel radiance = barycentric mix of the outgoing radiance of the triangle's
   corner points (sky texels take the sky's radiance; back faces give none);
2. project: SH coefficients per probe = texel radiance weighted by basis x solid angle;
3. interpolate: diffuse light at each point = the 8 surrounding probes' coefficients,
   weighted by (visibility-aware) trilinear weights, evaluated for the point's normal.

Drawing the lit scene again every bounce (the paper's way) gives the same numbers up to the
texel-centre sampling of the radiance; :func:`~cubegi_engine.capture.reference_coefficients`
does that with a renderer and is kept as a check in the tests.

Light is carried as the diffuse value of a white Lambertian surface, ``E / pi``; the outgoing
radiance of a surface of albedo rho receiving diffuse light l is ``rho * l`` (+ emission).
"""

import time

import numpy as np

from . import cubemap, nearfield, sh, spatial, working
from .gather import same_side
from .grid import points_by_cell
from .visibility import CastCover, Cover, PointProbes, Probes, probes_in_front, seen_corners_only, seen_from_behind, visibility_weights

# A covered point in the open (see Transport._light_under) casts rays this many cells long,
# and is lit through the gap where at least this share of them meets what covers it.
UNDER_REACH, UNDER_SHARE = 1.0, 0.5

__all__ = ["Transport", "COEFFS_PER_POINT"]

# A point interpolates 8 probes (the corners of its cell) x 9 SH coefficients; one whose
# weights are all under NO_WEIGHT gets no probe light.
COEFFS_PER_POINT, NO_WEIGHT = 8 * 9, 1e-6
# A probe whose cube map sees back faces over more than this share of the sphere is taken
# to sit inside geometry and is left out of the interpolation (as DDGI does).
INSIDE_BACKFACE_SHARE = 0.25


# Points per chunk of :meth:`Transport.interpolate`; texels per chunk of texel_radiance.
INTERPOLATE_CHUNK = 32768
TEXEL_CHUNK = 100_000
# A bake gathers through a dense (9p, s) matrix where it has at most this many numbers
# (32 MB): a small scene's bounce is then one matrix product, not a pass over every texel.
DENSE_GATHER_ELEMENTS = 8_000_000


class Transport:
    """The linear operators of one scene, grid and capture: gather, project, interpolate.

    After construction every bounce is a few gathers and matrix products (float32).
    """

    def __init__(self, scene, grid, capture, visibility=True, proxy=None, near_field=True, caster=None, tracing=None, make=None):
        """``proxy``: the :class:`~cubegi_engine.proxy.CaptureProxy` the capture drew (its
        triangles are what the texels see), or None for the scene's own triangles.
        ``near_field``: gather each point's short-range surroundings by rays
        (:mod:`cubegi_engine.nearfield`); ``caster``: the host's ray caster for the near field's
        crowded points (:func:`~cubegi_engine.gather.near_caster`), or None. ``tracing``: the
        near field's rays already started for ``scene`` and ``grid`` (:func:`~.nearfield.started`),
        or None: started here. ``make``: the host's caster maker (CastCover.of_proxy)."""
        self.proxy, self._make = proxy, make
        if near_field and tracing is None:
            tracing = nearfield.started(scene, grid, caster)  # while the visibility is tested
        try:
            self._build(scene, grid, capture, visibility, proxy, tracing, caster)
        except BaseException:
            if tracing is not None:  # nothing of the failed tables outlives them
                working.abandon(tracing)
            raise

    def _build(self, scene, grid, capture, visibility, proxy, tracing, caster):
        """The tables (see the constructor); ``tracing``: the near field's rays, started."""
        n = capture.size
        triangles = scene.triangles if proxy is None else proxy.triangles
        p = grid.count
        self.probe_count = p
        dirs = cubemap.texel_directions(n).reshape(-1, 3)
        solid = np.tile(cubemap.texel_solid_angles(n).ravel(), 6)
        self.sh_weights = (sh.basis(dirs) * solid[:, None]).astype(np.float32)  # (6n^2, 9)

        tid = capture.tid.reshape(p, -1)
        back = capture.backface.reshape(p, -1)
        hit = (tid >= 0) & ~back
        self.corners = triangles[np.maximum(tid, 0)].astype(np.int32)  # (p, 6n^2, 3): points or clusters
        self.bary = (capture.bary.reshape(p, -1, 3) * hit[..., None]).astype(np.float32)
        sky = (tid < 0).astype(np.float32)
        self.sky_projection = sky @ self.sh_weights  # (p, 9): SH of a unit sky seen by each probe
        # (p, 9, 3): the same for the sky's pattern (an environment image), or None (uniform).
        self.sky_projection_map = None
        self.sky_map = getattr(scene, "sky_map", None)  # kept: a capture is valid for this pattern only
        if self.sky_map is not None:
            self.sky_projection_map = self._sky_pattern_projection(dirs, sky)
        back_share = (back * solid[None, :]).sum(axis=1) / (4.0 * np.pi)
        self.probe_valid = back_share <= INSIDE_BACKFACE_SHARE
        self.seen_from_behind = self.triangle_object = None
        if scene.point_object is not None:
            self.triangle_object = scene.triangle_object() if proxy is None else proxy.triangle_object
            count = int(scene.point_object.max()) + 1
            self.seen_from_behind = seen_from_behind(self.triangle_object, count, tid, back, solid, self.probe_valid)

        positions = grid.positions()
        whole = grid.whole()  # (a probe subset's weights are its whole grid's, renumbered)
        index, weight = whole.trilinear(scene.points)
        # (s,) points with no probe of their grid at all (its probes around them all lie in a
        # finer grid's box): a grid-placement problem the bake notes. (Points covered by
        # another object, dark by the visibility test below, are not counted; nor are points
        # whose probes were all left out for lying inside geometry: a floor under a block.)
        self.no_probe = ~np.any(weight > 0, axis=1)
        index, weight = (index, weight) if whole is grid else grid.of_whole(index, weight)
        trilinear_weight = weight
        spare = None  # (rows, weights of the probes behind them), for points the near field leaves dark
        if visibility:
            weight, spare = self._seen_weights(scene, grid, capture, triangles, proxy, positions, index, weight, caster)
        elif not self.probe_valid.all():
            w = weight * self.probe_valid[index]
            total = w.sum(axis=1, keepdims=True)
            weight = np.where(total > 1e-9, w / np.maximum(total, 1e-30), weight)
        self.index = index
        # Per point: trilinear weights and the diffuse SH basis of its normal, kept after the
        # near field (whose voxel index is the tables' high-water mark of memory).
        basis = sh.diffuse_basis(scene.normals)
        self._cells = points_by_cell(index)  # the points grouped by their 8 probes (or None): how the weights are kept
        self._dense = None  # the gather-project matrix, once made (gather_project_matrix)
        # (s,) points another object covers (no probe sees them: a floor point under a wall
        # standing on it, the underside of a block on the ground): no probe light, no sky.
        self.covered = _no_weight(weight, basis) & ~self.no_probe
        self._resting, spare = self._lying(scene, spare)  # which of them lie on another surface (see resting)
        # The near field (a final gather of each point's short-range surroundings), or None.
        self.near = None
        self.near_waited = 0.0  # what the tables spent on the near field past what ran beside them (seconds)
        self.gathered = None  # the points gathered by rays over their whole view (take_gathered)
        self.own_near = None  # the near field of its own (what a report says of it), without them
        if tracing is not None:
            lit_if_open = None if spare is None else np.isin(np.arange(len(scene.points)), spare[0])
            t = time.perf_counter()
            self.near = nearfield.finish(working.result(tracing), hidden=self.covered, lit_if_open=lit_if_open,
                                         emitting=np.any(scene.emission > 0, axis=1), lying=self._resting)
            self.near_waited = time.perf_counter() - t
        # Each point's 8 probes' weights and its normal's diffuse basis, kept apart (their 72
        # products are a point's light per coefficient: 4 times the memory, 0.7 GB at 2.5M points).
        self._weight = np.empty((len(index), 8), dtype=np.float32)
        self._basis = np.empty((len(index), 9), dtype=np.float32)
        self._put_weights(np.arange(len(index)), weight, basis)
        if spare is not None:
            self._light_from_behind(spare, basis, len(scene.points))
        if self.near is not None and visibility and self.covered.any():
            self._light_under(scene, grid, index, trilinear_weight, basis, positions, caster)
        self.own_near = self.near
        if proxy is None:  # (a proxy's clusters have no covered flag of their own)
            self.bary = seen_corners_only(self.bary, self.corners, self.covered)

    @property
    def point_weights(self) -> np.ndarray:
        """``(s, 72)`` float32: each point's 8 probes' weights x its normal's diffuse basis, in
        the points' order (made when asked: the dense operators of :mod:`.relight`)."""
        at = slice(None) if self._cells is None else self._cells.rank
        return _outer_float32(self._weight[at], self._basis[at])

    def _put_weights(self, rows, weight, basis):
        """The weights of the points ``rows (m,)``: their 8 probes' ``weight (m, 8)`` and their
        diffuse ``basis (m, 9)``."""
        at = rows if self._cells is None else self._cells.rank[rows]
        self._weight[at], self._basis[at] = weight, basis

    def _weightless(self, rows=None) -> np.ndarray:
        """``(m,)`` bool: which of the points ``rows`` (all: None) no probe light reaches."""
        at = slice(None) if rows is None else (rows if self._cells is None else self._cells.rank[rows])
        out = _no_weight(self._weight[at], self._basis[at])
        return out if rows is not None or self._cells is None else out[self._cells.rank]

    def take_gathered(self, gathered):
        """Light the points of ``gathered`` (a :class:`~cubegi_engine.gather.Gathered`) by their
        own rays from now on: their rows join the near field in place of any they had (every
        probe light of theirs taken away). Once per Gathered."""
        if gathered is None or gathered is self.gathered or not gathered.count:
            return
        near = same_side(gathered.near, self.covered)
        self.near = near if self.near is None or not self.near.count else self.near.replaced_rows(near)
        self.gathered = gathered

    def emitters_changed(self, scene) -> np.ndarray:
        """The points whose emitting these tables hold (which points emit across a gap
        decides the near field's hidden ones) that ``scene`` changed (none: they hold)."""
        return np.zeros(0, dtype=np.int64) if self.own_near is None else self.own_near.emitters_changed(np.any(scene.emission > 0, axis=1))

    def resting(self) -> np.ndarray:
        """``(s,)`` bool: the covered points that lie on another surface facing them
        (:func:`~cubegi_engine.spatial.resting`: a wall's points inside a partition's end
        standing against it, a floor's under a wall), but the gathered ones (their corners'
        own rays decide). No light reaches them: not the probes' from behind, not the sky's,
        nor a lamp's through a partition thinner than its shadow maps' bias."""
        out = self._resting.copy()
        if self.gathered is not None:
            out[self.gathered.rows] = False
        return out

    @property
    def exact(self) -> np.ndarray:
        """``(s,)`` bool: the points whose light the energy balance neither counts nor scales:
        those no probe lights (:attr:`covered`: their light is the near field's alone), the
        gathered points (their own rays' light, whole) and those the near field gathers
        through the host's caster (:attr:`NearField.whole`: lit by what no probe sees)."""
        out = self.covered.copy()
        if self.gathered is not None:
            out[self.gathered.rows] = True
        if self.near is not None and self.near.whole is not None:
            out[self.near.whole] = True
        return out

    def _sky_pattern_projection(self, dirs, sky):
        """``(p, 9, 3)``: the SH of the scene's sky pattern (an environment image) as each
        probe sees it through the texels ``sky (p, texels)`` that see the sky."""
        pattern = cubemap.sample_image(np.asarray(self.sky_map, dtype=np.float64), cubemap.equirect_uv(dirs))
        weights = (self.sh_weights[:, :, None] * pattern[:, None, :].astype(np.float32)).reshape(len(dirs), 27)
        return (sky @ weights).reshape(len(sky), 9, 3)

    def _seen_weights(self, scene, grid, capture, triangles, proxy, positions, index, weight, caster=None):
        """The probe weights ``(s, 8)`` of each point's probes that see it (the visibility
        test, :func:`~cubegi_engine.visibility.visibility_weights`), and ``spare``: the points no
        probe in front of them sees but some behind their plane do, with those probes'
        weights (``(rows, weights)``; None where there are none)."""
        p, n = self.probe_count, capture.size
        cover = None
        if scene.point_object is not None:
            cover = Cover.of(capture.tid.reshape(p, 6, n, n), triangles, scene.points if proxy is None else proxy.points,
                             self.triangle_object, scene.point_object, CastCover.of_capture(scene, proxy, caster, self._make))
        probes = Probes(positions, capture.dist.reshape(p, 6, n, n), self.probe_valid)
        lit_by = visibility_weights(grid, probes, PointProbes(scene.points, scene.normals, index, weight), cover, both=True,
                                    sheet=None if scene.sheets() is None else scene.sheets().point_sheet)
        seen, behind = lit_by.weights, lit_by.behind
        alone = np.flatnonzero(~seen.any(axis=1) & behind.any(axis=1))
        return seen, ((alone, behind[alone]) if len(alone) else None)

    def _lying(self, scene, spare):
        """``(lying, spare)``: which covered points lie on another surface facing them, asked
        once a bake (:meth:`resting`, the near field's hidden points and the sky read it), and
        ``spare`` (see :meth:`_seen_weights`) without them: such a point takes no light from
        the probes behind it (a partition's top against the ceiling: the probes under a
        ceiling of large quads see it in the ceiling's plane, and lit it as the ceiling)."""
        lying = np.zeros(len(self.covered), dtype=bool)
        which = np.flatnonzero(self.covered)
        lying[which] = spatial.resting(scene.points, scene.normals, scene.triangles, scene.scale, which, scene.sheets())
        if spare is not None:
            keep = ~lying[spare[0]]
            spare = (spare[0][keep], spare[1][keep]) if keep.any() else None
        return lying, spare

    def _light_from_behind(self, spare, basis, count):
        """A point only probes behind its plane see (a block's underside below the lowest
        probes) is lit by its near field where that encloses at least half its view (the
        probes' light in the few open directions comes out too bright); elsewhere (a sofa's
        underside well above the floor, no near field) by them. Cornell box at 12 cells: 7.1%
        (at least half), 7.9% (three quarters), 9.2% (always by them)."""
        rows, w = spare
        if self.near is not None:
            keep = ~self.near.enclosed(count)[rows]
            rows, w = rows[keep], w[keep]
        self._put_weights(rows, w, basis[rows])
        self.covered[rows] = self._weightless(rows)

    def _light_under(self, scene, grid, index, weight, basis, positions, caster):
        """Covered points in the open (the floor under a sofa: every probe's view of it is
        cut by the sofa, but its near field does not close it in and it rests on nothing)
        take the valid probes in front of them, and rays of UNDER_REACH cells: the rays
        find the sofa's underside, the probes' light is kept for the few directions that
        leave under its edge."""
        if self.near.hidden is None:  # no near field (left out): nothing says what rests on what
            return
        s = len(scene.points)
        open_ = self.covered & ~self.near.enclosed(s)
        open_[self.near.hidden] = False  # closed in, or resting on a surface (the near field asked)
        open_ = np.flatnonzero(open_)
        if not len(open_):
            return
        w = probes_in_front(positions, self.probe_valid, scene.points[open_], scene.normals[open_], index[open_], weight[open_])
        lit = w.any(axis=1)
        open_, w = open_[lit], w[lit]
        if not len(open_):
            return
        reach = UNDER_REACH * grid.point_cell_edge(scene.points)
        hidden = np.zeros(s, dtype=bool)
        hidden[self.near.hidden] = True

        def rays(rows):
            which = np.zeros(s, dtype=bool)
            which[rows] = True
            return nearfield.build(scene.points, scene.normals, reach, scene.triangles, hidden=hidden, which=which,
                                   hidden_as_given=True, sheets=scene.sheets(), caster=caster, clustered=False)

        far = rays(open_)
        under = np.isin(open_, far.rows[far.share >= UNDER_SHARE]) if far.count else np.zeros(len(open_), dtype=bool)
        if not under.any():
            return
        if not under.all():
            far = rays(open_[under])
        open_, w = open_[under], w[under]
        self.near = self.near.replaced_rows(far)
        self._put_weights(open_, w, basis[open_])
        self.covered[open_] = False

    def gather_project_matrix(self):
        """``K (9p, s)`` float32: the probes' SH coefficients from per-point radiance (one
        channel), as a dense matrix; made once (a simplified capture gathers from clusters:
        the matrix over them, expanded to the points)."""
        if self._dense is None:
            if self.proxy is not None:
                self._dense = self.proxy.expand_columns(_gather_matrix(self, self.proxy.count))
            else:
                self._dense = _gather_matrix(self, len(self.index))
        return self._dense

    def gather_project(self, radiance):
        """SH radiance coefficients ``(p, 9, 3)`` the probes see of point radiance ``(s, 3)``:
        :meth:`texel_radiance` then :meth:`project`, or, where the scene is small enough that
        the dense matrix (9p x s numbers, at most DENSE_GATHER_ELEMENTS) is cheaper than the
        texels, one matrix product with it (built on the first call)."""
        if 9 * self.probe_count * len(self.index) > DENSE_GATHER_ELEMENTS:
            return self.project(self.texel_radiance(radiance))
        out = self.gather_project_matrix() @ np.asarray(radiance, dtype=np.float32)
        return out.reshape(self.probe_count, 9, -1)

    def seen_light(self, coeffs):
        """Diffuse light ``(s, 3)`` at the points of what the probes see directly, SH radiance
        ``(p, 9, 3)`` (the sky): interpolated, less its radiance in the directions the near
        field finds blocked close by (its rays that hit; the sky there is behind a wall).
        Linear in ``coeffs`` but for the clamps of :meth:`interpolate`."""
        light = self.interpolate(coeffs).astype(np.float64)
        if self.near is None or not self.near.count:
            return light
        light[self.near.rows] = np.maximum(
            light[self.near.rows] - self.interpolate_rows(coeffs, self.near.rows, self.near.open_basis), 0.0)
        return light

    def near_part(self, coeffs, light):
        """What the near field's rows lose of the probes' light ``light (s, 3)`` of ``coeffs``:
        their probe light in the hit directions (:meth:`interpolate_rows` of their open basis),
        and a gathered point's whole probe light as ``light`` has it (its rays replace it,
        deringed and clamped as it is: the same as a linear update's, which subtracts what it
        adds)."""
        near = self.near
        part = self.interpolate_rows(coeffs, near.rows, near.open_basis)
        if self.gathered is not None and self.gathered.count:
            place = np.full(len(self.index), -1, dtype=np.int64)
            place[near.rows] = np.arange(near.count)
            part[place[self.gathered.rows]] = np.asarray(light, dtype=np.float64)[self.gathered.rows]
        return part

    def interpolate_rows(self, coeffs, rows, basis):
        """``(m, 3)``: the probe light of points ``rows (m,)`` from coefficients ``(p, 9, 3)``
        for per-row bases ``(m, 9)`` instead of their normals' diffuse basis (same weights), in
        float32 as :meth:`_cell_light` (at 1.24M vertices 0.6 -> 0.2 s a call of 390K rows)."""
        rows = np.asarray(rows, dtype=np.int64)
        if not len(rows):
            return np.zeros((0, 3))
        flat = np.ascontiguousarray(coeffs, dtype=np.float32).reshape(len(coeffs), -1)  # (p, 27)
        index, weight = self.index[rows], self._weights_of(rows)
        mixed = weight[:, 0, None] * flat[index[:, 0]]  # each row's 8 probes mixed first: no (m, 8, 9, 3) array
        taken = np.empty_like(mixed)
        for j in range(1, index.shape[1]):
            mixed += np.multiply(np.take(flat, index[:, j], axis=0, out=taken), weight[:, j, None], out=taken)
        return np.matmul(np.asarray(basis, dtype=np.float32)[:, None, :], mixed.reshape(len(rows), 9, -1))[:, 0].astype(np.float64)

    def probe_weights(self, rows):
        """``(m, 8)`` float64: the (visibility-aware) weights of the points ``rows``' 8 probes."""
        return self._weights_of(rows).astype(np.float64)

    def _weights_of(self, rows):
        return self._weight[rows if self._cells is None else self._cells.rank[rows]]

    def arrays(self):
        """The tables' arrays (for memory accounting)."""
        extra = [] if self.proxy is None else [self.proxy.points, self.proxy.triangles, self.proxy.cluster, self.proxy.share]
        extra += [] if self.sky_projection_map is None else [self.sky_projection_map]
        extra += [] if self._dense is None else [self._dense]
        extra += [] if self.near is None else [self.near.rows, self.near.open_basis, self.near.hit_row, self.near.hit_corner, self.near.hit_weight]
        return [self.sh_weights, self.corners, self.bary, self.sky_projection, self.probe_valid, self.index, self._weight, self._basis,
                *extra]

    def landing_share(self):
        """Per point, the cosine-weighted share of its view that is surface, not sky:
        ``(s, 3)`` in [0, 1] (the light of a unit sky, from the probes, taken from 1). A point
        no probe lights (a wall's outer face, a floor under a rug) counts 0: no probe sees
        the light it sends either, so the energy balance leaves it out on both sides (its
        light mostly leaves through the sky, or lands where no probe looks)."""
        unit = np.repeat(self.sky_projection[:, :, None], 3, axis=2)  # geometric: a uniform unit sky
        landing = np.clip(1.0 - self.interpolate(unit).astype(np.float64), 0.0, 1.0)
        landing[self._weightless()] = 0.0
        if self.gathered is not None:  # their own rays say it
            landing[self.gathered.rows] = self.gathered.near.share[:, None]
        return landing

    def sky_coefficients(self, sky):
        """SH radiance coefficients ``(p, 9, 3)`` of the sky of mean radiance ``sky (3,)``
        where each probe sees sky (uniform, or the scene's sky pattern times ``sky``)."""
        projection = self.sky_projection[:, :, None] if self.sky_projection_map is None else self.sky_projection_map
        return projection * np.asarray(sky, dtype=np.float32)[None, None, :]

    def linear_gather(self, sent):
        """``coeffs (p, 9, 3) -> (p, 9, 3)``: :meth:`gather_project` of ``sent (s, 3)`` times
        the light :meth:`interpolate` gives without its clamps (the tail solve's step). Where
        the capture drew a simplified scene and the weights are kept cell by cell, the light
        stays in the cells' order and goes to the clusters at once (no scatter to the
        points, no copies: 0.19 -> 0.07 s a step at a million points)."""
        if self.proxy is None or self._cells is None or 9 * self.probe_count * len(self.index) <= DENSE_GATHER_ELEMENTS:
            return lambda coeffs: self.gather_project(sent * self.interpolate(coeffs, clamp=False))
        order = self._cells.order
        in_cells, sent = self.proxy.reordered(order), np.asarray(sent, dtype=np.float32)[order]
        return lambda coeffs: self.project(self.texel_radiance(in_cells.radiance(self._cell_light(coeffs) * sent), gathered=True))

    def texel_radiance(self, radiance, gathered=False):
        """Radiance seen by every texel ``(p, 6n^2, 3)`` from point radiance ``(s, 3)`` (or,
        ``gathered``, the radiance of what the texels see: a proxy's clusters)."""
        r = np.asarray(radiance, dtype=np.float32) if self.proxy is None or gathered else self.proxy.radiance(radiance)
        p = len(self.bary)
        out = np.empty(self.bary.shape, dtype=np.float32)
        step = max(1, TEXEL_CHUNK // max(self.bary.shape[1], 1))  # probes per chunk (in cache; 2x faster)
        for start in range(0, p, step):
            sl = slice(start, start + step)
            out[sl] = np.einsum("ptc,ptcr->ptr", self.bary[sl], np.take(r, self.corners[sl], axis=0))
        return out

    def project(self, texel_radiance, sky=None):
        """SH radiance coefficients ``(p, 9, 3)`` of texel radiance (plus a uniform sky)."""
        c = np.matmul(self.sh_weights.T[None], texel_radiance)
        if sky is not None:
            c = c + self.sky_coefficients(sky)
        return c

    def _cell_light(self, coeffs):
        """``(s, 3)`` float32: the unclamped light of coefficients ``(p, 9, 3)`` at the points
        in the cells' order (:class:`~.grid.PointCells`): each cell's points' weights x its 8
        probes' 27 coefficients, one matrix product, then each point's basis (as
        :meth:`interpolate` mixes points that are not grouped)."""
        flat = np.ascontiguousarray(coeffs, dtype=np.float32).reshape(len(coeffs), -1)  # (p, 27)
        probes = flat[self._cells.probes]  # (cells, 8, 27)
        out = np.empty((len(self._weight), 3), dtype=np.float32)
        for k, (a, b) in enumerate(zip(self._cells.bounds[:-1], self._cells.bounds[1:])):
            mixed = np.matmul(self._weight[a:b], probes[k]).reshape(b - a, 9, 3)
            np.matmul(self._basis[a:b, None, :], mixed, out=out[a:b, None, :])
        return out

    def interpolate(self, coeffs, clamp=True):
        """Diffuse light ``(s, 3)`` at every point from probe coefficients ``(p, 9, 3)``.

        Low-order SH can ring below zero next to a small bright source: probes that ring are
        deringed first (:func:`sh.dering`), and the result is clamped at zero against what
        is left between the checked directions. ``clamp=False`` skips both and keeps the
        map linear (for the tail solve).
        """
        if clamp:
            coeffs, _ = sh.dering(coeffs)
        s = len(self.index)
        out = np.empty((s, 3), dtype=np.float32)
        if self._cells is not None:  # one matrix product per cell, to the points' places
            out[self._cells.order] = self._cell_light(coeffs)
        else:  # in chunks (no (s, 8, 27) array): each point's 8 probes' coefficients mixed by its weights, then its basis
            flat = np.ascontiguousarray(coeffs, dtype=np.float32).reshape(len(coeffs), -1)  # (p, 27)
            for start in range(0, s, INTERPOLATE_CHUNK):
                sl = slice(start, start + INTERPOLATE_CHUNK)
                g = np.take(flat, self.index[sl], axis=0).reshape(-1, 8, 27)
                mixed = np.matmul(self._weight[sl, None, :], g)[:, 0].reshape(-1, 9, 3)
                out[sl] = np.matmul(self._basis[sl, None, :], mixed)[:, 0]
        return np.maximum(out, 0.0) if clamp else out


def _no_weight(weight, basis):
    """``(s,)`` bool: whether no probe light reaches each point of ``weight (s, 8)`` and
    ``basis (s, 9)``, as the transport keeps them (float32; before they are kept, the same
    answer): its largest product of the two under NO_WEIGHT."""
    largest = np.abs(weight).max(axis=1).astype(np.float32) * np.abs(basis).max(axis=1).astype(np.float32)
    return largest < np.float32(NO_WEIGHT)


def _outer_float32(weight, basis):
    """``(s, 8 * 9)`` float32: each point's trilinear weights ``(s, 8)`` times its diffuse SH
    basis ``(s, 9)``, with no float64 array of that size made (1.2 GB at two million points)."""
    out = np.empty((len(weight), 8, 9), dtype=np.float32)
    np.multiply(weight[:, :, None], basis[:, None, :], out=out, casting="same_kind")
    return out.reshape(len(weight), COEFFS_PER_POINT)


def _gather_matrix(transport, s):
    """``(9p, s)`` float32 over ``s`` gathered points (the scene's, or a proxy's clusters)."""
    p = transport.probe_count
    corners = transport.corners.reshape(p, -1, 3).astype(np.int64)  # (p, t, 3)
    bary = transport.bary.reshape(p, -1, 3).astype(np.float64)
    w = transport.sh_weights.astype(np.float64)  # (t, 9)
    flat = (np.arange(p)[:, None, None] * s + corners).ravel()
    out = np.empty((p, 9, s), dtype=np.float32)
    for j in range(9):
        out[:, j, :] = np.bincount(flat, (bary * w[None, :, j, None]).ravel(), minlength=p * s).reshape(p, s)
    return out.reshape(p * 9, s)
