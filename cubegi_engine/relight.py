"""Relighting on a kept capture: every source's light kept apart, so that an edit of a
light, the sky or an emitter costs a weighted sum or a small solve, never a capture.

Pure numpy; must not import bpy.

The bounce operator of a capture is linear in probe-coefficient space. Per colour channel,
with ``K`` the gather-and-project matrix (points' radiance -> probes' SH coefficients,
``(9p, s)``), ``A`` the albedo, ``I`` the interpolation matrix (coefficients -> points'
diffuse light, ``(s, 9p)``) and ``M = K A I`` (one bounce, coefficients to coefficients),
the one-shot bake's bounces of a direct light ``d`` are

    c_1 = K A d,   b_k = g_k c_k (bounce k's coefficients, balanced),   c_{k+1} = M b_k,
    light_k = I b_k,   the tail after bounce N: I (1 - g M)^-1 g M b_N   (g = g_N)

with ``g_k`` the energy balance's factor of bounce k (:func:`cubegi_engine.solve.
conserve_energy`). Everything the balance needs is a dot product in coefficient space
(``areas @ I`` and ``(areas albedo landing) @ I`` are kept), so :meth:`SceneLight.solve`
recomputes the factors of the scene's whole light and every source's bounces in
``O(N (9p)^2)`` plus one ``I`` product per source: the one-shot bake's numbers up to its
tail solve's tolerance, float rounding, and the clamp of a ringing probe (none in the
demo Room; measured in ``tests/blender/test_relight.py``).

A power or colour edit changes only a source's weight: the scene's light is the weighted
sum of the sources' (:meth:`SceneLight.set_weight`, microseconds), with the balance's
factors as they were; :meth:`SceneLight.solve` brings them up to date (milliseconds).
"""

import time
from dataclasses import dataclass, replace

import numpy as np

from .emitters import balanced_landing
from .errors import BakeError
from .lights import light_keys
from .series import bounce_series, landed_power, near_factor, tail_sum

__all__ = ["MatrixOperator", "Source", "SceneLight", "from_bake", "MAX_OPERATOR_ELEMENTS", "SKY", "EMISSION"]

SKY, EMISSION = "sky", "emission"

# The dense gather-project and interpolation matrices hold 9p x s numbers each (float32);
# past this many (200 MB each) relighting in place is refused: the caller re-solves on the
# kept capture instead (:func:`cubegi_engine.solve.solve_steps`).
MAX_OPERATOR_ELEMENTS = 50_000_000
# M = K A I is built (3 x 9p x 9p) when that costs at most this many multiply-adds (about a
# second on two cores); past it, M is applied as K (A (I x)) without being formed.
MAX_M_FLOPS = 2e10
# The tail is an explicit inverse of (1 - g M) up to this size, GMRES beyond. A kept inverse
# serves a nearby g by iterative refinement to this residual (a share of the right-hand
# side), within this many steps (else it is made again).
MAX_INVERSE_SIZE = 1500
REFINE_TOL, REFINE_STEPS = 1e-10, 8


def _interpolation_matrix(transport, s):
    """``I (s, 9p)``: diffuse light at the points from probe coefficients (one channel)."""
    return _dense_interpolation(transport.index, transport.point_weights, transport.probe_count)


def _dense_interpolation(index, weights, p):
    """``(m, 9p)`` float32: each row's light from probe coefficients (one channel), for its 8
    probes ``index (m, 8)`` and their 72 weights ``(m, 72)`` (weight x basis)."""
    m = len(index)
    cols = (np.asarray(index)[:, :, None] * 9 + np.arange(9)[None, None, :]).reshape(m, -1)  # (m, 72)
    flat = (np.arange(m)[:, None] * (9 * p) + cols).ravel()
    values = np.asarray(weights, dtype=np.float64).ravel()
    return np.bincount(flat, values, minlength=m * 9 * p).reshape(m, 9 * p).astype(np.float32)


