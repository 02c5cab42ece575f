"""The bake: direct light, probe capture, and the bounce loop, as one generator.

Pure numpy; must not import bpy. The GPU is reached only through the ``renderer`` passed
in (see :class:`Renderer`), so the same pipeline runs from the add-on, the command line and
the tests.

:func:`bake_steps` yields a :class:`Progress` after every stage (so a modal operator can
show each bounce as it lands) and returns a :class:`BakeResult`.
"""

import os
import time
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from . import convergence, cubemap, lights as lights_mod
from .transport import Transport, capture_cubes, clip_planes

MIN_CUBE_SIZE, MAX_CUBE_SIZE = 4, 512
# A tail solve that ends with a larger relative residual than this is not trusted.
SOLVE_GIVE_UP = 1e-2


class Renderer(Protocol):
    """What the bake needs from the GPU.

    ``render(view_projs (v, 4, 4), eyes (v, 3), axes (v, 3) or None, size)`` draws the
    scene's triangles into ``v`` square views and returns per texel the triangle index
    (int64, -1 for nothing), barycentric weights ``(v, n, n, 3)``, distance (radial from the
    eye, or along ``axes`` for orthographic views; inf for nothing) and a back-face flag.
    ``render_colour(view_projs, size, point_radiance (s, 3))`` draws the scene coloured by
    per-point radiance (back faces black) and returns ``(v, n, n, 3)``.
    """

    def render(self, view_projs, eyes, axes, size): ...

    def render_colour(self, view_projs, size, point_radiance): ...


@dataclass
class BakeSettings:
    """Everything that sets how a bake runs (not what it bakes)."""

    cube_size: int = 32
    bounces: int = 5
    visibility: bool = True
    shadow_size: int = 512
    sun_shadow_size: int = 2048
    area_shadow_size: int = 128
    # Stop once the estimated missing share of the indirect light is below this (None: run
    # all ``bounces``); ``bounces`` stays the cap.
    tolerance: float = None
    add_tail: bool = True  # add the light after the last bounce (estimated) to the total
    solve_tolerance: float = 1e-5
    # Scale each bounce (and the light from emitters) so that the power the surfaces receive
    # equals the power they send that lands on surfaces (see :func:`conserve_energy`).
    conserve_energy: bool = True

    def validate(self):
        if not MIN_CUBE_SIZE <= int(self.cube_size) <= MAX_CUBE_SIZE:
            raise ValueError(f"cube-map size must be between {MIN_CUBE_SIZE} and {MAX_CUBE_SIZE}, got {self.cube_size}")
        if int(self.bounces) < 0:
            raise ValueError(f"bounces must be 0 or more, got {self.bounces}")
        if self.tolerance is not None and not 0.0 < float(self.tolerance) < 1.0:
            raise ValueError(f"tolerance must be between 0 and 1 (a share of the light), got {self.tolerance}")


@dataclass
class Progress:
    stage: str
    done: int
    total: int
    message: str
    light: np.ndarray = None  # (s, 3) the light so far (direct + bounces), when it changed


@dataclass
class BakeResult:
    """Diffuse light per point: ``direct (s, 3)`` and one ``(s, 3)`` per bounce."""

    direct: np.ndarray
    bounces: list
    timings: dict
    bounce_records: list = field(default_factory=list)
    grid: object = None
    probe_valid: np.ndarray = None
    tail: np.ndarray = None  # (s, 3) light after the last bounce, when estimated
    tail_report: dict = field(default_factory=dict)
    # (p, 9, 3) SH radiance seen by each probe, summed over the computed bounces (emitters and
    # sky included; the tail not): what the probe-sphere display shows.
    probe_coeffs: np.ndarray = None
    # (objects,) share of each object's probe-seen solid angle that shows back faces (None
    # without SceneArrays.point_object); see transport._seen_from_behind.
    seen_from_behind: np.ndarray = None
    emitter_energy_factor: np.ndarray = None  # (3,) the energy factor of the light from emitters

    @property
    def bounce_sum(self):
        if not self.bounces:
            return np.zeros_like(self.direct)
        return np.sum(self.bounces, axis=0)

    @property
    def indirect(self):
        """The indirect light: the bounces, plus the tail when it is to be added."""
        if self.tail is not None and self.tail_report.get("added"):
            return self.bounce_sum + self.tail
        return self.bounce_sum


def area_weighted_mean(values, areas):
    """Area-weighted mean of ``values (s, 3)``: ``(3,)``."""
    total = float(areas.sum())
    if total <= 0.0:
        return np.zeros(values.shape[1:])
    return (values * areas[:, None]).sum(axis=0) / total


