"""The bounce series, written once: the bake and every update run it.

Pure numpy; must not import bpy.

In probe-coefficient space, with ``K`` the gather and projection (points' radiance to the
probes' SH coefficients), ``A`` the albedo and ``I`` the interpolation (coefficients to the
points' diffuse light), the bounces of a direct light ``d`` are

    c_1 = K A d,   b_k = g_k c_k (bounce k, balanced),   c_{k+1} = K A I b_k,
    the tail after bounce N:  sum_{j>N} = (1 - g_N M)^-1 g_N M b_N ... = g_N x,
    (1 - g_N M) x = M b_N,   M = K A I,

``g_k`` the energy balance's factor of bounce k (:func:`energy_factor`: the power bounce k
brings equals the power bounce k-1 sent that lands). :func:`bounce_series` is that
recurrence and :func:`tail_sum` that solve, over a :class:`BounceOperator`. Two operators
implement it: the bake's, over the capture's tables without forming a matrix
(:class:`cubegi_engine.solve.TableOperator`, which interpolates each bounce's light at every
point on the way (its ``bounce_light``), clamped against the ringing of low-order SH), and relighting's dense
matrices (:class:`cubegi_engine.relight.MatrixOperator`, linear: a sum of sources is the sum
of their series), its fast path for many small solves. The near field's final gather of
each bounce (:meth:`cubegi_engine.nearfield.NearField.delta` and ``settle``) is balanced
by :func:`near_factor`, for both.
"""

from dataclasses import dataclass
from typing import Iterator, Protocol

import numpy as np

from .convergence import gmres

__all__ = ["BounceOperator", "Bounce", "TailSum", "bounce_series", "tail_sum", "energy_factor", "near_factor",
           "area_weighted_mean", "conserve_energy", "ENERGY_FACTOR_RANGE"]

# Energy factors are kept within this range: a bounce that needs more is left as it is
# bigger than any sampling error, so something else is wrong (and the factor is reported).
ENERGY_FACTOR_RANGE = (0.5, 2.0)


def energy_factor(target, got) -> np.ndarray:
    """The energy balance's one rule: per channel ``target / got`` of two totals ``(3,)``,
    1 where either is not positive or the factor lies outside ENERGY_FACTOR_RANGE (a total
    that far off is not a bounce's small error but something the balance must not hide).
    Every balance (a bake's bounces, the near field's, the emitters', relighting's) takes
    its factor here."""
    target, got = np.asarray(target, dtype=np.float64), np.asarray(got, dtype=np.float64)
    factor = np.ones(3)
    ok = (got > 0) & (target > 0)
    factor[ok] = target[ok] / got[ok]
    lo, hi = ENERGY_FACTOR_RANGE
    return np.where((factor >= lo) & (factor <= hi), factor, 1.0)


def near_factor(probe_total, added_total) -> np.ndarray:
    """The near field's balance: it moves where a bounce's light lands, the energy balance
    has said how much lands, so light the near field adds is scaled back down to the
    probes' total (both ``(3,)``, area-weighted over the points a probe sees).

    Never up: where the near field takes light away (the contact and corner shadows of
    concave edges) the points' total is rightly below the probes'. A point's light is its
    value at the point, and a vertex on a room's edge has its edge's shadow, which covers
    a strip much narrower than the vertex's share of the surface: vertices sample less than
    the light that lands on their areas (Cycles' own per-vertex bake of the thin wall scene:
    indirect / direct light 3.91, 3.96 and 3.98 at 1x, 2x and 4x the vertices, the albedo's
    rho / (1 - rho) = 4 in the limit). Scaled back up, every point of the scene gained what
    the edges' vertices lost (thin wall: indirect bias +2.3%, +0.5% without it)."""
    probe_total = np.asarray(probe_total, dtype=np.float64)
    return np.minimum(energy_factor(probe_total, probe_total + np.asarray(added_total, dtype=np.float64)), 1.0)