class MatrixOperator:
    """The bounce operator of one capture as matrices (see the module docstring): a
    :class:`~cubegi_engine.series.BounceOperator` in coefficients ``(9p, 3)``, linear.

    ``landing``: ``(s, 3)`` share of each point's view that is surface (None: no energy
    balance); ``areas``: ``(s,)``.
    """

    def __init__(self, transport, albedo, landing=None, areas=None):
        s, p = len(transport.index), transport.probe_count
        if 9 * p * s > MAX_OPERATOR_ELEMENTS:
            raise BakeError(
                f"{p} probes x {s} points is too large to relight in place ({9 * p * s:,} numbers per matrix); bake again"
            )
        t = time.perf_counter()
        self.K = transport.gather_project_matrix()
        self.I = _interpolation_matrix(transport, s)
        self.landing = None if landing is None else np.asarray(landing, dtype=np.float64)
        self.areas = np.ones(s) if areas is None else np.asarray(areas, dtype=np.float64)
        self.u = self.areas @ self.I  # (9p,): area-weighted total of a coefficient vector's light
        self.matrix_seconds = time.perf_counter() - t
        self.set_albedo(albedo)

    def set_albedo(self, albedo):
        """Rebuild ``M`` for new albedo ``(s, 3)`` (a material edit)."""
        t = time.perf_counter()
        self.albedo = np.asarray(albedo, dtype=np.float64)
        n, s = self.K.shape
        self.M = None
        self._inverses = [None, None, None]  # per channel: (factor, (1 - factor M)^-1)
        if 3.0 * n * n * s <= MAX_M_FLOPS:
            self.M = np.stack([(self.K * self.albedo[:, c].astype(np.float32)) @ self.I for c in range(3)]).astype(np.float64)
        if self.landing is not None:  # (3, 9p): power sent on that lands, per coefficient vector
            self.v = np.stack([(self.areas * self.albedo[:, c] * self.landing[:, c]) @ self.I for c in range(3)])
        self.albedo_seconds = time.perf_counter() - t

    @property
    def size(self):
        return self.K.shape[0]

    @property
    def nbytes(self):
        return int(self.K.nbytes + self.I.nbytes + (self.M.nbytes if self.M is not None else 0))

    def project(self, radiance):
        """Probe coefficients ``(9p, 3)`` of per-point radiance ``(s, 3)``."""
        return (self.K @ np.asarray(radiance, dtype=np.float32)).astype(np.float64)

    def light(self, coeffs):
        """Diffuse light ``(s, 3)`` at the points from coefficients ``(9p, 3)``."""
        return (self.I @ np.asarray(coeffs, dtype=np.float32)).astype(np.float64)

    def apply(self, coeffs, light=None, factor=None):
        """``M (factor * coeffs)`` per channel: the next bounce's unbalanced coefficients."""
        x = coeffs if factor is None else coeffs * factor
        if self.M is not None:
            return np.stack([self.M[c] @ x[:, c] for c in range(3)], axis=1)
        return self.project(self.albedo * self.light(x))

    # --- the series' operator (cubegi_engine.series.BounceOperator) ---------------------------
    def first(self, direct):
        return self.project(self.albedo * direct)

    def bounce_light(self, coeffs):
        return None  # the dense operator keeps to coefficients

    def total(self, coeffs, light):
        return self.u @ coeffs

    def landed(self, coeffs, light):
        if light is not None:
            return landed_power(self.albedo * np.asarray(light), self.landing, self.areas)
        return np.einsum("cq,qc->c", self.v, coeffs)

    def linear(self, coeffs, factor):
        return self.apply(coeffs, factor=factor)

    def factors(self, direct, count):
        """The balance's factors ``(count, 3)`` of the bounces of ``direct (s, 3)``, as the
        one-shot bake computes them (ones without a balance)."""
        if count == 0:
            return np.ones((0, 3))
        series = bounce_series(self, direct, balanced=self.landing is not None)
        return np.stack([next(series).factor for _ in range(count)])

    def inverse(self, factor):
        """A solver of ``(1 - factor M) x = c`` per channel (``c``, ``x``: ``(9p, 3)``), or
        None where GMRES is used.

        The inverse is kept: a later factor (the energy balance moves a little with every
        edit) is served by iterative refinement on it, ``x += A0^-1 (c - A x)``, to a residual
        of REFINE_TOL of ``c``: a few ``(9p)^2`` products instead of a ``(9p)^3`` inverse. Where
        that does not converge within REFINE_STEPS, the inverse is made again at the new
        factor."""
        n = self.size
        if self.M is None or n > MAX_INVERSE_SIZE:
            return None
        factor = np.asarray(factor, dtype=np.float64)
        return lambda c: np.stack([self._tail_solve(ch, float(factor[ch]), c[:, ch]) for ch in range(3)], axis=1)

    def _tail_solve(self, ch, f, c):
        kept = self._inverses[ch]
        if kept is not None and kept[0] == f:
            return kept[1] @ c
        if kept is not None:
            _, inv = kept
            x = inv @ c
            scale = np.linalg.norm(c)
            for _ in range(REFINE_STEPS):
                r = c - (x - f * (self.M[ch] @ x))
                if np.linalg.norm(r) <= REFINE_TOL * scale:
                    return x
                x = x + inv @ r
        inv = np.linalg.inv(np.eye(self.size) - f * self.M[ch])
        self._inverses[ch] = (f, inv)
        return inv @ c

    def bounces(self, c1, g, inverse=None, tail=True, tol=1e-5):
        """Balanced coefficients of bounces 1..N ``(N, 9p, 3)`` and of the tail after them
        ``(9p, 3)`` (zeros without ``tail``) from bounce 1's unbalanced ``c1``, with the
        factors ``g (N, 3)`` given. ``inverse``: from :meth:`inverse` (None: GMRES to
        ``tol``)."""
        out = np.empty((len(g),) + c1.shape)
        last = None
        for last in bounce_series(self, factors=g, first=c1):
            out[last.number - 1] = last.balanced
        rest = np.zeros_like(c1)
        if tail and last is not None:
            rest = tail_sum(self, last.coeffs, last.factor, tol, inverse).balanced
        return out, rest