def direct_from_lights(scene, renderer, settings):
    """Diffuse light ``(s, 3)`` from every light, with shadows from depth maps."""
    s = len(scene.points)
    out = np.zeros((s, 3))
    point_ids = np.arange(s)
    scale = scene.scale
    near, far = clip_planes(scale)
    for light in scene.lights:
        value = lights_mod.unshadowed(light, scene.points, scene.normals)
        lit = np.any(value > 0, axis=1)
        if not light.casts_shadow or not lit.any():
            out += value
            continue
        pts, nrm, ids = scene.points[lit], scene.normals[lit], point_ids[lit]
        if light.kind == "SUN":
            vis = _sun_visibility(scene, renderer, settings, light, pts, nrm, ids)
        elif light.kind == "AREA":
            vis = _area_visibility(scene, renderer, settings, light, pts, nrm, ids, near, far)
        else:
            cap = capture_cubes(renderer, light.position[None], settings.shadow_size, near, far)
            vis = lights_mod.shadow_visibility(
                pts, nrm, light.position, cap.tid[0], cap.dist[0], cap.backface[0], scene.triangles, scene.points, ids, scale
            )
        value[lit] *= vis[:, None]
        out += value
    return out


def _sun_visibility(scene, renderer, settings, light, pts, nrm, ids):
    lo, hi = scene.bounds()
    centre, radius = 0.5 * (lo + hi), 0.5 * scene.scale * 1.01
    axis = light.direction / np.linalg.norm(light.direction)
    eye = centre - axis * radius * 2.0
    view = cubemap.look_matrix(eye, axis, cubemap.any_perpendicular(axis))
    vp = cubemap.orthographic(radius, 1e-3 * radius, 4.0 * radius) @ view
    n = settings.sun_shadow_size
    tid, _, dist, back = renderer.render(vp[None], eye[None], axis[None], n)
    return lights_mod.ortho_visibility(
        pts, nrm, vp, axis, eye, tid[0], dist[0], back[0], scene.triangles, scene.points, ids, radius, scene.scale
    )


def _area_visibility(scene, renderer, settings, light, pts, nrm, ids, near, far):
    samples = light.samples if light.samples is not None and len(light.samples) else light.position[None]
    # Lift the samples off the light's plane a little so the light's own geometry (if any)
    # and surfaces it rests on do not shadow it.
    eyes = samples + light.direction * (1e-4 * scene.scale)
    cap = capture_cubes(renderer, eyes, settings.area_shadow_size, near, far)
    num = np.zeros(len(pts))
    den = np.zeros(len(pts))
    for k, eye in enumerate(eyes):
        rel = eye - pts
        d2 = np.einsum("sc,sc->s", rel, rel)
        cos_r = np.maximum(0.0, np.einsum("sc,sc->s", nrm, rel)) / np.sqrt(np.maximum(d2, 1e-300))
        cos_l = np.maximum(0.0, -(rel @ light.direction)) / np.sqrt(np.maximum(d2, 1e-300))
        w = cos_r * cos_l / np.maximum(d2, 1e-300) + 1e-12
        vis = lights_mod.shadow_visibility(
            pts, nrm, eye, cap.tid[k], cap.dist[k], cap.backface[k], scene.triangles, scene.points, ids, scene.scale,
            reach=0,
        )
        num += w * vis
        den += w
    return num / den


# Bytes per cube-map texel while a bake runs: the capture (triangle, barycentrics, distance,
# back-face flag), the gather tables (corners, weights) and the gather's temporaries.
BYTES_PER_TEXEL = 80
BYTES_PER_POINT = 8 * 8 * 9 * 4 + 400  # interpolation weights and per-point arrays


# Energy factors are kept within this range: a bounce that needs more is left as it is
# bigger than any sampling error, so something else is wrong (and the factor is reported).
ENERGY_FACTOR_RANGE = (0.5, 2.0)


def conserve_energy(light, radiance, landing, areas):
    """Scale ``light`` so that the power it brings equals the power sent that lands.

    Every bit of light a surface sends lands on a surface or leaves through the sky. In
    CubeGI's units (diffuse light l = E / pi, radiance B) that is, per colour channel,
    ``sum_j A_j l_j = sum_i A_i B_i (1 - sky_i)``, with sky_i the cosine-weighted share of
    the sky seen from point i. Probe interpolation, texel sampling and SH truncation each
    move a bounce's total a little off this (measured: 0.1-1% per bounce), and in a
    closed room of albedo rho that error is amplified by about 1 / (1 - rho). The scale
    keeps where the light lands as interpolated and fixes how much lands.

    light: ``(s, 3)`` received; radiance: ``(s, 3)`` sent; landing: ``(s, 3)`` 1 - sky_i;
    areas: ``(s,)``. Returns ``(light, factor (3,))``.
    """
    target = (areas[:, None] * radiance * landing).sum(axis=0)
    got = (areas[:, None] * light).sum(axis=0)
    factor = np.ones(3)
    ok = (got > 0) & (target > 0)
    factor[ok] = target[ok] / got[ok]
    lo, hi = ENERGY_FACTOR_RANGE
    factor = np.where((factor >= lo) & (factor <= hi), factor, 1.0)
    return light * factor, factor


