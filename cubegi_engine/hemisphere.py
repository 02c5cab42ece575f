"""Cosine-weighted ray patterns over a point's hemisphere: the near field's rays
(:mod:`cubegi_engine.nearfield`) and the gathered points' (:mod:`cubegi_engine.gather`).

Pure numpy; must not import bpy.

With cosine-weighted directions a point's diffuse light is the mean of the radiance its rays
see, every ray standing for the same share of it. Neighbouring points turn their pattern by
an angle hashed from their position (``2 pi frac(position / length . TURN_HASH)``): the
same scene in another object order bakes the same, and neighbours' rays are decorrelated.
"""

import numpy as np

from .geometry import cross

__all__ = ["ray_pattern", "hemisphere_rays", "TURN_HASH", "GOLDEN_ANGLE"]

GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))
# Per point, the ray pattern's turn: 2 pi frac(position / reach . TURN_HASH).
TURN_HASH = np.array([7.548776662, 5.698402910, 4.370125427])


def ray_pattern(k, turn=None):
    """``k`` cosine-weighted directions about +z, ``(k, 3)`` (or ``(m, k, 3)``, turned about
    z by ``turn (m,)`` per row): a Fibonacci spiral on the unit disk lifted to the
    hemisphere (Malley's method), so every ray stands for the same share of the light."""
    i = np.arange(k) + 0.5
    r = np.sqrt(i / k)
    phi = np.arange(k) * GOLDEN_ANGLE
    if turn is not None:
        phi = phi[None, :] + np.asarray(turn, dtype=np.float64)[:, None]
        r = np.broadcast_to(r, phi.shape)
    z = np.sqrt(np.maximum(1.0 - r * r, 0.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def hemisphere_rays(normals, rays, turn):
    """Each point's rays in world space, ``(m, rays, 3)``. A point without a normal (zero: a
    face of no area) gets rays of no length, which meet nothing."""
    helper = np.where(np.abs(normals[:, 2:3]) < 0.9, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
    t1 = cross(helper, normals)
    t1 /= np.maximum(np.linalg.norm(t1, axis=1, keepdims=True), 1e-300)
    t2 = cross(normals, t1)
    local = ray_pattern(rays, turn)
    return local[..., 0:1] * t1[:, None] + local[..., 1:2] * t2[:, None] + local[..., 2:3] * normals[:, None]
