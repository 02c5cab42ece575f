"""Direct light, kept per source: each light, the emissive surfaces and the sky.

Pure numpy; must not import bpy. Lights and emissive triangles (as two-sided area lights,
:mod:`cubegi_engine.emitters`) are computed per point with shadows from depth maps drawn by
the injected renderer. The sky reaches the points through the probes (the capture's
tables), as in the paper, less the directions the near field finds blocked close by; a
vertex no probe lights and nothing encloses (the outer face of a thick wall) sees it along
its own lines of sight, SKY_DIRECTIONS orthographic depth maps as a sun's. Cycles counts
both as direct. (Every vertex along its own lines of sight was measured too: on the
courtyard that took the direct error from 3.7% to 3.8-1.8% with 64-256 maps but the total
from 3.6% to 4.9-4.7%, and added 0.2-0.9 s to a 0.4 s bake.) No light reaches a point lying
on another surface (:meth:`~cubegi_engine.transport.Transport.resting`).

Keeping each source's share apart is what lets a later edit of one light's power or colour
be a weighted sum, and a moved light be recomputed alone.
"""

import time
from collections import deque
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from . import cubemap, sh
from . import eyes as eyes_mod
from . import lights as lights_mod
from .cubemap import CubeCapture, clip_planes, no_barycentrics
from .emitters import emitter_direct
from .eyes import SOFT_SAMPLES, soft, soft_count
from .gather import caster_made_by, gathered_for, light_visibility, scene_caster, scene_inward, sky_pattern
from .penumbra import sun_visibility
from .working import CAPTURE_DRAWS_PER_STEP, WORKERS, in_background, in_batches, run, start, wait

__all__ = ["DirectLight", "Shadow", "draw_shadow", "visibility", "light_direct", "direct_light", "EMISSION", "SKY"]

EMISSION, SKY = "emission", "sky"

# Sun shadow map frustum: a box around the scene's bounding sphere (radius grown by 1% so
# that its surface is inside), seen from two radii away along the sun's direction; near
# and far leave a margin of a thousandth of the radius and two radii beyond the scene.
SUN_BOX_MARGIN = 1.01
SUN_EYE_DISTANCE = 2.0
SUN_NEAR, SUN_FAR = 1e-3, 4.0
# A light whose strongest light at any point (before shadows) is at most this share of the
# brightest light's is left out (no shadow map drawn) and named in the report: a spot
# turned away, a light under the floor, a candle beside the sun.
LIGHT_LEFT_OUT = 1e-4
# Area light shadow eyes sit this share of the scene's size off the light's plane, so the
# light's own geometry (if any) and surfaces it rests on do not shadow it.
AREA_EYE_LIFT = 1e-4
# An area light shadowed from at least SHARED_EYES points draws its maps at half the Area
# Shadow Size (no smaller than MIN_SHARED_EDGE): each map's aliasing averages out over the
# points, because every point's cube map is turned its own way (cubemap.turns). The Cornell
# box's area light, 64 points, direct error against Cycles: maps all facing the axes 2.14%
# at 128^2, 2.24% at 64^2 (a row of points saw the tall block's edge fall in the same texel
# and erred together; 100 points were worse, 4.0%); turned, 1.7-1.9% at 64^2 over four seeds
# (100 points 1.8%, 144 points 1.5%), in half the time of 128^2.
SHARED_EYES, MIN_SHARED_EDGE = 32, 32


@dataclass
class DirectLight:
    """Direct light per source: ``parts`` maps a source key (each light's, from
    :func:`~cubegi_engine.lights.light_keys`, in scene order; ``"emission"``; ``"sky"``) to
    its ``(s, 3)`` light.

    source_coeffs: ``(p, 9, 3)`` float32 SH radiance the probes see of the emitters and the
    sky (the start of the probe field); emitter_energy_factor: ``(3,)`` (ones: emitters'
    light is exact; kept in the report's layout).
    """

    parts: dict
    source_coeffs: np.ndarray
    emitter_energy_factor: np.ndarray = field(default_factory=lambda: np.ones(3))
    light_seconds: float = 0.0
    probe_seconds: float = 0.0
    left_out: list = field(default_factory=list)  # LeftOut: lights skipped, each with why
    eyes: dict = field(default_factory=dict)  # Light.shadow_key -> the eyes a soft light was drawn from (eyes.shadow_eyes)

    def total(self, scene) -> np.ndarray:
        """Every source summed, dark points zeroed: ``(s, 3)``."""
        out = np.zeros((len(scene.points), 3))
        for value in self.parts.values():
            out += value
        return scene.zero_dark_points_inplace(out)


