"""The bounces of one source's direct light on a kept capture: a :class:`LightSolution`.

Pure numpy; must not import bpy.

Bounce k's light is ``T^k d`` for the direct light ``d`` and the bounce operator ``T``
(gather, project, interpolate, times albedo; :class:`cubegi_engine.transport.Transport`).
:func:`solve_steps` runs the bounces until the cap or the tolerance, then adds the rest of
the series (the tail, see :mod:`cubegi_engine.convergence`). Everything here is linear in
``d`` but for the energy balance (one factor per bounce and channel, a ratio of totals),
so the solution of a sum of sources is the sum of their solutions up to that balance.
"""

import time
from dataclasses import dataclass, field

import numpy as np

from . import convergence
from .records import BounceRecord, Progress, Stage, TailReport
from .settings import BakeSettings
from .working import in_background

__all__ = ["LightSolution", "solve_steps", "conserve_energy", "energy_factor", "area_weighted_mean", "ENERGY_FACTOR_RANGE",
           "SOLVE_GIVE_UP"]

# A tail solve that ends with a larger relative residual than this is not trusted.
SOLVE_GIVE_UP = 1e-2
# Energy factors are kept within this range: a bounce that needs more is left as it is
# bigger than any sampling error, so something else is wrong (and the factor is reported).
ENERGY_FACTOR_RANGE = (0.5, 2.0)