def area_weighted_mean(values: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """Area-weighted mean of ``values (s, 3)``: ``(3,)``."""
    total = float(areas.sum())
    if total <= 0.0:
        return np.zeros(values.shape[1:])
    return (values * areas[:, None]).sum(axis=0) / total


def conserve_energy(light, radiance, landing, areas):
    """``light (s, 3)`` scaled so that the power it brings equals the power ``radiance (s, 3)``
    sends that lands: ``(light, factor (3,))``.

    Every bit of light a surface sends lands on a surface or leaves through the sky. In
    CubeGI's units (diffuse light l = E / pi, radiance B) that is, per colour channel,
    ``sum_j A_j l_j = sum_i A_i B_i (1 - sky_i)``, with ``landing`` ``(s, 3)`` the share
    ``1 - sky_i`` and ``areas (s,)``. Probe interpolation, texel sampling and SH truncation
    each move a bounce's total a little off this (measured: 0.1-1% per bounce), and in a
    closed room of albedo rho that error is amplified by about 1 / (1 - rho)."""
    factor = energy_factor(landed_power(radiance, landing, areas), (areas[:, None] * light).sum(axis=0))
    return light * factor, factor


def landed_power(radiance, landing, areas) -> np.ndarray:
    """``(3,)`` the power per channel that per-point radiance ``(s, 3)`` sends that lands."""
    return (areas[:, None] * radiance * landing).sum(axis=0)


class BounceOperator(Protocol):
    """One bounce, in probe-coefficient space (coefficients: ``(p, 9, 3)`` or ``(9p, 3)``, the
    operator's own shape; every channel apart)."""

    def first(self, direct: np.ndarray) -> np.ndarray:
        """``c_1``: the coefficients of what the points send of their direct light ``(s, 3)``."""

    def bounce_light(self, coeffs: np.ndarray) -> np.ndarray | None:
        """The points' light ``(s, 3)`` of ``coeffs``, where the operator makes it each bounce
        (None where it does not: the dense operator works in coefficients only)."""

    def total(self, coeffs: np.ndarray, light: np.ndarray | None) -> np.ndarray:
        """``(3,)`` the area-weighted total of the light of ``coeffs`` (``light``: its
        :meth:`bounce_light`)."""

    def landed(self, coeffs: np.ndarray | None, light: np.ndarray | None) -> np.ndarray:
        """``(3,)`` the power the points send of this light that lands (from ``light (s, 3)``
        where given, else from ``coeffs``)."""

    def apply(self, coeffs: np.ndarray, light: np.ndarray | None) -> np.ndarray:
        """``c_{k+1}`` from balanced bounce k (``coeffs`` and its points' ``light``)."""

    def linear(self, coeffs: np.ndarray, factor: np.ndarray) -> np.ndarray:
        """``M (factor coeffs)``: one bounce without clamps, float64 (for the tail)."""


@dataclass
class Bounce:
    """Bounce ``number`` of a series: its coefficients before the balance ``coeffs``, the
    balance's ``factor (3,)`` and, where the operator makes it, the points' balanced
    ``light (s, 3)``."""

    number: int
    coeffs: np.ndarray
    factor: np.ndarray
    light: np.ndarray | None

    @property
    def balanced(self) -> np.ndarray:
        """``b_k``: the coefficients as balanced (in the coefficients' own precision)."""
        return self.coeffs * self.factor.astype(self.coeffs.dtype)


def bounce_series(op: BounceOperator, direct=None, balanced=True, factors=None, first=None) -> Iterator[Bounce]:
    """The bounces of ``direct (s, 3)`` on ``op``, one :class:`Bounce` at a time, for as long
    as the caller takes them (the next bounce is made only when asked for).

    ``balanced``: each bounce scaled by the energy balance (else factors of 1); ``factors
    (N, 3)``: the factors given (relighting bounces every source with the whole scene's),
    then at most N bounces; ``first``: ``c_1`` when already made."""
    c = op.first(direct) if first is None else first
    balance = balanced and factors is None
    target = op.landed(None, direct) if balance else None
    count = None if factors is None else len(factors)
    k = 0
    while count is None or k < count:
        light = op.bounce_light(c)
        if factors is not None:
            g = np.asarray(factors[k], dtype=np.float64)
        elif balance:
            g = energy_factor(target, op.total(c, light))
        else:
            g = np.ones(3)
        k += 1
        bounce = Bounce(k, c, g, None if light is None else light * g)
        yield bounce
        b = bounce.balanced
        if balance:
            target = op.landed(b, bounce.light)
        c = op.apply(b, bounce.light)


@dataclass
class TailSum:
    """The bounces after bounce N summed: ``coeffs`` ``x`` of ``(1 - g M) x = M g c_N``, to be
    scaled by ``factor`` ``g (3,)`` (:attr:`balanced`); the GMRES ``iterations`` and the
    ``residual`` it stopped at (0 for a direct solve)."""

    coeffs: np.ndarray
    factor: np.ndarray
    iterations: int = 0
    residual: float = 0.0

    @property
    def balanced(self) -> np.ndarray:
        return self.coeffs * self.factor


def tail_sum(op: BounceOperator, last: np.ndarray, factor, tol=1e-5, inverse=None) -> TailSum:
    """The rest of the series after a last bounce of coefficients ``last`` (before the
    balance) and factor ``factor (3,)``, the factor every later bounce is given (by then the
    light's distribution, and so its factor, has settled): by ``inverse`` (a solver of
    ``(1 - g M) x = c``, where the operator keeps one) or GMRES to ``tol``."""
    f = np.asarray(factor, dtype=np.float64)
    shape = last.shape
    first = op.linear(last, f)  # c_{N+1}
    if inverse is not None:
        return TailSum(inverse(first.reshape(shape)).reshape(shape), f)
    if not np.any(first):
        return TailSum(np.zeros(shape), f)

    def step(x):
        y = x.reshape(shape)
        return (y - op.linear(y, f).reshape(shape)).ravel()

    total, iterations, residual = gmres(step, first.ravel(), tol=tol)
    return TailSum(total.reshape(shape), f, iterations, residual)
