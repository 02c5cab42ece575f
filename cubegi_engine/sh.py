"""Order-2 real spherical harmonics (9 coefficients) for irradiance, after Ramamoorthi and
Hanrahan, "An Efficient Representation for Irradiance Environment Maps", SIGGRAPH 2001.

Pure numpy; must not import bpy.

Conventions, fixed once:

* Coefficient order ``k = l^2 + l + m``: (0,0), (1,-1), (1,0), (1,1), (2,-2), (2,-1), (2,0),
  (2,1), (2,2).
* Real basis with the signs of R&H eq. 3 (no Condon-Shortley phase), written in terms of
  the unit direction (x, y, z) in Blender world space (Z up):
  Y00 = 0.282095, Y1-1 = 0.488603 y, Y10 = 0.488603 z, Y11 = 0.488603 x,
  Y2-2 = 1.092548 xy, Y2-1 = 1.092548 yz, Y20 = 0.315392 (3z^2 - 1),
  Y21 = 1.092548 xz, Y22 = 0.546274 (x^2 - y^2).
* Radiance coefficients ``L_lm = integral L(w) Y_lm(w) dw``; irradiance for a normal n is
  ``E(n) = sum_lm A_l L_lm Y_lm(n)`` with the clamped-cosine factors A_0 = pi,
  A_1 = 2 pi / 3, A_2 = pi / 4 (R&H eq. 8).
* CubeGI stores light as the diffuse value of a white Lambertian surface, E / pi; the
  functions named ``*_diffuse`` return that.
"""

import numpy as np

__all__ = ["basis", "project", "diffuse_basis", "irradiance_diffuse", "fibonacci_sphere", "dering", "COSINE_LOBE", "DERING_WINDOW"]

# Normalisation constants of the real SH basis (R&H eq. 3).
C0 = 0.5 * np.sqrt(1.0 / np.pi)  # 0.282095
C1 = np.sqrt(3.0 / (4.0 * np.pi))  # 0.488603
C2 = 0.5 * np.sqrt(15.0 / np.pi)  # 1.092548
C20 = 0.25 * np.sqrt(5.0 / np.pi)  # 0.315392
C22 = 0.25 * np.sqrt(15.0 / np.pi)  # 0.546274

# Clamped-cosine convolution factors per band (R&H eq. 8): pi, 2 pi / 3, pi / 4.
BAND_COSINE = np.array([np.pi, 2.0 * np.pi / 3.0, np.pi / 4.0])
BAND_OF_COEFF = np.array([0, 1, 1, 1, 2, 2, 2, 2, 2])
COSINE_LOBE = BAND_COSINE[BAND_OF_COEFF]  # (9,)


def basis(dirs):
    """Real SH basis at unit directions: ``(..., 9)`` in the dtype of ``dirs`` (..., 3)."""
    d = np.asarray(dirs)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    out = np.empty(d.shape[:-1] + (9,), dtype=np.result_type(d.dtype, np.float32))
    out[..., 0] = C0
    out[..., 1] = C1 * y
    out[..., 2] = C1 * z
    out[..., 3] = C1 * x
    out[..., 4] = C2 * x * y
    out[..., 5] = C2 * y * z
    out[..., 6] = C20 * (3.0 * z * z - 1.0)
    out[..., 7] = C2 * x * z
    out[..., 8] = C22 * (x * x - y * y)
    return out


def project(radiance, dirs, solid_angles):
    """Project radiance samples onto SH by quadrature.

    radiance: ``(..., t, c)``; dirs: ``(t, 3)`` unit; solid_angles: ``(t,)``.
    Returns ``(..., 9, c)`` radiance coefficients.
    """
    weights = basis(dirs) * solid_angles[:, None]  # (t, 9)
    return np.einsum("tk,...tc->...kc", weights, radiance)


def diffuse_basis(normals):
    """Basis rows that turn radiance coefficients into diffuse light (E / pi) for a normal.

    normals: ``(..., 3)`` unit. Returns ``(..., 9)``: ``basis(n) * A_l / pi``.
    """
    return basis(normals) * (COSINE_LOBE / np.pi)


def irradiance_diffuse(coeffs, normals):
    """Diffuse light E(n) / pi from radiance coefficients.

    coeffs: ``(..., 9, c)``; normals: ``(..., 3)`` broadcastable. Returns ``(..., c)``.
    """
    return np.einsum("...k,...kc->...c", diffuse_basis(normals), coeffs)


# Deringing. Order-2 SH of a small bright source rings: the irradiance it gives dips below
# zero on the far side (to -3.7% of its peak for a single direction). Scaling band 1 by
# sqrt(3)/2 and band 2 by 0.8 makes the order-2 irradiance of any single direction, and so
# of any non-negative radiance (a positive sum of directions), non-negative everywhere:
# with c = cos(angle to the source) the windowed response is proportional to
# 1 + sqrt(3) c + (3 c^2 - 1) / 2 * 5/4 * 0.8, whose minimum over c is 0 (at c = -1/sqrt(3)).
# Band 0 is untouched, so the mean of the irradiance over all normals does not change.
DERING_WINDOW = np.array([1.0, np.sqrt(3.0) / 2.0, 0.8])[BAND_OF_COEFF]  # (9,)


def fibonacci_sphere(k):
    """``k`` nearly evenly spread unit directions ``(k, 3)``."""
    i = np.arange(k) + 0.5
    z = 1.0 - 2.0 * i / k
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    a = np.pi * (1.0 + 5.0**0.5) * i
    return np.stack([r * np.cos(a), r * np.sin(a), z], axis=1)


_DERING_DIRS = diffuse_basis(fibonacci_sphere(512))  # (512, 9)
DERING_MARGIN = 0.02  # of a probe's mean light: closer to zero than this counts as ringing


def dering(coeffs):
    """Window the coefficients ``(..., 9, c)`` of each probe whose diffuse light goes negative
    in some direction (checked on 512 directions, with a margin of 2% of its mean) by
    ``DERING_WINDOW``; the others are left as they are. Returns ``(coefficients, deringed (..., c) bool)``.

    The full window, not a partial one, is applied: it is what makes the light
    non-negative for every direction, not only the checked ones.
    """
    c = np.asarray(coeffs)
    # One matrix product over every probe and channel: (512, 9) x (9, ... c).
    flat = np.moveaxis(c, -2, 0).reshape(9, -1)
    e0 = _DERING_DIRS.astype(np.result_type(c.dtype, np.float32)) @ flat
    # Near zero counts as ringing: the minimum can fall between the checked directions.
    rings = (e0.min(axis=0) < DERING_MARGIN * np.abs(e0).mean(axis=0)).reshape(c.shape[:-2] + c.shape[-1:])  # (..., c)
    if not rings.any():
        return c, rings
    window = np.where(rings[..., None, :], DERING_WINDOW.astype(c.dtype)[:, None], 1.0)
    return c * window.astype(c.dtype), rings