@dataclass
class Source:
    """One source of light at unit weight, and its weight now (``(3,)``: a light's colour
    times power; the sky's radiance; an emitter's scale).

    direct: ``(s, 3)``; first: ``(9p, 3)`` bounce 1's unbalanced coefficients; own:
    ``(9p, 3)`` what the probes see of the source itself (sky, emitters; zero for a light);
    bounces ``(N, 9p, 3)`` and tail ``(9p, 3)``: balanced, from the last :meth:`SceneLight.solve`;
    indirect: ``(s, 3)`` their light. ``light``: the Light it is (None for sky and emitters).
    """

    key: str
    direct: np.ndarray
    first: np.ndarray
    own: np.ndarray
    weight: np.ndarray
    light: object = None
    bounces: np.ndarray | None = None
    tail: np.ndarray | None = None
    indirect: np.ndarray | None = None
    near: np.ndarray | None = None  # per bounce, what the near field adds on its support points


class SceneLight:
    """The light of a scene on a kept capture, per source; see the module docstring.

    ``scene``: the SceneArrays the capture was taken of; ``op``: its MatrixOperator;
    ``light_direct(light) -> (s, 3)``: one Light's direct light with shadows (the renderer
    lives with the caller); ``count``: bounces kept apart (the rest is the tail, added if
    ``add_tail``).
    """

    def __init__(self, scene, transport, light_direct, op: MatrixOperator, count, add_tail=True, emitter_light=None,
                 sky_light=None):
        self.scene, self.transport, self.light_direct, self.op = scene, transport, light_direct, op
        self.emitter_light, self.sky_light = emitter_light, sky_light
        self.count, self.add_tail = int(count), bool(add_tail)
        self.sources: dict[str, Source] = {}
        self.factors = np.ones((self.count, 3))
        self.near_factors = None  # (steps, 3): the near field's scale per bounce (and tail)
        self.solve_seconds = 0.0

    def _add(self, key, direct, own, weight, light=None):
        direct = self.scene.zero_dark_points_inplace(np.asarray(direct, dtype=np.float64).copy())
        direct[self.transport.resting()] = 0.0  # as the bake's (direct.direct_light_steps)
        first = self.op.project(self.op.albedo * direct)
        self.sources[key] = Source(key, direct, first, own, np.asarray(weight, dtype=np.float64), light)
        return self.sources[key]

    # --- edits -------------------------------------------------------------------------------
    def set_light(self, key, light, direct=None):
        """Add a light, or replace one that moved, turned or changed shape (its direct light
        is drawn again, at unit colour, unless ``direct`` at its colour is given)."""
        colour = np.asarray(light.colour, dtype=np.float64)
        if direct is not None and np.all(colour > 0):
            unit = np.asarray(direct) / colour
        else:
            unit = self.light_direct(replace(light, colour=np.ones(3)))
        return self._add(key, unit, np.zeros((self.op.size, 3)), colour, light)

    def set_sky(self, radiance, direct=None):
        """The sky, of (mean) radiance ``(3,)``; ``direct``: its direct light at that radiance
        (else the unit sky's, from ``sky_light()``, or as the probes see it)."""
        own = self.transport.sky_coefficients(np.ones(3)).reshape(-1, 3).astype(np.float64)
        radiance = np.asarray(radiance, dtype=np.float64)
        if direct is not None and np.all(radiance > 0):
            unit = np.asarray(direct) / radiance[None, :]
        elif self.sky_light is not None:
            unit = self.sky_light()
        else:
            unit = self._seen(own)
        return self._add(SKY, unit, own, radiance)

    def set_emission(self, emission, direct=None):
        """Every emitter of the scene, sending ``emission (s, 3)``: one source. ``direct``:
        their direct light (drawn with ``emitter_light(emission)`` when not given: the exact
        form factors and the emitters' shadow maps)."""
        if not np.any(emission > 0):
            self.remove(EMISSION)
            return None
        own = self.op.project(emission)
        if direct is None:
            direct = self.emitter_light(emission)
        return self._add(EMISSION, direct, own, np.ones(3))

    def _seen(self, own):
        """The diffuse light of what probes see directly (the sky), as the bake makes it
        (:meth:`Transport.seen_light`: ringing probes deringed, clamped at zero, both of which
        commute with a positive weight, so the source stays linear in it)."""
        return self.transport.seen_light(np.asarray(own, dtype=np.float32).reshape(-1, 9, 3))

    def set_weight(self, key, weight):
        """A power or colour edit: the source's new weight ``(3,)``. The balance's factors
        stay as they are until :meth:`solve`."""
        self.sources[key].weight = np.asarray(weight, dtype=np.float64)

    def remove(self, key):
        self.sources.pop(key, None)

    def set_albedo(self, albedo):
        """A material's colour edit: new albedo ``(s, 3)``; then :meth:`solve`."""
        self.op.set_albedo(albedo)
        for src in self.sources.values():
            src.first = self.op.project(self.op.albedo * src.direct)

    # --- solving -----------------------------------------------------------------------------
    def solve(self):
        """Balance the scene's whole light as the one-shot bake does, and bounce every source
        with those factors (see the module docstring)."""
        t = time.perf_counter()
        direct = self.direct()
        self.factors = self.op.factors(direct, self.count)
        inverse = self.op.inverse(self.factors[-1]) if self.add_tail and self.count else None
        for src in self.sources.values():
            src.bounces, src.tail = self.op.bounces(src.first, self.factors, inverse, self.add_tail)
        near = self.transport.near
        if near is not None and near.count:
            self._near_field(near)
        else:
            self.near_factors = None
            for src in self.sources.values():
                src.near = None
                src.indirect = self.scene.zero_dark_points_inplace(self.op.light(src.bounces.sum(axis=0) + src.tail))
        self.solve_seconds = time.perf_counter() - t

    def _near_field(self, near):
        """Every source's light with the near field (:mod:`cubegi_engine.nearfield`), as the
        one-shot bake makes it: each bounce gathered once more from the one before, then
        scaled per channel down to the total its probe light has (with the energy balance: the
        near field moves light, the balance says how much; the factors are the whole
        scene's, like the balance's). Worked on the near field's support points only, every
        source at once (their channels side by side); ``src.near``: per bounce, what it adds
        there (scaled)."""
        rows_i, parts_m, seen_total = self._near_matrices(near)
        sup = near.support
        sources = list(self.sources.values())
        n, count = len(sources), len(self.factors)
        weights = np.stack([s.weight for s in sources])  # (n, 3)
        albedo = np.tile(self.op.albedo[sup], (1, n))
        area = self.op.areas[sup]
        unseen = np.asarray(self.transport.exact, dtype=bool)[sup]  # as solve.near_field_balanced: not balanced
        balanced = area * ~unseen

        def side_by_side(arrays):  # n arrays (r, 3) -> (r, 3n)
            return np.stack(arrays, axis=1).reshape(len(arrays[0]), 3 * n)

        steps = [side_by_side([s.bounces[k] for s in sources]) for k in range(count)]
        if self.add_tail and count:
            steps.append(side_by_side([s.tail for s in sources]))
        prev = side_by_side([s.direct[sup] for s in sources])
        scale = np.ones((len(steps), 3))
        deltas = []
        for k, c in enumerate(steps):
            c32 = c.astype(np.float32)
            base = (rows_i @ c32).astype(np.float64)
            part = (parts_m @ c32).astype(np.float64)
            if k < count:
                d = near.delta(base, part, albedo * prev)
            else:  # the tail: the sum of the bounces after the last, each from the one before
                d = near.settle(base, part, albedo, prev, clamp=False)
            if self.op.landing is not None:  # as solve.near_field_balanced: over the points a probe sees
                probe = ((seen_total @ c).reshape(n, 3) * weights).sum(axis=0)
                added = ((balanced @ d).reshape(n, 3) * weights).sum(axis=0)
                scale[k] = near_factor(probe, added)
            f = np.where(unseen[:, None], 1.0, np.tile(scale[k], n)[None, :])
            # What the near field adds on the support, scaled; on the points the balance leaves
            # alone (a gathered point's whole light is its rays') the probe light, which every
            # point's gets scaled below, is given back its scale.
            deltas.append(f * d + np.where(unseen[:, None], 1.0 - np.tile(scale[k], n)[None, :], 0.0) * base)
            prev = f * (base + d)
        self.near_factors = scale
        for m, src in enumerate(sources):
            cols = slice(3 * m, 3 * m + 3)
            total = src.tail if len(steps) == count else np.zeros_like(src.tail)
            for k in range(len(steps)):
                total = total + scale[k] * (src.bounces[k] if k < count else src.tail)
            src.indirect = self.op.light(total)
            src.indirect[sup] += sum(d[:, cols] for d in deltas)
            src.near = np.stack([d[:, cols] for d in deltas[:count]]) if count else np.zeros((0, len(sup), 3))
            self.scene.zero_dark_points_inplace(src.indirect)

    def _near_matrices(self, near):
        """``(I on the support (u, 9p), the probes' light in the hit directions (m, 9p), the
        area-weighted total of a coefficient vector's light over the points a probe sees
        (9p,))``, made once per near field."""
        cached = getattr(self, "_near_cache", None)
        if cached is not None and cached[0] is near:
            return cached[1]
        t = self.transport
        rows_i = self.op.I[near.support]
        w = t.probe_weights(near.rows)  # (m, 8)
        parts_m = _dense_interpolation(t.index[near.rows], (w[:, :, None] * near.open_basis[:, None, :]).reshape(near.count, -1),
                                       t.probe_count)
        seen = self.op.areas * ~np.asarray(t.exact, dtype=bool)
        self._near_cache = (near, (rows_i, parts_m, seen @ self.op.I))
        return self._near_cache[1]

    # --- the scene's light now ---------------------------------------------------------------
    def _sum(self, term):
        out = None
        for src in self.sources.values():
            value = term(src) * src.weight
            out = value if out is None else out + value
        return out

    def direct(self):
        """``(s, 3)`` every source's direct light, weighted."""
        if not self.sources:
            return np.zeros((len(self.scene.points), 3))
        return self._sum(lambda s: s.direct)

    def indirect(self):
        if not self.sources:
            return np.zeros((len(self.scene.points), 3))
        return self._sum(lambda s: s.indirect)

    def bounce(self, k):
        """``(s, 3)`` the light of bounce ``k`` (1-based)."""
        if not self.sources or not 1 <= k <= self.count:
            return np.zeros((len(self.scene.points), 3))
        light = self.op.light(self._sum(lambda s: s.bounces[k - 1]))
        if self.near_factors is not None:  # the near field's: scaled, and what it adds
            light *= self.near_factors[k - 1]
            light[self.transport.near.support] += self._sum(lambda s: s.near[k - 1])
        return self.scene.zero_dark_points_inplace(light)

    def field_coeffs(self):
        """``(coeffs, source_coeffs)``, each ``(p, 9, 3)`` float32: what the probes see (the sky,
        emitters and every bounce), and the part that is the sky and emitters."""
        own = self._sum(lambda s: s.own)
        total = own + self._sum(lambda s: s.bounces.sum(axis=0) + s.tail)
        return tuple(np.asarray(a, dtype=np.float32).reshape(-1, 9, 3) for a in (total, own))