@dataclass
class Shadow:
    """A light's depth maps of some geometry: a cube map per eye (point, spot: the light's
    position; area: its sample points) or one orthographic map (sun). Kept so that other
    receivers (a moving object) can be tested against the same occluders.

    occluders: what the maps were drawn of; cubes: CubeCapture; eyes: ``(k, 3)``; turns:
    ``(k, 3, 3)`` each eye's cube rotation, where there are several; sun, sun_map: a sun's
    orthographic view and its depth map.
    """

    light: object
    occluders: lights_mod.Occluders
    cubes: CubeCapture | None = None
    eyes: np.ndarray | None = None
    sun: lights_mod.OrthoView | None = None
    sun_map: lights_mod.DepthMap | None = None
    turns: np.ndarray | None = None

    def cube_map(self, k) -> lights_mod.DepthMap:
        """Eye ``k``'s depth cube map."""
        assert self.cubes is not None, "a sun's shadow has no cube maps"
        return lights_mod.DepthMap(self.cubes.tid[k], self.cubes.dist[k], self.cubes.backface[k])

    @property
    def nbytes(self):
        arrays = [self.cubes.tid, self.cubes.dist, self.cubes.backface] if self.cubes is not None else []  # no barycentrics
        return int(sum(a.nbytes for a in arrays) + (self.sun_map.nbytes if self.sun_map is not None else 0))


def draw_shadow(scene, renderer, settings, light, size=None, eyes=None) -> Shadow:
    """Draw ``light``'s depth maps of ``scene`` (see :class:`Shadow`); ``size``: the maps'
    edge (default: the light's own ``shadow_size``, else the settings' for its kind);
    ``eyes``: how many points a soft light is drawn from (see :func:`~cubegi_engine.eyes.shadow_eyes`; None: all of its own)."""
    return run(draw_shadow_steps(scene, renderer, settings, light, size, eyes=eyes))


def _cubes_in_batches(scene, renderer, eyes, edge, near, far, turns, step):
    """Depth cube maps at ``eyes``, a batch of faces of about CAPTURE_DRAWS_PER_STEP triangles
    drawn at a time (a fixed batch: the same maps every time; one face at least), handing
    control back between them."""
    eyes = np.asarray(eyes, dtype=np.float64).reshape(-1, 3)
    vps = cubemap.cube_view_projections_many(eyes, near, far, turns)
    face_eyes = np.repeat(eyes, 6, axis=0)
    per = CAPTURE_DRAWS_PER_STEP // max(len(scene.triangles), 1)
    batches = yield from in_batches(
        len(vps), per, lambda a, b: renderer.render(vps[a:b], face_eyes[a:b], None, edge, with_bary=False),
        lambda done: _working(step, f"direct light: shadow maps, {done // 6} of {len(eyes)}"))
    tid, dist, back = (np.concatenate([batch[f] for batch in batches]) for f in (0, 2, 3))
    shape = (len(eyes), 6, edge, edge)
    return CubeCapture(tid.reshape(shape), no_barycentrics(shape + (3,)), dist.reshape(shape), back.reshape(shape))


