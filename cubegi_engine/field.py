"""The probe field: SH radiance per probe, and the light it gives at any point.

Pure numpy; must not import bpy. After a bake the field holds what each probe sees of the
lit scene (emitters, sky, and every bounce of light off the surfaces, the tail included
when added). It lights any point in the grid, a vertex of an object that moves or was never
captured, with no capture: trilinear weights over the valid probes, evaluated for the
point's normal (R&H irradiance).
"""

from dataclasses import dataclass

import numpy as np

from . import sh

__all__ = ["ProbeField"]


@dataclass
class ProbeField:
    """grid: ProbeGrid or GridSet; coeffs: ``(p, 9, 3)`` SH radiance; valid: ``(p,)`` bool
    (False for a probe inside geometry, left out of every interpolation)."""

    grid: object
    coeffs: np.ndarray
    valid: np.ndarray

    def light_at(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Diffuse light ``(s, 3)`` (E / pi) at ``points (s, 3)`` facing ``normals (s, 3)``.

        Probes inside geometry are left out and the weights of the rest renormalised (a
        point whose probes are all invalid keeps its plain trilinear weights). No visibility
        test: the field is smooth by construction, so light can leak through walls thinner
        than a cell, as in every probe volume without depth data."""
        index, weight = self.grid.trilinear(np.asarray(points, dtype=np.float64))
        w = weight * self.valid[index]
        total = w.sum(axis=1, keepdims=True)
        weight = np.where(total > 1e-9, w / np.maximum(total, 1e-30), weight)
        coeffs, _ = sh.dering(self.coeffs)
        basis = sh.diffuse_basis(np.asarray(normals, dtype=np.float64))  # (s, 9)
        # light = sum over probes k and coefficients j of w_k * basis_j * c_kj
        out = np.einsum("sk,sj,skjc->sc", weight, basis, coeffs[index], optimize=True)
        return np.maximum(out, 0.0)

    @property
    def nbytes(self) -> int:
        return int(self.coeffs.nbytes + self.valid.nbytes)
