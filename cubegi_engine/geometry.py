"""Rays against the triangles a cube-map texel saw, and points near triangles. Pure numpy;
must not import bpy."""

import numpy as np

__all__ = ["cut_triangles", "near_any_triangle", "edge_neighbours", "chunks", "POINT_CHUNK"]

# Per-point tests that make several (s, 9, 3) float64 arrays run this many points at a time:
# a million points then need tens of megabytes, not gigabytes, and stay in cache.
POINT_CHUNK = 65536


def chunks(count, size=POINT_CHUNK):
    """Slices that cover ``range(count)`` in pieces of ``size``."""
    return [slice(start, start + size) for start in range(0, count, size)]


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


def near_any_triangle(centres, radius, a, b, c, tiles=8, centre_normals=None, across=None):
    """``(m,)`` bool: whether each of ``centres (m, 3)`` may lie within ``radius`` of any of
    the triangles ``a, b, c`` (each ``(k, 3)``). Conservative: the point is within ``radius``
    of the triangle's plane and its box and, projected onto it, within ``radius`` of the
    inside of every edge (near a sharp corner this takes in more than the true distance would). The
    centres are tested tile by tile (about ``tiles`` along the longest side, no smaller than
    eight radii) against the triangles whose boxes reach the tile. With ``centre_normals``
    ``(m, 3)`` and ``across``, a triangle counts for a centre only where the cosine between
    their normals is below ``across`` in magnitude (it runs across the centre's surface)."""
    m = len(centres)
    out = np.zeros(m, dtype=bool)
    if not m or not len(a):
        return out
    n = np.cross(b - a, c - a)
    length = np.linalg.norm(n, axis=1)
    keep = length > 0
    a, b, c, n = a[keep], b[keep], c[keep], n[keep] / length[keep, None]
    edges = [(a, b), (b, c), (c, a)]
    inward = []  # inward unit directions of the three edges, in the plane
    for p, q in edges:
        d = np.cross(n, q - p)
        inward.append(d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300))
    box_lo = np.minimum(np.minimum(a, b), c) - radius
    box_hi = np.maximum(np.maximum(a, b), c) + radius
    lo = centres.min(axis=0)
    edge = max(float(np.max(centres.max(axis=0) - lo)) / tiles, 8.0 * radius, 1e-300)
    tile = np.floor((centres - lo) / edge).astype(np.int64)
    ids, which = np.unique(tile, axis=0, return_inverse=True)
    which = which.ravel()
    order = np.argsort(which, kind="stable")
    bounds = np.searchsorted(which[order], np.arange(len(ids) + 1))
    for t in range(len(ids)):
        cells = order[bounds[t] : bounds[t + 1]]
        t_lo = lo + ids[t] * edge
        sel = np.flatnonzero(np.all(box_lo <= t_lo + edge, axis=1) & np.all(box_hi >= t_lo, axis=1))
        if not len(sel):
            continue
        pts = centres[cells]
        near = np.all((pts[:, None, :] >= box_lo[None, sel]) & (pts[:, None, :] <= box_hi[None, sel]), axis=2)
        near &= np.abs(np.einsum("mkc,kc->mk", pts[:, None, :] - a[None, sel], n[sel])) <= radius
        if centre_normals is not None:
            near &= np.abs(centre_normals[cells] @ n[sel].T) < across
        for (p, _), d in zip(edges, inward):
            near &= np.einsum("mkc,kc->mk", pts[:, None, :] - p[None, sel], d[sel]) >= -radius
        out[cells] = near.any(axis=1)
    return out


def edge_neighbours(triangles) -> np.ndarray:
    """``(t, 3)``: for each triangle, the triangle across each of its edges (edge k joins
    corners k and k + 1), -1 where none (a border). Where more than two triangles share an
    edge, each is paired with the next one in index order."""
    t = len(triangles)
    out = np.full((t, 3), -1, dtype=np.int32)
    if not t:
        return out
    tri = np.asarray(triangles, dtype=np.int64)
    a = tri.ravel()
    b = np.roll(tri, -1, axis=1).ravel()
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo * (int(tri.max()) + 1) + hi
    order = np.argsort(key, kind="stable")
    same = key[order[1:]] == key[order[:-1]]
    first, second = order[:-1][same], order[1:][same]
    out.ravel()[first] = second // 3
    out.ravel()[second] = first // 3
    return out