def area_weighted_mean(values: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """Area-weighted mean of ``values (s, 3)``: ``(3,)``."""
    total = float(areas.sum())
    if total <= 0.0:
        return np.zeros(values.shape[1:])
    return (values * areas[:, None]).sum(axis=0) / total


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
    factor = energy_factor(target, got)
    return light * factor, factor


def energy_factor(target, got):
    """The energy balance's one rule: per channel ``target / got`` of two totals ``(3,)``,
    1 where either is not positive or the factor lies outside ENERGY_FACTOR_RANGE (a total
    that far off is not a bounce's small error but something the balance must not hide).
    Every balance (a bake's bounces, the near field's, relighting's) takes its factor here."""
    target, got = np.asarray(target, dtype=np.float64), np.asarray(got, dtype=np.float64)
    factor = np.ones(3)
    ok = (got > 0) & (target > 0)
    factor[ok] = target[ok] / got[ok]
    lo, hi = ENERGY_FACTOR_RANGE
    return np.where((factor >= lo) & (factor <= hi), factor, 1.0)


def keep_total(light, before, areas, unseen=None):
    """``light (s, 3)`` scaled per channel to the area-weighted total of ``before``: the near
    field moves where a bounce's light lands, the energy balance has said how much lands.
    ``unseen (s,)``: points no probe sees (a ceiling 1 cm above a lamp), whose near-field light
    the balance knows nothing of: neither counted nor scaled (the light trapped in a gap)."""
    weights = areas if unseen is None else areas * ~unseen
    out = light * energy_factor((weights[:, None] * before).sum(axis=0), (weights[:, None] * light).sum(axis=0))
    if unseen is not None:
        out[unseen] = light[unseen]
    return out


@dataclass
class LightSolution:
    """The indirect light of one direct light on one capture.

    direct: ``(s, 3)`` the direct light it starts from; bounces: one ``(s, 3)`` per bounce;
    tail: ``(s, 3)`` the light after the last bounce, when estimated (``tail_report.added``
    says whether it counts); bounce_coeffs: ``(p, 9, 3)`` SH radiance the probes see of
    the bounced light (each bounce as balanced), summed over the bounces; tail_coeffs: the same for the tail, when
    it was solved in probe space (else None).
    """

    direct: np.ndarray
    bounces: list = field(default_factory=list)
    records: list = field(default_factory=list)  # BounceRecord per bounce
    tail: np.ndarray | None = None
    tail_report: TailReport = field(default_factory=lambda: TailReport(0.0))
    bounce_coeffs: np.ndarray | None = None
    tail_coeffs: np.ndarray | None = None

    @property
    def bounce_sum(self) -> np.ndarray:
        if not self.bounces:
            return np.zeros_like(self.direct)
        out = np.array(self.bounces[0], dtype=np.result_type(*self.bounces))  # in order, as np.sum over a stack adds them
        for bounce in self.bounces[1:]:
            out += bounce
        return out

    @property
    def indirect(self) -> np.ndarray:
        """The indirect light: the bounces, plus the tail when it is to be added."""
        if self.tail is not None and self.tail_report.added:
            return self.bounce_sum + self.tail
        return self.bounce_sum

    @property
    def total(self) -> np.ndarray:
        return self.direct + self.indirect


def solve_steps(scene, transport, direct, settings: BakeSettings | None = None, landing=None, first_step=2, total_steps=None):
    """Bounce ``direct (s, 3)`` on ``transport``: a generator of :class:`Progress` (one per
    bounce, and the tail when added), returning a :class:`LightSolution`.

    ``landing``: ``(s, 3)`` the share of each point's view that is surface
    (:meth:`Transport.landing_share`), for the energy balance; None skips the balance.
    ``first_step``/``total_steps``: where these steps sit in the whole bake's count.
    """
    settings = settings or BakeSettings()
    total = total_steps if total_steps is not None else first_step + settings.bounces + 1
    areas = scene.point_areas()
    albedo = scene.albedo.astype(np.float32)
    bounces, records = [], []
    light_sum = direct.copy()
    previous, previous_mean = direct, area_weighted_mean(direct, areas)
    coeffs = None
    bounce_coeffs = np.zeros((transport.probe_count, 9, 3), dtype=np.float32)
    indirect_mean = np.zeros(3)
    remaining = 1.0 if np.any(direct > 0) else 0.0
    cap = settings.bounces
    near = transport.near  # each bounce's light is gathered once more with its near field
    seen_before = direct

    def working(b):
        return Progress(Stage.BOUNCE, first_step + b - 1, total, f"bounce {b}/{cap}", working=True)

    for b in range(1, cap + 1):
        t0 = time.perf_counter()
        coeffs, light, factor, gathered, t_gather = yield from in_background(
            _one_bounce, working(b), scene, transport, albedo, areas, landing, previous, seen_before)
        t1 = t2 = t0 + t_gather
        bounce_coeffs = bounce_coeffs + coeffs * factor.astype(np.float32)  # as balanced
        t3 = time.perf_counter()
        mean = area_weighted_mean(light, areas)
        ratio = convergence.ratios(previous_mean, mean)
        light_sum = light_sum + gathered
        indirect_mean = indirect_mean + mean
        remaining = convergence.remaining_share(indirect_mean, mean, ratio)
        record = BounceRecord(
            bounce=b, seconds=t3 - t0, gather_seconds=t1 - t0, project_seconds=t2 - t1, interpolate_seconds=t3 - t2,
            mean_light=mean.tolist(), mean=float(mean.mean()), ratio=ratio.tolist(),
            ratio_mean=float(mean.sum() / previous_mean.sum()) if previous_mean.sum() > 0 else 0.0,
            estimated_remaining=remaining, energy_factor=factor.tolist(),
        )
        records.append(record)
        bounces.append(gathered)
        seen_before = gathered
        previous, previous_mean = light, mean
        yield Progress(
            Stage.BOUNCE, first_step + b, total,
            f"bounce {b}/{cap}: mean light {mean.mean():.4g}, x{record.ratio_mean:.3f} of the bounce before, "
            f"about {100 * remaining:.3g}% of the indirect light still missing",
            light=light_sum, new_light=gathered, bounce=b,
        )
        if settings.tolerance is not None and remaining < settings.tolerance:
            break
        if not np.any(light > 0):  # nothing left to bounce: further bounces are all zero
            break

    def the_tail():
        tail, tail_coeffs, report = _tail(transport, albedo, coeffs, bounces, records, remaining, areas, settings)
        if tail is not None and tail_coeffs is not None and near is not None:  # a solved tail: its near field too
            tail = _near_tail(transport, tail, tail_coeffs, albedo, seen_before, areas, landing is not None)
        return tail, tail_coeffs, report

    tail, tail_coeffs, report = yield from in_background(
        the_tail, Progress(Stage.TAIL, total - 1, total, "the light after the last bounce", working=True))
    if tail is not None:
        scene.zero_dark_points_inplace(tail)
    solution = LightSolution(direct, bounces, records, tail, report, bounce_coeffs, tail_coeffs)
    if report.added:
        yield Progress(
            Stage.TAIL, total, total,
            f"light after bounce {len(bounces)} {report.method}: {100 * report.share_of_indirect:.2g}% of the indirect light, added",
            light=solution.total, new_light=tail,
        )
    return solution


def _one_bounce(scene, transport, albedo, areas, landing, previous, seen_before):
    """The next bounce of ``previous (s, 3)`` (the near field gathers ``seen_before``, the
    light last gathered): ``(coeffs, light, factor, gathered, seconds of the gather)``;
    ``landing`` None skips the energy balance."""
    near = transport.near
    t0 = time.perf_counter()
    coeffs = transport.gather_project(albedo * previous)
    t1 = time.perf_counter()
    light = scene.zero_dark_points_inplace(transport.interpolate(coeffs).astype(np.float64))
    factor = np.ones(3)
    if landing is not None:
        light, factor = conserve_energy(light, albedo * previous, landing, areas)
    gathered = light
    if near is not None:
        gathered = scene.zero_dark_points_inplace(near.correct(
            light, transport.interpolate_rows(coeffs * factor.astype(np.float32), near.rows, near.open_basis), albedo * seen_before))
        if landing is not None:
            gathered = keep_total(gathered, light, areas, transport.covered)
    return coeffs, light, factor, gathered, t1 - t0


def _near_tail(transport, tail, tail_coeffs, albedo, seen_before, areas, balanced):
    """A solved tail with its near field summed to the end (and its total kept where the
    bake is ``balanced``)."""
    near = transport.near
    part = transport.interpolate_rows(tail_coeffs, near.rows, near.open_basis)
    fixed = near.correct_sum(tail, part, albedo, seen_before)
    return keep_total(fixed, tail, areas, transport.covered) if balanced else fixed


def _tail(transport, albedo, last_coeffs, bounces, records, remaining, areas, settings):
    """The light after the last bounce: ``(light or None, coeffs or None, TailReport)``
    (estimated, solved for, or left out; see :mod:`convergence`)."""
    report = TailReport(estimated_remaining=remaining)
    if not bounces:
        return None, None, report
    ratio = np.asarray(records[-1].ratio)
    last = bounces[-1]
    if not convergence.converges(ratio):
        report.warning = (
            f"the bounces do not converge: each keeps {100 * float(ratio.max()):.2f}% of the light before "
            f"(albedo 1 in a closed room?); stopped at {len(bounces)} bounces and no tail is added"
        )
        report.estimated_remaining = 1.0
        return None, None, report
    if remaining <= 0.0:
        return None, None, report
    coeffs = None
    if remaining <= convergence.GEOMETRIC_TAIL_LIMIT:
        light = convergence.geometric_tail(last, ratio)
        report.method = "geometric"
    else:
        factor = np.asarray(records[-1].energy_factor)
        light, coeffs, iterations, residual = _solve_tail(transport, albedo, last_coeffs, settings.solve_tolerance, factor)
        report.method, report.iterations, report.relative_residual = "solved", iterations, residual
        if not residual <= SOLVE_GIVE_UP:
            report.warning = f"the tail solve stopped at relative residual {residual:.2g}; no tail is added"
            return None, None, report
    light = np.maximum(np.nan_to_num(light, nan=0.0, posinf=0.0, neginf=0.0), 0.0)
    report.mean_light = area_weighted_mean(light, areas).tolist()
    indirect_mean = float(sum(r.mean for r in records))
    tail_mean = float(np.mean(report.mean_light))
    report.share_of_indirect = tail_mean / (indirect_mean + tail_mean) if indirect_mean + tail_mean > 0 else 0.0
    report.added = bool(settings.add_tail)
    return light, coeffs, report


def _solve_tail(transport, albedo, coeffs, tol, factor):
    """``sum_{k>N} T^k d`` from bounce N's probe coefficients, by GMRES on (I - M).

    ``factor`` ``(3,)``: the last bounce's energy factor, applied to every further bounce
    (by then the light's distribution, and so its factor, has settled). Returns the light
    ``(s, 3)``, the probe coefficients of the bounces it sums (``(p, 9, 3)``), iterations
    and relative residual."""
    shape = coeffs.shape
    f = np.asarray(factor, dtype=np.float64)

    def bounce(c):
        light = transport.interpolate(c.reshape(shape).astype(np.float32), clamp=False) * f.astype(np.float32)
        return transport.gather_project(albedo * light).astype(np.float64).ravel()

    first = bounce(coeffs.astype(np.float64).ravel())  # c_{N+1}
    total, iterations, residual = convergence.gmres(lambda x: x - bounce(x), first, tol=tol)
    light = transport.interpolate(total.reshape(shape).astype(np.float32), clamp=False) * f
    return light.astype(np.float64), (total.reshape(shape) * f).astype(np.float32), iterations, residual
