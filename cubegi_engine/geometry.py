"""Rays against the triangles a cube-map texel saw. Pure numpy; must not import bpy."""

import numpy as np

__all__ = ["cut_triangles"]


def cut_triangles(origins, u, tid, triangles, vertices):
    """Where the rays ``origins + t u`` cut the planes of triangles ``tid``.

    origins, u: ``(..., 3)`` (u unit); tid: ``(...)`` triangle index, -1 for none;
    triangles: ``(t, 3)`` indices into vertices ``(v, 3)``. Returns ``(t, inside, normal)``:
    the distance along each ray (nan where there is no triangle or the ray grazes its plane,
    within 1e-3 of parallel), whether the cut lies inside the triangle, and the triangle's
    unnormalised normal ``(..., 3)``.
    """
    tri = triangles[np.maximum(tid, 0)]
    a, b, c = vertices[tri[..., 0]], vertices[tri[..., 1]], vertices[tri[..., 2]]
    nrm = np.cross(b - a, c - a)
    area2 = np.einsum("...c,...c->...", nrm, nrm)
    denom = np.einsum("...c,...c->...", u, nrm)
    ok = (tid >= 0) & (area2 > 0) & (np.abs(denom) > 1e-3 * np.sqrt(area2))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("...c,...c->...", a - origins, nrm) / np.where(ok, denom, 1.0)
        x = origins + t[..., None] * u
        l1 = np.einsum("...c,...c->...", np.cross(c - b, x - b), nrm) / np.where(ok, area2, 1.0)
        l2 = np.einsum("...c,...c->...", np.cross(a - c, x - c), nrm) / np.where(ok, area2, 1.0)
    inside = ok & (l1 >= 0) & (l2 >= 0) & (l1 + l2 <= 1)
    return np.where(ok, t, np.nan), inside, nrm
