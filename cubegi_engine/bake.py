"""The one-shot bake, composed of the parts that outlive it.

Pure numpy; must not import bpy. The GPU is reached only through the ``renderer`` passed
in (see :class:`Renderer`), so the same pipeline runs from the add-on, the command line and
the tests.

A bake is: a :class:`~cubegi_engine.capture.ProbeCapture` (taken, or reused when still
valid), the :class:`~cubegi_engine.direct.DirectLight` of every source, one
:class:`~cubegi_engine.solve.LightSolution` of their sum, and the
:class:`~cubegi_engine.field.ProbeField` the probes see of the result. :func:`bake_steps`
yields a :class:`~cubegi_engine.records.Progress` after every stage (so a modal operator
can show each bounce as it lands) and returns a :class:`BakeResult` holding all four.
"""

import dataclasses
import os
import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .capture import ProbeCapture, RayCubes, start_near_field
from .direct import DirectLight, direct_light_steps, sun_steps
from .emitters import balanced_landing
from .errors import BakeError
from .field import ProbeField
from .gather import front_triangles, gathered_for, scene_caster
from .geometry import chunks
from .grid import ProbeSubset, probes_used
from .placement import HostRays, Placement, place
from .proxy import simplify
from .records import Progress, Stage
from .settings import BakeSettings
from .solve import LightSolution, area_weighted_mean, solve_steps
from .spatial import forget_indexes
from .working import abandon, in_background, run, start, wait  # noqa: F401 (bake.run: the one driver)

__all__ = ["Renderer", "BakeResult", "bake_steps", "start_simplifying", "run", "check_memory", "memory_estimate", "area_weighted_mean"]


class Renderer(Protocol):
    """What the bake needs from the GPU.

    ``render(view_projs (v, 4, 4), eyes (v, 3), axes (v, 3) or None, size, with_bary=True)``
    draws the scene's triangles into ``v`` square views and returns per texel the triangle
    index (int32, -1 for nothing), barycentric weights ``(v, n, n, 3)`` (without
    ``with_bary``, for shadows' depth maps: zeros that take no memory,
    :func:`~cubegi_engine.cubemap.no_barycentrics`), distance (radial from the eye, or along ``axes``
    for orthographic views; inf for nothing) and a back-face flag.
    ``render_colour(view_projs, size, point_radiance (s, 3))`` draws the scene coloured by
    per-point radiance (back faces black) and returns ``(v, n, n, 3)``.
    ``with_geometry(points, triangles, drawn=None, sheet=None)``: a renderer of other
    triangles (a simplified copy of the scene for the probes); ``drawn``: the indices of the
    triangles it draws (the rest are left out), each still reported by its own index;
    ``sheet``: ``(t,)`` bool, triangles whose back faces are not drawn (two-sided objects,
    whose twins stand there: ``SceneArrays.back``). A renderer of the scene itself is made
    with the scene's ``sheet_triangles()``; of a sheet's two twins it may draw one, reporting
    the other where it is seen from behind. ``rays(points, triangles)`` (optional): a
    :class:`~cubegi_engine.rays.RayCaster` over those triangles (else the engine tests every
    ray against every triangle: small scenes).
    """

    def render(self, view_projs, eyes, axes, size, with_bary=True): ...

    def render_colour(self, view_projs, size, point_radiance): ...

    def with_geometry(self, points, triangles, drawn=None, sheet=None): ...


@dataclass
class BakeResult:
    """A bake's parts: the capture, the direct light per source, the solution of their sum
    and the probe field; ``timings`` in seconds by stage."""

    capture: ProbeCapture
    direct_parts: DirectLight
    solution: LightSolution
    field: ProbeField
    timings: dict = dataclasses.field(default_factory=dict)
    capture_reused: bool = False
    probes_recaptured: int | None = None  # a patched capture: how many probes were drawn again
    shadows: dict = dataclasses.field(default_factory=dict)  # Light.shadow_key -> Shadow, when kept (moving objects)
    placement: Placement | None = None  # probes moved out of geometry or left out before the capture

    @property
    def direct(self) -> np.ndarray:
        return self.solution.direct

    @property
    def bounces(self) -> list:
        return self.solution.bounces

    @property
    def indirect(self) -> np.ndarray:
        return self.solution.indirect

    @property
    def grid(self):
        return self.capture.grid

    @property
    def probe_valid(self) -> np.ndarray:
        return self.capture.probe_valid

    @property
    def seen_from_behind(self):
        return self.capture.transport.seen_from_behind


# Bytes per cube-map texel while a bake runs: the capture (triangle, barycentrics, distance,
# back-face flag), the gather tables (corners, weights) and the gather's temporaries.
BYTES_PER_TEXEL = 80
BYTES_PER_POINT = 8 * 8 * 9 * 4 + 400  # interpolation weights and per-point arrays


