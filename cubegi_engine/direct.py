"""Direct light, kept per source: each light, the emissive surfaces and the sky.

Pure numpy; must not import bpy. Lights and emissive triangles (as two-sided area lights,
:mod:`cubegi_engine.emitters`) are computed per point with shadows from depth maps drawn by
the injected renderer. The sky reaches the points through the probes (the capture's
tables), as in the paper, less the directions the near field finds blocked close by; a
vertex no probe lights and nothing encloses (the outer face of a thick wall) sees it along
its own lines of sight, by rays or orthographic depth maps as a sun's (:mod:`.sky`). Cycles counts
both as direct. (Every vertex along its own lines of sight was measured too: on the
courtyard that took the direct error from 3.7% to 3.8-1.8% with 64-256 maps but the total
from 3.6% to 4.9-4.7%, and added 0.2-0.9 s to a 0.4 s bake.) No light reaches a point lying
on another surface (:meth:`~cubegi_engine.transport.Transport.resting`).

Keeping each source's share apart is what lets a later edit of one light's power or colour
be a weighted sum, and a moved light be recomputed alone.
"""

import time
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from . import cubemap, sh, sky
from . import eyes as eyes_mod
from . import lights as lights_mod
from .cubemap import CubeCapture, clip_planes, no_barycentrics
from .emitters import emitter_direct
from .eyes import SOFT_SAMPLES, SUN_BOX_MARGIN, SUN_EYE_DISTANCE, SUN_FAR, SUN_NEAR, soft, soft_count
from .gather import gathered_for, light_visibility, scene_caster, scene_occluders
from .penumbra import sun_visibility
from .records import direct_step
from .working import CAPTURE_DRAWS_PER_STEP, in_background, in_batches, run

__all__ = ["DirectLight", "Shadow", "draw_shadow", "visibility", "light_direct", "direct_light", "EMISSION", "SKY"]

EMISSION, SKY = "emission", "sky"

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
        lambda done: direct_step(step, f"direct light: shadow maps, {done // 6} of {len(eyes)}"))
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
                                                direct_step(step, f"direct light: {light.name or 'a light'}'s shadow maps"))
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
    value = yield from in_background(lights_mod.unshadowed, direct_step(step, f"direct light: {light.name or 'a light'}"), light,
                                     scene.points, scene.normals)
    lit = np.any(value > 0, axis=1)
    if not light.casts_shadow or not lit.any():
        return value
    shadow = yield from draw_shadow_steps(scene, renderer, settings, light, step=step, eyes=eyes)
    if shadows is not None:
        shadows[light.shadow_key] = shadow
    return (yield from in_background(_shadowed, direct_step(step, f"direct light: {light.name or 'a light'}'s shadows"), scene,
                                     partial(scene_caster, scene, renderer), gathered_for(scene, renderer), light, value, lit, shadow))


def _shadowed(scene, caster, gathered, light, value, lit, shadow):
    """``value (s, 3)``, a light's unshadowed light, times the share of the light that
    reaches each point it lights (``lit``) past ``shadow``; the gathered points' (``gathered``)
    by their own rays (through ``caster()``)."""
    seen = visibility(shadow, scene.points[lit], scene.normals[lit], np.arange(len(scene.points))[lit])
    unshadowed = value[gathered.rows] if gathered is not None else None
    value[lit] *= seen[:, None]
    if gathered is not None:  # their own rays towards the light, from each corner
        value[gathered.rows] = unshadowed * light_visibility(gathered, caster(), light, shadow.eyes)[:, None]
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
        yield from in_background(gathered_for, direct_step(step, "rays from the vertices that stand for much surface"), scene, renderer)
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
        parts[SKY] = scene.sky[None, :] * (yield from sky.unit_sky_direct_steps(scene, renderer, transport, settings.sky_per_vertex, step))
    resting = transport.resting()
    for value in parts.values():  # none reaches them (a lamp's shadow maps miss a wall thinner than their bias)
        value[resting] = 0.0
    counts = {light.shadow_key: n for light, n in zip(scene.lights, eyes) if n is not None}
    return DirectLight(parts, coeffs, factor, light_seconds, time.perf_counter() - t, left_out, counts)