def memory_estimate(probes, cube_size, points):
    """Bytes a bake of ``probes`` cube maps of ``cube_size`` over ``points`` needs, roughly."""
    return int(probes) * 6 * int(cube_size) ** 2 * BYTES_PER_TEXEL + int(points) * BYTES_PER_POINT


def physical_memory():
    """This machine's memory in bytes (None where it cannot be told)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(probes, cube_size, points, limit=None):
    """Refuse, with the estimate, a bake that would need more than half the memory."""
    need = memory_estimate(probes, cube_size, points)
    total = limit if limit is not None else physical_memory()
    if total and need > 0.5 * total:
        raise ValueError(
            f"{probes} probes at {cube_size}x{cube_size} would need about {need / 2**30:.1f} GiB, more than half of "
            f"this machine's {total / 2**30:.1f} GiB; use fewer probes or a smaller cube-map size"
        )
    return need


def bake_steps(scene, grid, renderer, settings=None):
    """Bake ``scene`` on ``grid``; a generator of :class:`Progress`, returning a BakeResult."""
    settings = settings or BakeSettings()
    settings.validate()
    check_memory(grid.count, settings.cube_size, len(scene.points))
    t_start = time.perf_counter()
    timings = {}
    total = 3 + settings.bounces
    areas = scene.point_areas()
    near, far = clip_planes(scene.scale)

    yield Progress("capture", 0, total, f"capturing {grid.count} probes at {settings.cube_size}x{settings.cube_size}")
    t = time.perf_counter()
    capture = capture_cubes(renderer, grid.positions(), settings.cube_size, near, far)
    timings["capture"] = time.perf_counter() - t

    t = time.perf_counter()
    transport = Transport(scene, grid, capture, visibility=settings.visibility)
    timings["tables"] = time.perf_counter() - t

    yield Progress("direct", 1, total, f"direct light from {len(scene.lights)} lights")
    t = time.perf_counter()
    direct = direct_from_lights(scene, renderer, settings)
    timings["direct_lights"] = time.perf_counter() - t
    t = time.perf_counter()
    # Light reaching a point straight from emissive surfaces or the sky is direct (as in
    # Cycles); it comes through the probes.
    probe_coeffs = np.zeros((grid.count, 9, 3), dtype=np.float32)
    landing = transport.landing_share() if settings.conserve_energy else None
    emitter_factor = np.ones(3)
    if np.any(scene.emission > 0):
        probe_coeffs = transport.project(transport.texel_radiance(scene.emission))
        from_emitters = scene.darken(transport.interpolate(probe_coeffs).astype(np.float64))
        if landing is not None:
            from_emitters, emitter_factor = conserve_energy(from_emitters, scene.emission, landing, areas)
        direct = direct + from_emitters
    if np.any(scene.sky > 0):
        sky_coeffs = transport.sky_coefficients(scene.sky)
        probe_coeffs = probe_coeffs + sky_coeffs
        direct = direct + transport.interpolate(sky_coeffs)
    scene.darken(direct)
    timings["direct_probes"] = time.perf_counter() - t
    timings["direct"] = timings["direct_lights"] + timings["direct_probes"]
    yield Progress("direct", 2, total, "direct light done", light=direct)

    bounces, records = [], []
    albedo = scene.albedo.astype(np.float32)
    light_sum = direct.copy()
    previous, previous_mean = direct, area_weighted_mean(direct, areas)
    coeffs = None
    indirect_mean = np.zeros(3)
    remaining = 1.0 if np.any(direct > 0) else 0.0
    cap = settings.bounces
    for b in range(1, cap + 1):
        t0 = time.perf_counter()
        texels = transport.texel_radiance(albedo * previous)
        t1 = time.perf_counter()
        coeffs = transport.project(texels)
        probe_coeffs = probe_coeffs + coeffs
        t2 = time.perf_counter()
        light = scene.darken(transport.interpolate(coeffs).astype(np.float64))
        factor = np.ones(3)
        if landing is not None:
            light, factor = conserve_energy(light, albedo * previous, landing, areas)
        t3 = time.perf_counter()
        mean = area_weighted_mean(light, areas)
        ratio = convergence.ratios(previous_mean, mean)
        light_sum = light_sum + light
        indirect_mean = indirect_mean + mean
        remaining = convergence.remaining_share(indirect_mean, mean, ratio)
        records.append(
            {
                "bounce": b,
                "seconds": t3 - t0,
                "gather_seconds": t1 - t0,
                "project_seconds": t2 - t1,
                "interpolate_seconds": t3 - t2,
                "mean_light": mean.tolist(),
                "mean": float(mean.mean()),
                "ratio": ratio.tolist(),
                "ratio_mean": float(mean.sum() / previous_mean.sum()) if previous_mean.sum() > 0 else 0.0,
                "estimated_remaining": remaining,
                "energy_factor": factor.tolist(),
            }
        )
        bounces.append(light)
        previous, previous_mean = light, mean
        yield Progress(
            "bounce", 2 + b, total,
            f"bounce {b}/{cap}: mean light {mean.mean():.4g}, x{records[-1]['ratio_mean']:.3f} of the bounce before, "
            f"about {100 * remaining:.3g}% of the indirect light still missing",
            light=light_sum,
        )
        if settings.tolerance is not None and remaining < settings.tolerance:
            break

    timings["bounces"] = sum(r["seconds"] for r in records)
    t = time.perf_counter()
    tail = _tail(transport, albedo, coeffs, bounces, records, remaining, areas, settings)
    if tail["light"] is not None:
        scene.darken(tail["light"])
    timings["tail"] = time.perf_counter() - t
    result = BakeResult(
        direct, bounces, timings, records, grid, transport.probe_valid, tail["light"], tail["report"], probe_coeffs,
        transport.seen_from_behind, emitter_factor,
    )
    if tail["report"]["added"]:
        yield Progress(
            "tail", total, total,
            f"light after bounce {len(bounces)} {tail['report']['method']}: "
            f"{100 * tail['report']['share_of_indirect']:.2g}% of the indirect light, added",
            light=direct + result.indirect,
        )
    timings["total"] = time.perf_counter() - t_start
    return result


def _tail(transport, albedo, last_coeffs, bounces, records, remaining, areas, settings):
    """The light after the last bounce: estimated, solved for, or left out (see convergence)."""
    report = {"estimated_remaining": remaining, "method": "none", "added": False, "warning": None}
    if not bounces:
        return {"light": None, "report": report}
    ratio = np.asarray(records[-1]["ratio"])
    last = bounces[-1]
    if not convergence.converges(ratio):
        report["warning"] = (
            f"the bounces do not converge: each keeps {100 * float(ratio.max()):.2f}% of the light before "
            f"(albedo 1 in a closed room?); stopped at {len(bounces)} bounces and no tail is added"
        )
        report["estimated_remaining"] = 1.0
        return {"light": None, "report": report}
    if remaining <= 0.0:
        return {"light": None, "report": report}
    if remaining <= convergence.GEOMETRIC_TAIL_LIMIT:
        light = convergence.geometric_tail(last, ratio)
        report["method"] = "geometric"
    else:
        factor = np.asarray(records[-1]["energy_factor"])
        light, iterations, residual = _solve_tail(transport, albedo, last_coeffs, settings.solve_tolerance, factor)
        report.update(method="solved", iterations=iterations, relative_residual=residual)
        if not residual <= SOLVE_GIVE_UP:
            report["warning"] = f"the tail solve stopped at relative residual {residual:.2g}; no tail is added"
            return {"light": None, "report": report}
    light = np.maximum(np.nan_to_num(light, nan=0.0, posinf=0.0, neginf=0.0), 0.0)
    report["mean_light"] = area_weighted_mean(light, areas).tolist()
    indirect_mean = float(sum(r["mean"] for r in records))
    tail_mean = float(np.mean(report["mean_light"]))
    report["share_of_indirect"] = tail_mean / (indirect_mean + tail_mean) if indirect_mean + tail_mean > 0 else 0.0
    report["added"] = bool(settings.add_tail)
    return {"light": light, "report": report}


def _solve_tail(transport, albedo, coeffs, tol, factor):
    """``sum_{k>N} T^k d`` from bounce N's probe coefficients, by GMRES on (I - M).

    ``factor`` ``(3,)``: the last bounce's energy factor, applied to every further bounce
    (by then the light's distribution, and so its factor, has settled)."""
    shape = coeffs.shape
    f = np.asarray(factor, dtype=np.float64)

    def bounce(c):
        light = transport.interpolate(c.reshape(shape).astype(np.float32), clamp=False) * f.astype(np.float32)
        return transport.project(transport.texel_radiance(albedo * light)).astype(np.float64).ravel()

    first = bounce(coeffs.astype(np.float64).ravel())  # c_{N+1}
    total, iterations, residual = convergence.gmres(lambda x: x - bounce(x), first, tol=tol)
    light = transport.interpolate(total.reshape(shape).astype(np.float32), clamp=False) * f
    return light.astype(np.float64), iterations, residual


def run(steps, progress=None):
    """Drain a generator of :class:`Progress`, calling ``progress`` on each; return its result."""
    while True:
        try:
            step = next(steps)
        except StopIteration as stop:
            return stop.value
        if progress is not None:
            progress(step)
