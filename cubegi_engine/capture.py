"""The probe capture: what every probe's cube map sees, and the tables built from it.

Pure numpy; must not import bpy. A :class:`ProbeCapture` is drawn once per geometry and
grid and stays valid across edits of lights, materials and the world (its tables do not
depend on them); :meth:`ProbeCapture.valid_for` says whether it still applies to a scene.
"""

import time
from dataclasses import dataclass, replace

import numpy as np

from . import cubemap, sh
from .cubemap import CubeCapture, capture_cubes, clip_planes
from .gather import near_caster
from .geometry import first_of_twins, twin_triangles
from .grid import Grid
from .nearfield import started
from .rays import hits_from_distances
from .records import Progress, Stage
from .scene import GeometryFingerprint, same_sky_map
from .transport import Transport
from .working import CAPTURE_DRAWS_PER_STEP, in_background, in_batches, run

__all__ = ["ProbeCapture", "RayCubes", "reference_coefficients"]

# The rays a batch of the probes' capture by rays (RayCubes) casts between steps; how far past
# a lone sheet triangle met from behind its ray is cast on (a share of the scene's size), at
# most how many times.
CAPTURE_RAYS_PER_STEP, PAST_LONE, LONE_ROUNDS = 1 << 18, 1e-6, 4


@dataclass
class ProbeCapture:
    """Cube maps of every probe of ``grid`` (``cubes``: texel -> triangle, barycentrics,
    distance, back face) and the transport tables built from them (``transport``), for the
    geometry whose fingerprint is ``fingerprint``."""

    grid: Grid  # a ProbeGrid, GridSet or ProbeSubset
    cube_size: int
    visibility: bool
    fingerprint: GeometryFingerprint
    cubes: CubeCapture
    transport: Transport
    capture_seconds: float = 0.0
    tables_seconds: float = 0.0
    proxy: object = None  # the CaptureProxy drawn instead of the scene's triangles, if any
    key: tuple = ()  # the settings it was taken with that it depends on (BakeSettings.capture_key)
    small_objects: tuple = ()  # objects left out of the capture: under a texel from every probe

    @classmethod
    def take(cls, scene, grid, renderer, settings, proxy=None) -> "ProbeCapture":
        """Draw every probe's cube map of ``scene`` at ``settings`` (a BakeSettings: the
        cube-map size, visibility, near field) and build the tables. With ``proxy`` (a
        :class:`~cubegi_engine.proxy.CaptureProxy`), ``renderer`` draws the proxy's
        triangles, or casts them (a :class:`RayCubes`, which offers the host's ``rays`` to
        the tables as a renderer does), and the tables gather through its clusters."""
        return run(cls.take_steps(scene, grid, renderer, settings, proxy))

    @classmethod
    def take_steps(cls, scene, grid, renderer, settings, proxy=None, step=None, tracing=None):
        """:meth:`take` as a generator of working steps (:mod:`cubegi_engine.working`): the
        probes drawn in batches, the tables built in a thread. ``step(message)``: the working
        Progress to yield; ``tracing``: the near field's rays, started before the drawing
        (:func:`start_near_field`), or None. Returns the ProbeCapture."""
        step = step or (lambda message: Progress(Stage.CAPTURE, 0, 1, message, working=True))
        cube_size, visibility = int(settings.cube_size), bool(settings.visibility)
        positions = grid.positions()
        near, far = clip_planes(scene.scale, grid.point_cell_edge(positions))
        near = np.broadcast_to(np.asarray(near, dtype=np.float64), (len(positions),))
        t = time.perf_counter()
        if isinstance(renderer, RayCubes):  # (cast, not drawn: see RayCubes)
            per_batch, one = CAPTURE_RAYS_PER_STEP // (6 * cube_size * cube_size), renderer.capture
        else:
            drawn = len(proxy.triangles) if proxy is not None else len(scene.triangles)
            per_batch = CAPTURE_DRAWS_PER_STEP // max(6 * drawn, 1)
            one = lambda eyes, size, near_: capture_cubes(renderer, eyes, size, near_, far)  # noqa: E731
        batches = yield from in_batches(len(positions), per_batch, lambda a, b: one(positions[a:b], cube_size, near[a:b]),
                                        lambda done: step(f"captured {done} of {len(positions)} probes"))
        cubes = CubeCapture(*(np.concatenate([getattr(c, f) for c in batches]) for f in ("tid", "bary", "dist", "backface")))
        t_capture = time.perf_counter() - t
        t = time.perf_counter()
        def tables():
            scene.fingerprint()  # made here, in the thread, and kept on the snapshot for below
            return _tables(scene, grid, cubes, visibility, proxy, settings, renderer, tracing)

        transport = yield from in_background(tables, step("building the tables (what each probe sees, and each point's near field)"))
        return cls(grid, cube_size, visibility, scene.fingerprint(), cubes, transport, t_capture,
                   time.perf_counter() - t, proxy, settings.capture_key())

    def valid_for(self, scene, grid, settings, tables=True) -> bool:
        """True if this capture applies to ``scene`` baked on ``grid`` at ``settings`` (and
        its sky pattern, which the tables hold); with ``tables``, its tables too (they also
        hold which points emit across a covered gap: :meth:`Transport.emitters_changed`)."""
        return (
            self.key == settings.capture_key()
            and _same_grid(self.grid, grid) and not self.fingerprint.changed(scene.fingerprint())
            and _same_sky(self.transport, scene)
            and (not tables or not len(self.transport.emitters_changed(scene)))
        )

    def retabled_steps(self, scene, renderer, settings, step):
        """This capture's cube maps with the tables built anew for ``scene`` (whose geometry
        it was drawn of, :meth:`valid_for` without ``tables``): a generator of working steps
        (``step(message)``, in a thread) returning the ProbeCapture."""
        t = time.perf_counter()
        transport = yield from in_background(
            lambda: _tables(scene, self.grid, self.cubes, self.visibility, self.proxy, settings, renderer),
            step("building the tables again (a surface across a covered gap started or stopped emitting)"))
        return replace(self, transport=transport, capture_seconds=0.0, tables_seconds=time.perf_counter() - t)

    def patched(self, scene, grid, renderer, settings):
        """This capture brought up to date for ``scene`` whose geometry moved but kept its
        layout (the same objects, point counts and triangles): only the probes that saw a
        moved object, or may see it where it is now, are drawn again; the tables are built
        anew. Returns ``(ProbeCapture, probes drawn)``, or None where it cannot be patched
        (another grid or setting, a changed layout, or a simplified capture, whose clusters
        move with the geometry: take a new capture)."""
        fingerprint = scene.fingerprint()
        if (self.key != settings.capture_key() or not _same_grid(self.grid, grid) or self.proxy is not None
                or not fingerprint.same_layout(self.fingerprint)
                or not _same_sky(self.transport, scene)):
            return None
        moved = fingerprint.changed(self.fingerprint)
        names = [name for name, _ in fingerprint.objects]
        index = [names.index(n) for n in moved if n in names]
        t = time.perf_counter()
        redraw = self.probes_seeing(index) | self._may_see(scene, index)
        if redraw.all():  # every probe concerned: a new capture is as cheap
            return None
        cubes = CubeCapture(*(a.copy() for a in (self.cubes.tid, self.cubes.bary, self.cubes.dist, self.cubes.backface)))
        if redraw.any():
            eyes = grid.positions()[redraw]
            near, far = clip_planes(scene.scale, grid.point_cell_edge(eyes))
            fresh = capture_cubes(renderer, eyes, self.cube_size, near, far)
            for mine, theirs in zip((cubes.tid, cubes.bary, cubes.dist, cubes.backface), (fresh.tid, fresh.bary, fresh.dist, fresh.backface)):
                mine[redraw] = theirs
        t_capture = time.perf_counter() - t
        t = time.perf_counter()
        transport = _tables(scene, grid, cubes, self.visibility, None, settings, renderer)
        patched = ProbeCapture(grid, self.cube_size, self.visibility, fingerprint, cubes, transport, t_capture,
                               time.perf_counter() - t, None, self.key)
        return patched, int(redraw.sum())

    def _may_see(self, scene, objects) -> np.ndarray:
        """``(p,)`` bool: probes that may see any of ``objects`` where they are in ``scene``:
        some direction towards the object's points (its box corners and centre) in which the
        kept cube map records a surface farther than the object (or sky)."""
        if not objects:
            return np.zeros(len(self.cubes.tid), dtype=bool)
        owner = scene.point_object
        eyes = self.grid.positions()
        n = self.cube_size
        seen = np.zeros(len(eyes), dtype=bool)
        for k in objects:
            pts = scene.points[owner == k]
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            samples = np.concatenate([corners, [(lo + hi) / 2], pts[:: max(1, len(pts) // 64)]])  # (m, 3)
            rel = samples[None, :, :] - eyes[:, None, :]  # (p, m, 3)
            dist = np.linalg.norm(rel, axis=-1)
            face, row, col, _, _ = cubemap.direction_to_texel(np.where(dist[..., None] > 0, rel, 1.0), n)
            recorded = self.cubes.dist[np.arange(len(eyes))[:, None], face, row, col]
            seen |= np.any(recorded > dist * (1.0 - 2.0 / n), axis=1)
        return seen

    @property
    def probe_valid(self) -> np.ndarray:
        return self.transport.probe_valid

    def probes_seeing(self, objects) -> np.ndarray:
        """``(p,)`` bool: the probes whose cube maps show any triangle of the objects with
        these indices (``SceneArrays.point_object``); what a change of them invalidates."""
        tid = self.cubes.tid.reshape(len(self.cubes.tid), -1)
        owner = self.transport.triangle_object
        if owner is None:
            return np.ones(len(tid), dtype=bool)
        hit = np.isin(owner[np.maximum(tid, 0)], np.asarray(list(objects), dtype=np.int64)) & (tid >= 0)
        return hit.any(axis=1)

    @property
    def nbytes(self) -> int:
        """Memory held, in bytes."""
        arrays = [self.cubes.tid, self.cubes.bary, self.cubes.dist, self.cubes.backface, *self.transport.arrays()]
        return int(sum(a.nbytes for a in arrays))


class RayCubes:
    """The probes' cube maps cast through the host's ray caster instead of drawn: a ray from
    each probe through each texel's centre (:func:`~.cubemap.texel_directions`, where the
    drawing samples it), its nearest hit past the near plane's distance. What a texel sees is
    what the drawing gives it (the same triangle, side and distance), but at an edge, where
    float rounding decides either way. The probes' simplified copy of the scene is cast
    (:mod:`.proxy`): a few hundred thousand rays cost a tenth of drawing its triangles into
    every face on a CPU rasterizer (the Breakfast Room's 196 probes: 0.3-0.7 s against
    1.4-1.8 s on llvmpipe).

    ``make(points, triangles)``: the host's caster maker (a renderer's ``rays``); ``drawn``:
    the triangles cast (all: None); ``sheet (t,)``: triangles of two-sided objects, whose
    pairs of twins (:func:`~.geometry.twin_triangles`) are cast as one, a hit from behind
    taking the twin. A sheet's triangle with no twin (``lone``) is drawn with its back face
    culled: a ray that meets one from behind is cast on from just past it (the Breakfast
    Room's simplified copy has 472 such triangles among 64,512 of sheets)."""

    def __init__(self, make, points, triangles, drawn, twin, lone):
        self.points, self.triangles, self.twin, self.lone = points, triangles, twin, lone
        self.cast = first_of_twins(twin, drawn)
        span = points.max(axis=0) - points.min(axis=0) if len(points) else np.zeros(3)
        self.nudge = PAST_LONE * float(np.linalg.norm(span))
        self.caster = make(points, triangles[self.cast])
        # The host's caster maker, as a renderer offers it: the tables' near field casts
        # through it (gather.near_caster), over the scene's own triangles.
        self.rays = make

    @classmethod
    def of(cls, make, points, triangles, drawn=None, sheet=None) -> "RayCubes | None":
        """The cube maps of ``triangles`` cast (see the class), or None where the host has no
        caster (``make`` None) or nothing to cast."""
        triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        drawn = np.arange(len(triangles)) if drawn is None else np.asarray(drawn, dtype=np.int64)
        if make is None or not len(drawn):
            return None
        twin, lone = np.full(len(triangles), -1, dtype=np.int64), np.zeros(len(triangles), dtype=bool)
        if sheet is not None:
            asked = np.zeros(len(triangles), dtype=bool)
            asked[drawn] = np.asarray(sheet, dtype=bool)[drawn]
            twin = twin_triangles(points, triangles, asked)
            lone = asked & (twin < 0)
        return cls(make, np.asarray(points, dtype=np.float64), triangles, drawn, twin, lone)

    def capture(self, eyes, size, near) -> CubeCapture:
        """The cube maps at ``eyes (k, 3)`` of edge ``size``, ``near (k,)`` each one's near
        distance: a :class:`~.cubemap.CubeCapture` as :func:`~.cubemap.capture_cubes` gives."""
        eyes = np.asarray(eyes, dtype=np.float64).reshape(-1, 3)
        dirs = cubemap.texel_directions(size).reshape(-1, 3)
        per = len(dirs)
        origins = np.repeat(eyes, per, axis=0)
        d = np.tile(dirs, (len(eyes), 1))
        start = np.repeat(np.asarray(near, dtype=np.float64), per)
        found = self.caster.cast(origins + start[:, None] * d, d)
        hit, front, t = found.hit.copy(), found.front.copy(), found.t + start
        tid = np.where(hit, self.cast[np.maximum(found.triangle, 0)], -1)
        for _ in range(LONE_ROUNDS):  # through a lone sheet's back face, as its drawing culls it
            again = np.flatnonzero(hit & ~front & self.lone[np.maximum(tid, 0)])
            if not len(again):
                break
            past = t[again] + self.nudge
            on = self.caster.cast(origins[again] + past[:, None] * d[again], d[again])
            hit[again], front[again], t[again] = on.hit, on.front, on.t + past
            tid[again] = np.where(on.hit, self.cast[np.maximum(on.triangle, 0)], -1)
        back = hit & ~front
        turned = np.flatnonzero(back)
        turned = turned[self.twin[tid[turned]] >= 0]  # a sheet seen from behind: its twin, from the front
        tid[turned], back[turned] = self.twin[tid[turned]], False
        t = np.where(hit, t, np.inf)
        bary = hits_from_distances(self.points, self.triangles, origins, d, t, tid).bary
        shape = (len(eyes), 6, size, size)
        return CubeCapture(tid.astype(np.int32).reshape(shape), bary.astype(np.float32).reshape(shape + (3,)),
                           t.astype(np.float32).reshape(shape), back.reshape(shape))


def _tables(scene, grid, cubes, visibility, proxy, settings, renderer, tracing=None) -> Transport:
    """The tables of ``cubes`` (drawn of ``scene``, or of ``proxy``) on ``grid``, the near
    field's crowded points cast through the ``renderer``'s ray caster (``tracing``: its rays
    already started, see :func:`start_near_field`)."""
    return Transport(scene, grid, cubes, visibility=visibility, proxy=proxy, near_field=settings.near_field,
                     caster=near_caster(scene, renderer), tracing=tracing, make=getattr(renderer, "rays", None))


def start_near_field(scene, grid, renderer, settings):
    """The near field's rays of ``scene`` on ``grid`` started in a thread, or None where
    ``settings`` ask for no near field: they need only the geometry and the probes' cells,
    so a new capture traces them while the scene is simplified and the probes are drawn
    (:meth:`ProbeCapture.take_steps`' ``tracing``)."""
    return started(scene, grid, near_caster(scene, renderer)) if settings.near_field else None


def _same_sky(transport, scene) -> bool:
    """Whether the tables' sky pattern is ``scene``'s (both uniform, or the same image)."""
    return same_sky_map(getattr(transport, "sky_map", None), getattr(scene, "sky_map", None))


def _same_grid(a, b) -> bool:
    """Whether grids ``a`` and ``b`` number the same probes at the same places."""
    a_subset, b_subset = a.whole() is not a, b.whole() is not b
    if a_subset or b_subset:  # probe subsets
        return (a_subset and b_subset and np.array_equal(a.kept(), b.kept())
                and np.array_equal(a.positions(), b.positions()) and _same_grid(a.whole(), b.whole()))
    ga, gb = [g for g, _ in a.parts()], [g for g, _ in b.parts()]
    return len(ga) == len(gb) and all(x == y for x, y in zip(ga, gb))


def reference_coefficients(renderer, grid, scene, radiance, size, near, far):
    """The paper's way: draw the scene coloured by ``radiance`` ``(s, 3)`` into a cube map at
    every probe and project the images. Returns ``(p, 9, 3)`` float64. Sky is black."""
    eyes = grid.positions()
    vps = np.concatenate([cubemap.cube_view_projections(e, near, far) for e in eyes])
    images = renderer.render_colour(vps, size, radiance)  # (6p, n, n, 3)
    images = images.reshape(len(eyes), 6 * size * size, 3).astype(np.float64)
    dirs = cubemap.texel_directions(size).reshape(-1, 3)
    solid = np.tile(cubemap.texel_solid_angles(size).ravel(), 6)
    return sh.project(images, dirs, solid)
