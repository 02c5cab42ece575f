"""The bounces of one source's direct light on a kept capture: a :class:`LightSolution`.

Pure numpy; must not import bpy.

Bounce k's light is ``T^k d`` for the direct light ``d`` and the bounce operator ``T``
(gather, project, interpolate, times albedo; :class:`cubegi_engine.transport.Transport`).
:func:`solve_steps` runs the series of :mod:`cubegi_engine.series` over the capture's tables
(:class:`TableOperator`) until the cap or the tolerance, gathering each bounce once more
with its near field, then adds the rest of the series (the tail, see
:mod:`cubegi_engine.convergence`). Everything here is linear in ``d`` but for the energy
balance (one factor per bounce and channel, a ratio of totals) and the clamps, so the
solution of a sum of sources is the sum of their solutions up to that balance
(relighting, :mod:`cubegi_engine.relight`, runs the same series on dense matrices).
"""

import time
from dataclasses import dataclass, field

import numpy as np

from . import convergence
from .records import BounceRecord, Progress, Stage, TailReport
from .series import Bounce, area_weighted_mean, bounce_series, conserve_energy, landed_power, near_factor, tail_sum
from .settings import BakeSettings
from .working import checkpoint, in_background

__all__ = ["LightSolution", "TableOperator", "solve_steps", "near_field_balanced", "SOLVE_GIVE_UP",
           "area_weighted_mean", "conserve_energy"]

# A tail solve that ends with a larger relative residual than this is not trusted.
SOLVE_GIVE_UP = 1e-2


class TableOperator:
    """The bake's :class:`~cubegi_engine.series.BounceOperator`: a bounce through the
    capture's tables (:meth:`Transport.gather_project`, :meth:`Transport.interpolate`), no
    matrix formed. Each bounce's light is interpolated at every point (deringed, clamped at
    zero, dark points zero: :meth:`bounce_light`); ``landing`` ``(s, 3)`` None: no balance.
    ``gather_seconds``: the time of the last :meth:`first` or :meth:`apply`."""

    def __init__(self, scene, transport, albedo, areas, landing=None):
        self.scene, self.transport, self.albedo, self.areas, self.landing = scene, transport, albedo, areas, landing
        self.gather_seconds, self._linear = 0.0, None

    def _gather(self, radiance):
        t = time.perf_counter()
        out = self.transport.gather_project(radiance)
        self.gather_seconds = time.perf_counter() - t
        return out

    def first(self, direct):
        return self._gather(self.albedo * direct)

    def bounce_light(self, coeffs):
        return self.scene.zero_dark_points_inplace(self.transport.interpolate(coeffs).astype(np.float64))

    def total(self, coeffs, light):
        return (self.areas[:, None] * light).sum(axis=0)

    def landed(self, coeffs, light):
        return landed_power(self.albedo * light, self.landing, self.areas)

    def apply(self, coeffs, light):
        return self._gather(self.albedo * light)

    def linear(self, coeffs, factor):
        if self._linear is None:  # made on the first call (the tail's), kept for the solve
            self._linear = self.transport.linear_gather(self.albedo)
        return self._linear(coeffs.astype(np.float32)).astype(np.float64) * np.asarray(factor, dtype=np.float64)