def draw_shadow_steps(scene, renderer, settings, light, size=None, step=None, eyes=None):
    """:func:`draw_shadow` as a generator: a light's many cube maps (an area light's sample
    points, a soft light's) drawn in batches."""
    size = size or light.shadow_size or None
    shadow = Shadow(light, scene_occluders(scene, renderer))
    if light.kind == "SUN":
        lo, hi = scene.bounds()
        centre, radius = 0.5 * (lo + hi), 0.5 * scene.scale * SUN_BOX_MARGIN
        axis = light.direction / np.linalg.norm(light.direction)
        eye = centre - axis * radius * SUN_EYE_DISTANCE
        view = cubemap.look_matrix(eye, axis, cubemap.any_perpendicular(axis))
        vp = cubemap.orthographic(radius, SUN_NEAR * radius, SUN_FAR * radius) @ view
        tid, _, dist, back = renderer.render(vp[None], eye[None], axis[None], size or settings.sun_shadow_size, with_bary=False)
        shadow.sun, shadow.sun_map = lights_mod.OrthoView(vp, axis, eye, radius), lights_mod.DepthMap(tid[:1], dist[:1], back[:1])
        return shadow
    nearest, is_soft = yield from in_background(lambda: (_nearest_distance(scene.points, light.position), soft(light, scene.points)),
                                                _working(step, f"direct light: {light.name or 'a light'}'s shadow maps"))
    near, far = clip_planes(scene.scale, nearest)
    if light.kind == "AREA":
        samples = eyes_mod.fewer_samples(light.samples, eyes) if light.samples is not None and len(light.samples) else light.position[None]
        shadow.eyes = samples + light.direction * (AREA_EYE_LIFT * scene.scale)
        edge = size or (max(settings.area_shadow_size // 2, MIN_SHARED_EDGE) if len(samples) >= SHARED_EYES else settings.area_shadow_size)
        shadow.turns = cubemap.turns(len(shadow.eyes)) if len(shadow.eyes) > 1 else None
        shadow.cubes = yield from _cubes_in_batches(scene, renderer, shadow.eyes, edge, near, far, shadow.turns, step)
    elif is_soft and (eyes is None or eyes > 1):
        count = min(soft_count(scene), eyes or SOFT_SAMPLES)
        shadow.eyes = light.position + light.radius * sh.fibonacci_sphere(count)
        edge = size or max(settings.area_shadow_size, settings.shadow_size // 2)
        shadow.turns = cubemap.turns(count)
        shadow.cubes = yield from _cubes_in_batches(scene, renderer, shadow.eyes, edge, near, far, shadow.turns, step)
    else:
        shadow.eyes = light.position[None]
        shadow.cubes = yield from _cubes_in_batches(scene, renderer, shadow.eyes, size or settings.shadow_size, near, far, None, step)
    return shadow


def _nearest_distance(points, eye):
    """Distance from ``eye`` to the nearest point (what a light's near plane must not clip)."""
    return float(np.sqrt(np.min(np.einsum("sc,sc->s", points - eye, points - eye)))) if len(points) else 1.0


def scene_occluders(scene, renderer=None) -> lights_mod.Occluders:
    """Every triangle of ``scene`` as shadow maps' occluders, with the ``renderer``'s ray
    caster over them where it has one (asked where a map cannot decide; made when first
    asked). The occluders hold the caster's maker, not the renderer (a kept shadow must not
    keep the GPU's copy of the scene)."""
    make = getattr(renderer, "rays", None)
    rays = None if make is None else partial(caster_made_by, scene, make)
    return lights_mod.Occluders(scene.triangles, scene.points, scene.scale, scene.sides(), rays, partial(scene_inward, scene))


def visibility(shadow, pts, nrm, ids) -> np.ndarray:
    """``(k,)`` in [0, 1]: how much of ``shadow``'s light reaches each receiver (``ids``: the
    receivers' indices among the shadow's vertices, -1 for a receiver not among them)."""
    light, receivers = shadow.light, lights_mod.Receivers(pts, nrm, ids)
    if shadow.sun is not None:
        return sun_visibility(receivers, shadow.occluders, shadow.sun, shadow.sun_map, light.angle)
    if len(shadow.eyes) == 1 and light.kind != "AREA":
        return lights_mod.shadow_visibility(receivers, shadow.occluders, light.position, shadow.cube_map(0))
    # Several eyes (an area light's points, a soft point light's sphere): their visibility
    # weighted by how much light each sends the receiver.
    num = np.zeros(len(pts))
    den = np.zeros(len(pts))
    for k, eye in enumerate(shadow.eyes):
        rel = eye - pts
        d2 = np.einsum("sc,sc->s", rel, rel)
        cos_r = np.maximum(0.0, np.einsum("sc,sc->s", nrm, rel)) / np.sqrt(np.maximum(d2, 1e-300))
        cos_l = np.maximum(0.0, -(rel @ light.direction)) / np.sqrt(np.maximum(d2, 1e-300)) if light.kind == "AREA" else 1.0
        w = cos_r * cos_l / np.maximum(d2, 1e-300) + 1e-12
        vis = lights_mod.shadow_visibility(receivers, shadow.occluders, eye, shadow.cube_map(k), reach=0,
                                           turn=None if shadow.turns is None else shadow.turns[k])
        num += w * vis
        den += w
    return num / den


def light_direct(scene, renderer, settings, light, shadows=None, eyes=None) -> np.ndarray:
    """Diffuse light ``(s, 3)`` from one light, with shadows from depth maps. ``shadows``: a
    dict that keeps the light's :class:`Shadow` under its name, if given; ``eyes``: as for
    :func:`draw_shadow`."""
    return run(light_direct_steps(scene, renderer, settings, light, shadows, eyes=eyes))


def light_direct_steps(scene, renderer, settings, light, shadows=None, step=None, eyes=None):
    """:func:`light_direct` as a generator: the shadow maps drawn (the GPU's, here), the
    shadow test of every point run in a thread while it hands control back."""
    value = yield from in_background(lights_mod.unshadowed, _working(step, f"direct light: {light.name or 'a light'}"), light,
                                     scene.points, scene.normals)
    lit = np.any(value > 0, axis=1)
    if not light.casts_shadow or not lit.any():
        return value
    shadow = yield from draw_shadow_steps(scene, renderer, settings, light, step=step, eyes=eyes)
    if shadows is not None:
        shadows[light.shadow_key] = shadow
    ids = np.arange(len(scene.points))[lit]
    seen = yield from in_background(visibility, _working(step, f"direct light: {light.name or 'a light'}'s shadows"), shadow,
                                    scene.points[lit], scene.normals[lit], ids)
    gathered = gathered_for(scene, renderer)
    unshadowed = value[gathered.rows] if gathered is not None else None
    value[lit] *= seen[:, None]
    if gathered is not None:  # their own rays towards the light, from each corner
        vis = yield from in_background(light_visibility, _working(step, f"direct light: {light.name or 'a light'}'s shadows "
                                                                        "at the gathered vertices"),
                                       gathered, scene_caster(scene, renderer), light, shadow.eyes)
        value[gathered.rows] = unshadowed * vis[:, None]
    return value


def direct_light(scene, renderer, settings, transport, landing=None, shadows=None) -> DirectLight:
    """The direct light of every source of ``scene`` (see :class:`DirectLight`).

    ``landing``: as for :func:`cubegi_engine.solve.solve_steps`; the light from emitters is
    balanced with it (None: not balanced). ``shadows``: a dict that keeps each light's
    :class:`Shadow`, if given.
    """
    return run(direct_light_steps(scene, renderer, settings, transport, landing, shadows))


@dataclass
class LightsDone:
    """Lights worked out (:func:`lights_steps`): ``parts`` and ``left_out`` by light key, the
    keys ``asked``, the seconds, and every light's ``reach`` and ``eyes`` (see :mod:`.eyes`)."""

    parts: dict
    left_out: dict
    asked: frozenset
    seconds: float
    reach: list
    eyes: list


def lights_steps(scene, renderer, settings, shadows=None, step=None, ask=None, done=None):
    """The direct light of the lights ``ask(light)`` selects (every one by default) but
    those ``done`` (a LightsDone) holds, each with its shadows, handing control back after
    each: a LightsDone of those and ``done``'s."""
    from .records import LeftOut, LeftOutKind, Progress, Stage

    step = step or (lambda message: Progress(Stage.DIRECT, 1, 1, message, working=True))
    t = time.perf_counter()
    parts, left_out = dict(done.parts) if done else {}, dict(done.left_out) if done else {}
    asked = set(done.asked) if done else set()
    if done is None:
        reach, distances = yield from in_background(lambda: eyes_mod.reach(scene), step("direct light: where each light reaches"))
        eyes = eyes_mod.shadow_eyes(scene, scene.lights, distances)
    else:
        reach, eyes = done.reach, done.eyes
    brightest = max(reach, default=0.0)
    for k, (key, light) in enumerate(zip(lights_mod.light_keys(scene.lights), scene.lights)):
        if key in asked or (ask is not None and not ask(light)):
            continue
        asked.add(key)
        if reach[k] <= LIGHT_LEFT_OUT * brightest:  # no shadow map drawn for it
            why = "reaches no surface" if reach[k] <= 0.0 else f"below {LIGHT_LEFT_OUT:g} of the brightest light everywhere"
            name = light.name or str(k)
            left_out[key] = LeftOut(LeftOutKind.LIGHT, f"{name}: {why}", names=(name,))
            continue
        parts[key] = yield from light_direct_steps(scene, renderer, settings, light, shadows, step, eyes[k])
        yield step(f"direct light: {k + 1} of {len(scene.lights)} lights")
    seconds = time.perf_counter() - t + (done.seconds if done else 0.0)
    return LightsDone(parts, left_out, frozenset(asked), seconds, reach, eyes)


def sun_steps(scene, renderer, settings, shadows=None, step=None):
    """:func:`lights_steps` of the suns alone (None where there is none): their shadows need
    neither the probes nor the simplified scene, so the bake works them out while the scene
    is simplified (a thread of its own), where a core would wait."""
    if not any(light.kind == "SUN" for light in scene.lights):
        return None
    mask = getattr(scene, "gathered", None)
    if mask is not None and np.any(mask):  # their rays, cast in a thread (kept for the bake)
        yield from in_background(gathered_for, _working(step, "rays from the vertices that stand for much surface"), scene, renderer)
    return (yield from lights_steps(scene, renderer, settings, shadows, step, ask=lambda light: light.kind == "SUN"))


def direct_light_steps(scene, renderer, settings, transport, landing=None, shadows=None, step=None, done=None):
    """:func:`direct_light` as a generator that hands control back (``step(message)``, a
    working Progress) after each light, the emitters and the sky; returns the DirectLight.
    ``done``: lights already worked out (a LightsDone, as :func:`sun_steps` gives)."""
    from .records import Progress, Stage

    step = step or (lambda message: Progress(Stage.DIRECT, 1, 1, message, working=True))
    lights = yield from lights_steps(scene, renderer, settings, shadows, step, done=done)
    keys = lights_mod.light_keys(scene.lights)
    parts = {key: lights.parts[key] for key in keys if key in lights.parts}  # in scene order, however worked out
    left_out = [lights.left_out[key] for key in keys if key in lights.left_out]
    eyes, light_seconds = lights.eyes, lights.seconds
    t = time.perf_counter()
    coeffs = np.zeros((transport.probe_count, 9, 3), dtype=np.float32)
    factor = np.ones(3)
    if np.any(scene.emission > 0):
        coeffs = transport.gather_project(scene.emission)  # what the probes see (the field)
        # Straight to every point, exact, from both faces (as Cycles): see cubegi_engine.emitters.
        parts[EMISSION] = scene.zero_dark_points_inplace(emitter_direct(scene, renderer, settings.area_shadow_size))
        yield step("direct light: the emitters")
    if np.any(scene.sky > 0):
        coeffs = coeffs + transport.sky_coefficients(scene.sky)  # what the probes see of it (the field)
        parts[SKY] = scene.sky[None, :] * (yield from unit_sky_direct_steps(scene, renderer, transport, settings.sky_per_vertex, step))
    resting = transport.resting()
    for value in parts.values():  # none reaches them (a lamp's shadow maps miss a wall thinner than their bias)
        value[resting] = 0.0
    counts = {light.shadow_key: n for light, n in zip(scene.lights, eyes) if n is not None}
    return DirectLight(parts, coeffs, factor, light_seconds, time.perf_counter() - t, left_out, counts)


def unit_sky_direct(scene, renderer, transport, per_vertex=False) -> np.ndarray:
    """:func:`unit_sky_direct_steps` in one go."""
    return run(unit_sky_direct_steps(scene, renderer, transport, per_vertex))


def unit_sky_direct_steps(scene, renderer, transport, per_vertex=False, step=None):
    """Diffuse light ``(s, 3)`` of a sky of unit mean radiance (its pattern, if any): what
    the probes see of it (:meth:`Transport.seen_light`), and for the vertices no probe
    lights and nothing close encloses (the outer face of a thick wall: every probe is inside
    the room) the sky along their own lines of sight (:func:`sky_direct`). ``per_vertex``:
    every vertex a probe lights with any sky takes it along its own lines of sight too,
    SKY_PER_VERTEX_DIRECTIONS of them, drawn at SKY_PER_VERTEX_MAP_SIZE."""
    light = transport.seen_light(transport.sky_coefficients(np.ones(3)))
    alone = transport.covered.copy()
    if transport.near is not None:
        # Only a point closed in nearly all round (under a rug) is left to its near field: a
        # vertex where walls meet (half its view a wall) sees the sky along its own lines of
        # sight (the Breakfast Room's walls: direct light 0.0002 against Cycles' 0.16 when
        # half-enclosed points were left out).
        alone &= ~transport.near.enclosed(len(alone), SKY_ENCLOSED)
    alone &= ~transport.resting()  # not the underside of a block standing on the ground
    if per_vertex:  # every vertex its probes give any sky (one under a roof has none)
        alone |= ~transport.covered & (light.max(axis=1) > 0)
    if transport.gathered is not None:  # their own rays say it
        alone[transport.gathered.rows] = False
    if alone.any():
        sampling = (SKY_PER_VERTEX_DIRECTIONS, SKY_PER_VERTEX_MAP_SIZE) if per_vertex else (SKY_DIRECTIONS, SKY_MAP_SIZE)
        light[alone] = yield from sky_direct_steps(scene, renderer, np.flatnonzero(alone), *sampling, step=step,
                                                   rays_at_most=SKY_RAYS_AT_MOST)
    if transport.gathered is not None:
        light[transport.gathered.rows] = transport.gathered.sky
    return light


# A covered point whose near surroundings close in at least this share of its view takes
# no sky of its own (see unit_sky_direct).
SKY_ENCLOSED = 0.9
# The sky's direct light at a vertex no probe lights: its visibility along this many
# directions (a Fibonacci sphere), each an orthographic depth map of this edge, as a sun's.
# 64 -> 32: the Breakfast Room's sky (26,793 such vertices) 3.35 -> 1.73 s, direct error
# 6.11 -> 6.35%, indirect 34.04 -> 32.88%; the courtyard 0.31 -> 0.18 s, its errors unchanged;
# a hand-made room with a window 0.41 -> 0.33 s, indirect 23.2 -> 23.3%.
SKY_DIRECTIONS = 32
SKY_MAP_SIZE = 256
# The same for every vertex (``BakeSettings.sky_per_vertex``): on the sunlit courtyard of
# the benchmark, direct error 3.5% through the probes; 64 / 128 / 256 / 512 directions at
# 256: 4.3 / 2.6 / 1.8 / 1.5%; 256 directions at 128 / 384: 2.5 / 1.6%.
SKY_PER_VERTEX_DIRECTIONS = 256
SKY_PER_VERTEX_MAP_SIZE = 256
# Sky depth maps drawn and read back at a time: a step of about a tenth of a second on llvmpipe
# (The Breakfast Room: 32 at a time took 2.5-3.2 s between two steps of the modal bake).
SKY_MAPS_AT_ONCE = 2
# Where the points' rays across those directions are at most this many, a ray each way decides
# instead of the maps: the Breakfast Room's outside faces (26,793 points, 430K rays) by rays,
# direct light 6.35 -> 5.63% off Cycles, indirect 32.9 -> 32.6%, its window wall's mean -18.9 ->
# -11.2%, 0.3 s slower; the courtyard's 1,525 points, 24K rays, 0.15 -> 0.04 s. The courtyard's
# sky per vertex (3,242 points, 415K rays) 2.1 -> 1.4 s, direct 1.77 -> 1.39%. A ray costs
# 2-30 us (long ones through a large room the most) and a map several ms to a tenth of a second:
# the Breakfast Room's sky per vertex (7.3M rays) took 205 s by rays, 65 s by maps.
SKY_RAYS_AT_MOST = 500_000
# By rays, every SKY_FIRST_EVERY-th direction is asked first; a receiver whose first rays, at
# least SKY_FIRST_AT_LEAST of them, all meet a surface or all reach the sky takes that answer
# for its other directions (the Breakfast Room's outside faces: 79% see no sky along any of
# their rays, 10% see it along all).
SKY_FIRST_EVERY, SKY_FIRST_AT_LEAST = 4, 3


def sky_direct(scene, renderer, which, directions=SKY_DIRECTIONS, size=SKY_MAP_SIZE, rays_at_most=0) -> np.ndarray:
    """Diffuse light ``(k, 3)`` of a sky of unit mean radiance (its pattern, if any) at the
    points ``which (k,)``, with the scene's shadows: the unoccluded sky for each normal (exact
    for a uniform sky; the pattern's 9 SH coefficients otherwise) times the share of it the
    point sees, measured along ``directions`` directions, each an orthographic depth map of
    ``size`` drawn with the sun's machinery, weighted by the sky's radiance and the cosine.
    ``rays_at_most``: where the points' lines of sight are at most this many, a ray each way
    decides instead of the maps (see SKY_RAYS_AT_MOST)."""
    return run(sky_direct_steps(scene, renderer, which, directions, size, rays_at_most=rays_at_most))


def _working(step, stage_message):
    if step is None:
        from .records import Progress, Stage

        return Progress(Stage.DIRECT, 1, 1, stage_message, working=True)
    return step(stage_message)


def sky_direct_steps(scene, renderer, which, directions=SKY_DIRECTIONS, size=SKY_MAP_SIZE, step=None, rays_at_most=0):
    """:func:`sky_direct` as a generator handing control back after each direction."""
    dirs = sh.fibonacci_sphere(directions)  # towards the sky
    pattern = sky_pattern(scene, dirs)  # (k, 3)
    lo, hi = scene.bounds()
    centre, radius = 0.5 * (lo + hi), 0.5 * scene.scale * SUN_BOX_MARGIN
    eyes = centre + dirs * radius * SUN_EYE_DISTANCE
    vps = np.stack([cubemap.orthographic(radius, SUN_NEAR * radius, SUN_FAR * radius)
                    @ cubemap.look_matrix(e, -d, cubemap.any_perpendicular(d)) for e, d in zip(eyes, dirs)])
    pts, nrm = scene.points[which], scene.normals[which]
    seen = np.zeros((len(which), 3))
    facing = np.zeros((len(which), 3))
    occluders = scene_occluders(scene)

    def tests(first, tid, dist, back):
        """The shadow tests of a batch of maps: ``[(k, receivers, their visibility)]``."""
        out = []
        for j in range(len(tid)):
            k = first + j
            on = np.flatnonzero(nrm @ dirs[k] > 0)
            if len(on):
                view = lights_mod.OrthoView(vps[k], -dirs[k], eyes[k], radius)
                depth = lights_mod.DepthMap(tid[j:j + 1], dist[j:j + 1], back[j:j + 1])
                receivers = lights_mod.Receivers(pts[on], nrm[on], which[on])
                out.append((k, on, lights_mod.ortho_visibility(receivers, occluders, view, depth)))
        return out

    def add(done):
        for k, on, vis in done:
            w = (nrm[on] @ dirs[k])[:, None] * pattern[k][None, :]
            seen[on] += w * vis[:, None]
            facing[on] += w

    rays = None if getattr(renderer, "rays", None) is None else int(np.count_nonzero(nrm @ dirs.T > 0))
    if rays is not None and rays <= rays_at_most:  # few points: a ray each way, not a map
        receivers = lights_mod.Receivers(pts, nrm, which)
        working = _working(step, f"direct light: the sky, {rays:,} rays")
        yield working  # a step of its own, however fast the rays
        add((yield from in_background(_sky_rays, working, receivers, occluders, scene_caster(scene, renderer), dirs,
                                      2.0 * radius / size)))
        dirs = dirs[:0]  # no maps
    # Each batch's maps are drawn (the GPU's work, on this thread) while the batches before
    # are tested in threads, up to WORKERS at once; the sums are taken in order.
    jobs = deque()
    for first in range(0, len(dirs), SKY_MAPS_AT_ONCE):  # (a few hundred MB of maps at once, not more)
        tid, _, dist, back = renderer.render(vps[first : first + SKY_MAPS_AT_ONCE], eyes[first : first + SKY_MAPS_AT_ONCE],
                                             -dirs[first : first + SKY_MAPS_AT_ONCE], size, with_bary=False)
        while len(jobs) >= WORKERS:
            add((yield from wait(jobs.popleft(), _working(step, f"direct light: the sky, {first} of {len(dirs)} directions"))))
        jobs.append(start(tests, first, tid, dist, back))
        yield _working(step, f"direct light: the sky, {first + len(tid)} of {len(dirs)} directions drawn")
    while jobs:
        add((yield from wait(jobs.popleft(), _working(step, f"direct light: the sky, {len(dirs)} of {len(dirs)} directions"))))
    open_sky = np.ones((len(which), 3))
    if getattr(scene, "sky_map", None) is not None:  # the pattern's SH, as diffuse light per normal
        n = 16
        texel_dirs = cubemap.texel_directions(n).reshape(-1, 3)
        coeffs = sh.project(sky_pattern(scene, texel_dirs), texel_dirs, np.tile(cubemap.texel_solid_angles(n).ravel(), 6))
        open_sky = np.maximum(sh.diffuse_basis(nrm) @ coeffs, 0.0)
    return open_sky * np.where(facing > 0, seen / np.maximum(facing, 1e-300), 0.0)


def _sky_rays(receivers, occluders, caster, dirs, footprint):
    """:func:`sky_direct_steps`' shadow tests by rays: ``[(k, receivers, their visibility)]``
    for each direction ``dirs[k]``, one ray from each receiver facing it (started off its
    surface as a map's doubtful receiver's ray is: ``footprint``, the map's texel).

    Every SKY_FIRST_EVERY-th direction goes first; a receiver whose first rays (at least
    SKY_FIRST_AT_LEAST of them) all agree takes their answer for the others (see
    SKY_FIRST_EVERY)."""
    facing = receivers.normals @ dirs.T > 0  # (r, k)
    first = (np.arange(len(dirs)) % SKY_FIRST_EVERY == 0)[None, :] & facing
    open_ = np.zeros(facing.shape, dtype=bool)
    open_[first] = _sky_open(receivers, occluders, caster, dirs, footprint, first)
    asked = first.sum(axis=1)
    seen = (open_ & first).sum(axis=1)
    decided = (asked >= SKY_FIRST_AT_LEAST) & ((seen == 0) | (seen == asked))
    rest = facing & ~first & ~decided[:, None]
    open_[rest] = _sky_open(receivers, occluders, caster, dirs, footprint, rest)
    open_ |= facing & ~first & (decided & (seen > 0))[:, None]
    row, k = np.nonzero(facing)
    order = np.argsort(k, kind="stable")  # each direction's rays together (not one mask per direction)
    bounds = np.searchsorted(k[order], np.arange(len(dirs) + 1))
    return [(j, row[order[a:b]], open_[row[order[a:b]], j].astype(np.float64))
            for j, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])) if b > a]


def _sky_open(receivers, occluders, caster, dirs, footprint, ask):
    """``(m,)`` bool in ``np.nonzero(ask)`` order: whether the ray from each asked receiver
    along each asked direction (``ask (r, k)``) reaches the sky."""
    row, k = np.nonzero(ask)
    if not len(row):
        return np.zeros(0, dtype=bool)
    start = lights_mod.ray_starts(receivers[row], occluders, np.full(len(row), footprint), np.arange(len(row)))
    return ~caster.blocked(start, dirs[k], None)
