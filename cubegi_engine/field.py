"""The probe field: SH radiance per probe, and the light it gives at any point.

Pure numpy; must not import bpy. After a bake the field holds what each probe sees of the
lit scene: the sky and emitters (``source_coeffs``, which CubeGI counts as direct light) and
every bounce of light off the surfaces, the tail included when added. It lights any point
in the grid, a vertex of an object that moves or was never captured, with no capture:
trilinear weights over the valid probes, evaluated for the point's normal (R&H irradiance).
"""

from dataclasses import dataclass

import numpy as np

from . import sh
from .grid import Grid, ProbeSubset

__all__ = ["ProbeField"]

# Up to this many probes, light_at evaluates every probe for every point (one matrix
# product, s x 27p multiply-adds) before picking each point's 8; beyond, it gathers.
ALL_PROBES_LIMIT = 256
FIELD_CHUNK = 65536


@dataclass
class ProbeField:
    """grid: ProbeGrid or GridSet; coeffs: ``(p, 9, 3)`` SH radiance, everything the probes
    see; valid: ``(p,)`` bool (False for a probe inside geometry, left out of every
    interpolation); source_coeffs: ``(p, 9, 3)`` the part that is the sky and emitters."""

    grid: Grid
    coeffs: np.ndarray
    valid: np.ndarray
    source_coeffs: np.ndarray | None = None

    def weights(self, points, normals=None):
        """``(index (s, 8), weight (s, 8))``: trilinear weights over the valid probes; with
        ``normals``, probes behind a point's surface (inside the object it belongs to) are
        left out too. A point with no probe left keeps its plain trilinear weights."""
        points = np.asarray(points, dtype=np.float64)
        index, plain = self.grid.trilinear(points)
        weight = plain * self.valid[index]
        total = weight.sum(axis=1)
        if normals is not None:
            # probe . n > point . n: the probe is in front of the point's tangent plane
            normals = np.asarray(normals, dtype=np.float64)
            positions = self._positions()
            if len(positions) <= ALL_PROBES_LIMIT:
                probe_n = _pick(normals @ positions.T, index)
            else:
                probe_n = np.einsum("skc,sc->sk", positions[index], normals)
            facing = weight * (probe_n > np.einsum("sc,sc->s", points, normals)[:, None])
            facing_total = facing.sum(axis=1)
            has = facing_total > 1e-9
            weight = np.where(has[:, None], facing, weight)
            total = np.where(has, facing_total, total)
        none = total <= 1e-9
        if none.any():
            weight[none] = plain[none]
            total[none] = plain[none].sum(axis=1)
        weight /= np.maximum(total, 1e-30)[:, None]
        return index, weight

    def light_at(self, points: np.ndarray, normals: np.ndarray, part: str = "all", one_sided: bool = False) -> np.ndarray:
        """Diffuse light ``(s, 3)`` (E / pi) at ``points (s, 3)`` facing ``normals (s, 3)``.

        ``part``: "all", "direct" (the sky and emitters) or "indirect" (the bounces).
        ``one_sided``: leave out probes behind each point's surface (for an object the
        capture never saw: a probe inside it would light it from inside). No visibility
        test: the field is smooth by construction, so light can leak through walls thinner
        than a cell, as in every probe volume without depth data."""
        return self.light_parts(points, normals, (part,), one_sided)[0]

    def light_parts(self, points, normals, parts=("direct", "indirect"), one_sided=False) -> list:
        """:meth:`light_at` for several ``parts`` at once (the weights, the basis and the
        product are shared): a list of ``(s, 3)``. Points go through in chunks of
        FIELD_CHUNK (a million points never make (s, p, 3) temporaries)."""
        coeffs = np.concatenate([self._coeffs(part) for part in parts], axis=2)  # (p, 9, 3k)
        points = np.asarray(points, dtype=np.float64)
        normals = np.asarray(normals, dtype=np.float64)
        out = np.empty((len(points), coeffs.shape[2]), dtype=np.float64)
        for start in range(0, len(points), FIELD_CHUNK):
            sl = slice(start, start + FIELD_CHUNK)
            out[sl] = self._light(coeffs, points[sl], normals[sl], one_sided)
        return [np.ascontiguousarray(out[:, 3 * k : 3 * k + 3]) for k in range(len(parts))]

    def _light(self, coeffs, points, normals, one_sided):
        index, weight = self.weights(points, normals if one_sided else None)
        basis = sh.diffuse_basis(normals).astype(np.float32)  # (s, 9)
        weight = weight.astype(np.float32)
        p, c = len(coeffs), coeffs.shape[2]
        if p <= ALL_PROBES_LIMIT:
            # Every probe's light for every point's normal in one BLAS product, then the 8
            # each point uses: fastest while probes are few.
            each = (basis @ coeffs.transpose(1, 0, 2).reshape(9, p * c)).reshape(len(basis), p, c)
            out = np.einsum("sk,skc->sc", weight, _pick(each, index))
        else:
            pw = (weight[:, :, None] * basis[:, None, :]).reshape(len(basis), 72)
            out = np.einsum("sk,skc->sc", pw, coeffs[index].reshape(len(basis), 72, c), optimize=True)
        return np.maximum(out, 0.0, out=out)

    def _positions(self):
        cached = getattr(self, "_probe_positions", None)
        if cached is None or cached[0] is not self.grid:
            cached = (self.grid, self.grid.positions())
            self._probe_positions = cached
        return cached[1]

    def _coeffs(self, part):
        """The deringed float32 coefficients of ``part``, kept per part until the field's
        arrays are replaced."""
        key = (id(self.coeffs), id(self.source_coeffs))
        cached = getattr(self, "_deringed", None)
        if cached is None or cached[0] != key:
            cached = self._deringed = (key, {})
        if part not in cached[1]:
            source = self.source_coeffs if self.source_coeffs is not None else np.zeros_like(self.coeffs)
            raw = {"all": self.coeffs, "direct": source, "indirect": self.coeffs - source}[part]
            deringed, _ = sh.dering(np.asarray(raw, dtype=np.float64))
            cached[1][part] = deringed.astype(np.float32)
        return cached[1][part]

    def whole(self) -> "ProbeField":
        """This field on its whole grid: a field of a probe subset (a bake that left out the
        probes no point uses) with the left-out probes as invalid and dark."""
        grid = self.grid
        if not isinstance(grid, ProbeSubset):  # every other grid is its own whole
            return self
        source = None if self.source_coeffs is None else grid.expand(self.source_coeffs)
        whole = grid.whole()
        if np.any(grid.displacements()):  # moved probes keep their places
            whole = ProbeSubset(whole, np.ones(whole.count, dtype=bool), grid.expand(grid.displacements(), 0.0))
        return ProbeField(whole, grid.expand(self.coeffs), grid.expand(self.valid, False), source)

    @property
    def nbytes(self) -> int:
        return int(self.coeffs.nbytes + self.valid.nbytes)


def _pick(per_point, index):
    """``per_point[i, index[i, k]]`` for every point i and k: ``(s, 8, ...)`` (flat indexing,
    ``np.take`` along the first axis: three times faster than fancy indexing)."""
    s, p = per_point.shape[:2]
    flat = per_point.reshape((s * p,) + per_point.shape[2:])
    rows = (np.arange(s)[:, None] * p + index).ravel()
    return np.take(flat, rows, axis=0).reshape(index.shape + per_point.shape[2:])