def near_field_balanced(light, before, areas, unseen=None):
    """``light (s, 3)`` (a bounce's light gathered with the near field) scaled per channel
    down to the area-weighted total of ``before`` (its probe light) where it is above it,
    never up (:func:`~cubegi_engine.series.near_factor`). ``unseen (s,)``: points no probe
    sees (a ceiling 1 cm above a lamp), whose near-field light the balance knows nothing of:
    neither counted nor scaled (the light trapped in a gap)."""
    weights = areas if unseen is None else areas * ~unseen
    out = light * near_factor((weights[:, None] * before).sum(axis=0), (weights[:, None] * (light - before)).sum(axis=0))
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

    The series is :func:`~cubegi_engine.series.bounce_series` over a :class:`TableOperator`;
    each bounce's light is gathered once more with its near field. ``landing``: ``(s, 3)``
    the share of each point's view that is surface (:meth:`Transport.landing_share`), for
    the energy balance; None skips the balance. ``first_step``/``total_steps``: where these
    steps sit in the whole bake's count.
    """
    settings = settings or BakeSettings()
    total = total_steps if total_steps is not None else first_step + settings.bounces + 1
    areas = scene.point_areas()
    albedo = scene.sent_on().astype(np.float32)
    op = TableOperator(scene, transport, albedo, areas, landing)
    series = bounce_series(op, direct, balanced=landing is not None)
    bounces, records = [], []
    light_sum = direct.copy()
    previous_mean = area_weighted_mean(direct, areas)
    last = None
    bounce_coeffs = np.zeros((transport.probe_count, 9, 3), dtype=np.float32)
    indirect_mean = np.zeros(3)
    remaining = 1.0 if np.any(direct > 0) else 0.0
    cap = settings.bounces
    seen_before = direct  # the light last gathered: the near field gathers from it

    def working(b):
        return Progress(Stage.BOUNCE, first_step + b - 1, total, f"bounce {b}/{cap}", working=True)

    for b in range(1, cap + 1):
        t0 = time.perf_counter()
        last, gathered = yield from in_background(_one_bounce, working(b), series, scene, transport, albedo, areas, landing,
                                                  seen_before)
        light, t1 = last.light, t0 + op.gather_seconds
        bounce_coeffs = bounce_coeffs + last.balanced
        t3 = time.perf_counter()
        mean = area_weighted_mean(light, areas)
        ratio = convergence.ratios(previous_mean, mean)
        light_sum = light_sum + gathered
        indirect_mean = indirect_mean + mean
        remaining = convergence.remaining_share(indirect_mean, mean, ratio)
        record = BounceRecord(
            bounce=b, seconds=t3 - t0, gather_seconds=t1 - t0, interpolate_seconds=t3 - t1,
            mean_light=mean.tolist(), mean=float(mean.mean()), ratio=ratio.tolist(),
            ratio_mean=float(mean.sum() / previous_mean.sum()) if previous_mean.sum() > 0 else 0.0,
            estimated_remaining=remaining, energy_factor=last.factor.tolist(),
        )
        records.append(record)
        bounces.append(gathered)
        seen_before = gathered
        previous_mean = mean
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
        return _tail_with_near_field(op, last, bounces, records, remaining, areas, settings, seen_before, landing is not None)

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


def _tail_with_near_field(op, last, bounces, records, remaining, areas, settings, seen_before, balanced):
    """:func:`_tail`, with the near field's rows summed to the end (:func:`_near_tail`).
    A geometric tail's probes are the last bounce's at the same ratio. The near field's own
    series converges slower where a point is closed in by white surfaces (a white teapot's
    inside: 0.93 of its view, albedo 1): a few bounces and the scene's ratio miss most of it."""
    tail, tail_coeffs, report = _tail(op, last, bounces, records, remaining, areas, settings)
    transport = op.transport
    if tail is not None and transport.near is not None and transport.near.count:
        coeffs = tail_coeffs if tail_coeffs is not None else (
            last.balanced * convergence.geometric_factor(np.asarray(records[-1].ratio))[None, None, :]).astype(np.float32)
        tail = _near_tail(transport, tail, coeffs, op.albedo, seen_before, areas, balanced)
    return tail, tail_coeffs, report


def _one_bounce(series, scene, transport, albedo, areas, landing, seen_before) -> tuple[Bounce, np.ndarray]:
    """The series' next bounce, and its light gathered once more with the near field from
    ``seen_before`` (the light last gathered), its total kept where the bake is balanced
    (``landing`` not None): ``(bounce, gathered (s, 3))``."""
    bounce = next(series)
    checkpoint()  # (a cancelled bake's bounce stops here)
    near, light = transport.near, bounce.light
    if near is None:
        return bounce, light
    part = transport.near_part(bounce.balanced, light)
    gathered = scene.zero_dark_points_inplace(near.correct(light, part, albedo * seen_before))
    if landing is not None:
        gathered = near_field_balanced(gathered, light, areas, transport.exact)
    return bounce, gathered


def _near_tail(transport, tail, tail_coeffs, albedo, seen_before, areas, balanced):
    """A solved tail with its near field summed to the end (and its total kept where the
    bake is ``balanced``)."""
    near = transport.near
    part = transport.near_part(tail_coeffs, tail)
    fixed = near.correct_sum(tail, part, albedo, seen_before)
    return near_field_balanced(fixed, tail, areas, transport.exact) if balanced else fixed


def _tail(op, last: Bounce | None, bounces, records, remaining, areas, settings):
    """The light after the last bounce: ``(light or None, coeffs or None, TailReport)``
    (estimated, solved for, or left out; see :mod:`convergence`)."""
    report = TailReport(estimated_remaining=remaining)
    if not bounces or last is None:
        return None, None, report
    ratio = np.asarray(records[-1].ratio)
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
        light = convergence.geometric_tail(bounces[-1], ratio)
        report.method = "geometric"
    else:
        rest = tail_sum(op, last.coeffs, last.factor, settings.solve_tolerance)
        light = op.transport.interpolate(rest.coeffs.astype(np.float32), clamp=False) * rest.factor
        coeffs = rest.balanced.astype(np.float32)
        report.method, report.iterations, report.relative_residual = "solved", rest.iterations, rest.residual
        if not rest.residual <= SOLVE_GIVE_UP:
            report.warning = f"the tail solve stopped at relative residual {rest.residual:.2g}; no tail is added"
            return None, None, report
    light = np.maximum(np.nan_to_num(light, nan=0.0, posinf=0.0, neginf=0.0), 0.0)
    report.mean_light = area_weighted_mean(light, areas).tolist()
    indirect_mean = float(sum(r.mean for r in records))
    tail_mean = float(np.mean(report.mean_light))
    report.share_of_indirect = tail_mean / (indirect_mean + tail_mean) if indirect_mean + tail_mean > 0 else 0.0
    report.added = bool(settings.add_tail)
    return light, coeffs, report