def from_bake(result, scene, light_direct, add_tail=True, conserve_energy=True, emitter_light=None, sky_light=None):
    """A solved :class:`SceneLight` of a finished bake: its capture, and its lights',
    emitters' and sky's direct light (no drawing). ``light_direct``, ``emitter_light``,
    ``sky_light``: for lights, emission and a sky that change later."""
    transport = result.capture.transport
    albedo = scene.sent_on()
    landing = balanced_landing(scene, transport) if conserve_energy else None
    op = MatrixOperator(transport, albedo, landing, scene.point_areas())
    state = SceneLight(scene, transport, light_direct, op, len(result.solution.bounces), add_tail, emitter_light, sky_light)
    parts = result.direct_parts.parts
    for key, light in zip(light_keys(scene.lights), scene.lights):
        state.set_light(key, light, parts.get(key))
    if np.any(scene.sky > 0):
        state.set_sky(scene.sky, parts.get(SKY))
    state.set_emission(scene.emission, parts.get(EMISSION))
    state.solve()
    return state


def solved_light(result, scene, settings, renderer, shadows=None):
    """:func:`from_bake` with the drawing a later edit needs: a light drawn again with its
    shadows (kept in ``shadows``, a dict by ``Light.shadow_key``, for dynamic objects, where
    given; never the bake's own), emitters and the sky by the bake's own functions.
    ``renderer()``: the GPU renderer (made on first use by the caller)."""
    from .direct import light_direct
    from .emitters import emitter_direct
    from .sky import unit_sky_direct

    eyes = dict(result.direct_parts.eyes)

    def draw(light):  # a light the bake drew keeps its eyes' count (a new one: all its own)
        return light_direct(scene, renderer(), settings, light, shadows, eyes=eyes.get(light.shadow_key))

    def emitters(emission):
        return emitter_direct(replace(scene, emission=emission), renderer(), settings.area_shadow_size)

    def sky():
        return unit_sky_direct(scene, renderer(), result.capture.transport, settings.sky_per_vertex)

    return from_bake(result, scene, draw, settings.add_tail, settings.conserve_energy, emitters, sky)