# Probes whose distances to every object are taken at a time (small-object test).
PROBES_AT_ONCE = 256


def memory_estimate(probes, cube_size, points) -> int:
    """Bytes a bake of ``probes`` cube maps of ``cube_size`` over ``points`` needs, roughly."""
    return int(probes) * 6 * int(cube_size) ** 2 * BYTES_PER_TEXEL + int(points) * BYTES_PER_POINT


def physical_memory():
    """This machine's memory in bytes (None where it cannot be told)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(probes, cube_size, points, limit=None) -> int:
    """Refuse, with the estimate, a bake that would need more than half the memory."""
    need = memory_estimate(probes, cube_size, points)
    total = limit if limit is not None else physical_memory()
    if total and need > 0.5 * total:
        raise BakeError(
            f"{probes} probes at {cube_size}x{cube_size} would need about {need / 2**30:.1f} GiB, more than half of "
            f"this machine's {total / 2**30:.1f} GiB; use fewer probes or a smaller cube-map size"
        )
    return need


def bake_steps(scene, grid, renderer, settings: BakeSettings | None = None, capture: ProbeCapture | None = None,
               keep_shadows: bool = False, whole_field: bool = False, simplifying=None):
    """Bake ``scene`` on ``grid``; a generator of :class:`Progress`, returning a BakeResult.

    ``capture``: a capture kept from an earlier bake; used if it is still valid for this
    scene, grid and settings (else a new one is taken). ``keep_shadows``: keep every
    light's depth maps of the scene in the result (moving objects are tested against them).
    Probes that give no point a trilinear weight light nothing and are not captured, and
    probes inside geometry are moved out of it or left out (``settings.move_probes``,
    :mod:`cubegi_engine.placement`); the result's grid is then a
    :class:`~cubegi_engine.grid.ProbeSubset`. ``whole_field`` captures every probe but the
    ones inside geometry, for a probe field that must light points anywhere in the grid
    (dynamic objects). ``simplifying``: the scene's simplification for a new capture, already
    started by the caller (:func:`start_simplifying`, while it uploads the scene to the GPU).
    """
    try:
        return (yield from _bake(scene, grid, renderer, settings, capture, keep_shadows, whole_field, simplifying))
    finally:
        forget_indexes()  # the voxel indexes its stages shared


def probe_rays(scene, renderer, settings):
    """What the placement casts its crowded probes' rays through (:func:`~.placement.place`'s
    ``rays``): a callable giving a :class:`~.placement.HostRays` over ``scene``'s caster;
    None where the host has no caster of its own, or where the scene has more triangles
    than the capture's budget: there the caster, made this early, is kept through the
    tables' peak of memory (the Room at 993K vertices: 2.96 -> 3.44 GB), and the capture's
    own test still leaves out the probes it finds inside."""
    budget = settings.capture_triangles
    if getattr(renderer, "rays", None) is None or (budget is not None and len(scene.triangles) > budget):
        return None
    sheet = scene.sheet_triangles()
    return lambda: HostRays(scene_caster(scene, renderer), None if sheet is None else sheet[front_triangles(scene)])


def start_simplifying(scene, settings: BakeSettings | None = None):
    """:func:`~cubegi_engine.proxy.simplify` of ``scene`` to the capture's triangle budget,
    started in a thread (for :func:`bake_steps`' ``simplifying``)."""
    return start(simplify, scene, (settings or BakeSettings()).capture_triangles)


def _bake(scene, grid, renderer, settings, capture, keep_shadows, whole_field, simplifying):
    settings = (settings or BakeSettings()).validate()
    t_start = time.perf_counter()
    timings = {}
    total = 3 + settings.bounces

    def working(stage, done):
        return lambda message: Progress(stage, done, total, message, working=True)

    used = np.ones(grid.count, dtype=bool) if whole_field else (
        yield from in_background(probes_used, working(Stage.CAPTURE, 0)("finding the probes the points use"), grid, scene.points))
    yield from in_background(scene.point_areas, working(Stage.CAPTURE, 0)("the area of each point"))  # kept for the rest
    # A new capture's simplified scene does not depend on the probes: made while they are
    # placed (two threads of numpy work), where no capture is kept (one that is kept is
    # reused or patched, or else simplifies after).
    if simplifying is None and capture is None:
        simplifying = start_simplifying(scene, settings)
    placement = None
    if settings.move_probes:
        placement = yield from in_background(place, working(Stage.CAPTURE, 0)("placing the probes"), grid, scene.points,
                                             scene.triangles, used, probe_rays(scene, renderer, settings))
        used = placement.keep
        timings["placement"] = placement.seconds
    if not used.all() or (placement is not None and placement.moved):
        grid = ProbeSubset(grid, used, None if placement is None else placement.displacement)

    shadows: dict | None = {} if keep_shadows else None
    suns = None  # the suns' direct light, where worked out before the capture
    drawn = capture is not None and capture.valid_for(scene, grid, settings, tables=False)  # the cube maps hold
    reused = drawn and not len(capture.transport.emitters_changed(scene))
    patched = None
    if drawn and not reused:
        patched = (yield from capture.retabled_steps(scene, renderer, settings, working(Stage.CAPTURE, 0))), 0
    elif capture is not None and not reused:
        patched = capture.patched(scene, grid, renderer, settings)
    if reused:
        yield Progress(Stage.CAPTURE, 0, total, f"reusing the capture of {grid.count} probes (the geometry is unchanged)")
        timings["capture"] = timings["tables"] = 0.0
    elif patched is not None:
        capture, redrawn = patched
        yield Progress(Stage.CAPTURE, 0, total, f"re-captured {redrawn} of {grid.count} probes (the ones a moved object concerns)"
                       if redrawn else f"the capture of {grid.count} probes kept, its tables built again")
        timings["capture"], timings["tables"] = capture.capture_seconds, capture.tables_seconds
    else:
        check_memory(grid.count, settings.cube_size, len(scene.points))  # (before any work)
        capture, suns = yield from _new_capture(scene, grid, renderer, settings, working, timings, total, simplifying, shadows)
        timings["capture"], timings["tables"] = capture.capture_seconds, capture.tables_seconds
    assert capture is not None  # reused, patched or new
    transport = capture.transport
    # (Part of "tables": what they waited for the near field past what ran beside them.)
    timings["near_field"] = transport.near_waited if transport.near is not None and not reused else 0.0
    if scene.gathered is not None and scene.gathered.any():
        gathered = yield from in_background(gathered_for, working(Stage.CAPTURE, 0)("rays from the vertices that stand for much "
                                                                                   "surface"), scene, renderer)
        transport.take_gathered(gathered)
        timings["gather"] = gathered.seconds if gathered is not None else 0.0

    yield Progress(Stage.DIRECT, 1, total, f"direct light from {len(scene.lights)} lights")
    t = time.perf_counter()
    landing = (yield from in_background(lambda: balanced_landing(scene, transport), working(Stage.DIRECT, 1)(
        "the share of each point's view that is surface"))) if settings.conserve_energy else None
    t_landing = time.perf_counter() - t
    parts = yield from direct_light_steps(scene, renderer, settings, transport, landing, shadows, step=working(Stage.DIRECT, 1),
                                          done=suns)
    direct = parts.total(scene)
    timings["direct_lights"], timings["direct_probes"] = parts.light_seconds, parts.probe_seconds + t_landing
    timings["direct"] = timings["direct_lights"] + timings["direct_probes"]
    yield Progress(Stage.DIRECT, 2, total, "direct light done", light=direct, new_light=direct)

    t = time.perf_counter()
    solution = yield from solve_steps(scene, transport, direct, settings, landing, first_step=2, total_steps=total)
    timings["bounces"] = sum(r.seconds for r in solution.records)
    timings["tail"] = max(time.perf_counter() - t - timings["bounces"], 0.0)
    coeffs = parts.source_coeffs + solution.bounce_coeffs
    if solution.tail_coeffs is not None and solution.tail_report.added:
        coeffs = coeffs + solution.tail_coeffs
    probe_field = ProbeField(grid, coeffs, capture.probe_valid.copy(), parts.source_coeffs)
    timings["total"] = time.perf_counter() - t_start
    return BakeResult(capture, parts, solution, probe_field, timings, reused, patched[1] if patched else None, shadows or {},
                      placement)


# An object is left out of the capture where from every probe it spans less than this many
# texels (it still receives light, and lights others through the direct light's shadows).
SMALL_OBJECT_TEXELS = 1.0
# The probes' simplified copy of the scene is cast through the host's ray caster, not drawn
# (capture.RayCubes): the Breakfast Room's capture 1.5-2.7 -> 0.4-0.5 s on llvmpipe, its
# light within 0.2% of the drawn capture's and its errors against Cycles the same.
CAPTURE_BY_RAYS = True


def _new_capture(scene, grid, renderer, settings, working, timings, total, simplifying, shadows):
    """A new capture of ``scene`` on ``grid`` and the suns' direct light (a generator of
    Progress, returning ``(ProbeCapture, suns)``, see :func:`~.direct.sun_steps`, which keeps
    their ``shadows``): the suns' light worked out while the scene is simplified, then the
    near field's rays started (they need only the geometry and the probes' cells: traced
    while the probes are drawn, :func:`_drawn`), the tables built. A failed one stops those
    rays and waits for them. (Traced beside the suns' rays, at 1.24M vertices, both took
    longer.)"""
    suns = yield from sun_steps(scene, renderer, settings, shadows, working(Stage.CAPTURE, 0))
    tracing = start_near_field(scene, grid, renderer, settings)
    try:
        return (yield from _drawn(scene, grid, renderer, settings, working, timings, total, simplifying, tracing)), suns
    except BaseException:
        if tracing is not None:
            abandon(tracing)
        raise


def _drawn(scene, grid, renderer, settings, working, timings, total, simplifying, tracing):
    """The probes of a new capture drawn and its tables built (see :func:`_new_capture`): the
    scene simplified to the capture's triangle budget (``simplifying``: that work already
    started, see :func:`~.working.start`), objects under a texel from every probe left out
    of the drawing. The simplify timing is what the bake waited for it."""
    t = time.perf_counter()
    simplifying = simplifying or start_simplifying(scene, settings)
    proxy = yield from wait(simplifying, working(Stage.CAPTURE, 0)("simplifying the scene for the probes"))
    shown = (scene.points, scene.triangles, scene.triangle_object()) if proxy is None else (
        proxy.points, proxy.triangles, proxy.triangle_object)
    small = small_objects(shown[0], shown[1], shown[2], grid.positions(), settings.cube_size)
    if small.any() and small[shown[2]].all():  # nothing would be left to draw
        small[:] = False
    if proxy is None and not small.any():
        drawer = renderer
    else:
        sheet = scene.sheet_triangles() if proxy is None else proxy.sheet_triangles(scene)
        drawn = None if not small.any() else np.flatnonzero(~small[shown[2]])
        # A simplified copy is cast where the host has a ray caster (RayCubes): the scene's
        # own triangles are drawn as before.
        drawer = RayCubes.of(getattr(renderer, "rays", None), shown[0], shown[1], drawn, sheet) if (
            proxy is not None and CAPTURE_BY_RAYS) else None
        drawer = drawer or renderer.with_geometry(shown[0], shown[1], drawn, sheet)
    timings["simplify"] = time.perf_counter() - t
    drawn = f" ({len(proxy.triangles):,} of {len(scene.triangles):,} triangles)" if proxy is not None else ""
    yield Progress(Stage.CAPTURE, 0, total, f"capturing {grid.count} probes at {settings.cube_size}x{settings.cube_size}{drawn}")
    capture = yield from ProbeCapture.take_steps(scene, grid, drawer, settings, proxy, step=working(Stage.CAPTURE, 0), tracing=tracing)
    capture.small_objects = tuple(int(k) for k in np.flatnonzero(small))
    return capture


def small_objects(points, triangles, triangle_object, probes, cube_size) -> np.ndarray:
    """``(objects,)`` bool: the objects (``triangle_object (t,)`` per triangle of ``triangles``
    over ``points``) that span less than SMALL_OBJECT_TEXELS texels of a ``cube_size`` cube
    map from every one of ``probes (p, 3)``: their bounding sphere's angular diameter from
    the nearest probe, against a texel's angle at a face's centre (the largest)."""
    if triangle_object is None or not len(triangles) or not len(probes):
        return np.zeros(0 if triangle_object is None else int(np.max(triangle_object, initial=-1)) + 1, dtype=bool)
    owner = np.asarray(triangle_object, dtype=np.int64)
    count = int(owner.max()) + 1
    corners = np.asarray(points, dtype=np.float64)[np.asarray(triangles)]  # (t, 3, 3)
    lo = np.full((count, 3), np.inf)
    hi = np.full((count, 3), -np.inf)
    np.minimum.at(lo, owner, corners.min(axis=1))
    np.maximum.at(hi, owner, corners.max(axis=1))
    used = np.isfinite(lo[:, 0])
    centre = np.where(used[:, None], 0.5 * (lo + hi), 0.0)
    radius = np.where(used, 0.5 * np.linalg.norm(np.where(used[:, None], hi - lo, 0.0), axis=1), 0.0)
    probes = np.asarray(probes, dtype=np.float64)
    nearest = np.full(count, np.inf)
    for sl in chunks(len(probes), PROBES_AT_ONCE):  # (objects, PROBES_AT_ONCE) distances at a time
        d = np.linalg.norm(centre[:, None, :] - probes[None, sl], axis=2)
        nearest = np.minimum(nearest, d.min(axis=1))
    gap = nearest - radius
    texel = 2.0 / float(cube_size)  # radians subtended by a texel at a face's centre
    return used & (gap > 0) & (2.0 * radius < SMALL_OBJECT_TEXELS * texel * gap)


