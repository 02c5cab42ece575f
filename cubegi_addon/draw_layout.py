"""How the GPU capture lays out a scene's triangles for drawing (numpy alone; see
:mod:`.gpu_capture`): the index buffer in which each triangle has a provoking vertex of its
own, the drawing order and the chunks each view culls, and the barycentric weights of the
points the id pass reports."""

import numpy as np

from ..cubegi_engine import geometry
from ..cubegi_engine.errors import BakeError

# Per-view culling: the triangles are uploaded in spatial order (a Morton curve through
# their centroids) and cut into chunks of CULL_CHUNK; a view draws only the chunks whose
# bounding box reaches into its frustum (a cube face sees about a sixth of the scene
# around a probe). A scene of at most one chunk is drawn whole.
CULL_CHUNK = 2048
MAX_TRIANGLES = (1 << 24) - 1


def prepare(points, triangles, drawn, sheet, last_provokes=True):
    """The arrays a :class:`.gpu_capture.GpuRenderer` draws from; ``last_provokes``: whether
    the GPU takes a flat value from a triangle's last vertex (else its first)."""
    triangles = np.asarray(triangles)
    if len(triangles) > MAX_TRIANGLES:
        raise BakeError(f"the scene has {len(triangles)} triangles; capture supports up to {MAX_TRIANGLES}")
    pts = np.asarray(points, dtype=np.float64)
    lo, hi = (pts.min(axis=0), pts.max(axis=0)) if len(pts) else (np.zeros(3), np.ones(3))
    out = {"triangles": triangles, "centre": 0.5 * (lo + hi), "unit": max(float(np.max(hi - lo)), 1e-300)}
    unit_pts = ((pts - out["centre"]) / out["unit"]).astype(np.float32)
    drawn = np.arange(len(triangles)) if drawn is None else np.asarray(drawn, dtype=np.int64)
    sheet = np.zeros(len(triangles), dtype=bool) if sheet is None else np.asarray(sheet, dtype=bool)
    out["all_drawn"], out["sheet_all"], out["unit_points"] = drawn, sheet, unit_pts  # for render_colour
    twin = geometry.twin_triangles(unit_pts, triangles, sheet & np.isin(np.arange(len(triangles)), drawn))
    drawn = drawn[~(twin[drawn] >= 0) | (twin[drawn] > drawn)]  # a pair drawn once, as its first
    # A sheet's triangle with no twin here is drawn last, its back face culled.
    lone = sheet[drawn] & (twin[drawn] < 0)
    parts = (drawn[~lone], drawn[lone])
    t = len(drawn)
    # Drawn in spatial order, each part; a texel reports the drawn triangle's number, which
    # ``order`` maps back to the triangle (so nothing depends on the order).
    if t > CULL_CHUNK:
        parts = tuple(p[_spatial_order(unit_pts[triangles[p]].mean(axis=1))] if len(p) else p for p in parts)
    order = np.concatenate(parts)
    out["order"], out["twin"], out["drawn_count"], out["lone_from"] = order, twin, t, len(parts[0])
    indices, extra, owner = provoking_layout(triangles[order], len(unit_pts), last_provokes)
    out["indices"], out["pos"], out["tid"] = indices, np.concatenate([unit_pts, unit_pts[extra]]), owner.astype(np.float32)
    # Chunks of CULL_CHUNK triangles (one per part where the scene is small), never across parts.
    size = CULL_CHUNK if t > CULL_CHUNK else max(t, 1)
    starts = np.concatenate([np.arange(0, len(parts[0]), size), np.arange(len(parts[0]), t, size)]).astype(np.int64)
    out["chunk_starts"], out["chunk_ends"] = starts, np.append(starts[1:], t)
    out["chunk_boxes"] = _chunk_boxes(out["pos"][indices], starts) if t > CULL_CHUNK else None
    return out


def provoking_layout(triangles, count, last_provokes=True):
    """Indices over ``count`` vertices in which each triangle has a provoking vertex of its
    own (the vertex a flat value is taken from: the last or the first of its three). Each
    triangle takes one of its corners no other triangle took, where one is left, else a copy
    of a corner added at the end. Returns ``(indices (t, 3) int32, extra (e,): the vertex each
    added one copies, owner (count + e,) float: the triangle each vertex provokes, -1: none)``.
    The winding is kept (the corners turn, in order)."""
    tri = np.array(triangles, dtype=np.int64).reshape(-1, 3)  # a copy: its added corners are set below
    t = len(tri)
    owner = np.full(count, -1, dtype=np.int64)
    pick = np.full(t, -1, dtype=np.int64)  # the corner that provokes
    for j in range(3):
        free = np.flatnonzero(pick < 0)
        v = tri[free, j]
        untaken = owner[v] < 0
        free, v = free[untaken], v[untaken]
        taken, first = np.unique(v, return_index=True)  # one triangle per vertex
        owner[taken] = free[first]
        pick[free[first]] = j
    rest = np.flatnonzero(pick < 0)
    extra = tri[rest, 0]
    tri[rest, 0] = count + np.arange(len(rest))
    pick[rest] = 0
    owner = np.concatenate([owner, rest])
    turn = (1, 2, 0) if last_provokes else (0, 1, 2)  # the picked corner last (or first)
    rows = np.arange(t)
    indices = np.stack([tri[rows, (pick + k) % 3] for k in turn], axis=1)
    return indices.astype(np.int32), extra, owner


def barycentric_rows(points, triangles):
    """``(t, 4, 3)`` float64 per triangle (corners ``triangles (t, 3)`` into ``points``): its
    first corner ``a`` and the rows ``u1``, ``u2`` that give the weights of its second and third
    corners at a point ``p`` as ``(p - a) . u1`` and ``(p - a) . u2``, in its plane (a point off
    it: its projection), and their offsets (``(1/3, 1/3)`` with zero rows for a triangle of no
    area). Made once per renderer: each texel then costs a gather and two dot products."""
    a, b, c = (np.asarray(points[triangles[:, j]], dtype=np.float64) for j in range(3))
    e1, e2 = b - a, c - a
    d11, d12, d22 = (np.einsum("kc,kc->k", x, y) for x, y in ((e1, e1), (e1, e2), (e2, e2)))
    det = d11 * d22 - d12 * d12
    ok = det > 0
    safe = np.where(ok, det, 1.0)[:, None]
    rows = np.zeros((len(a), 4, 3))
    rows[:, 0] = np.where(ok[:, None], a, 0.0)
    rows[:, 1] = np.where(ok[:, None], (d22[:, None] * e1 - d12[:, None] * e2) / safe, 0.0)
    rows[:, 2] = np.where(ok[:, None], (d11[:, None] * e2 - d12[:, None] * e1) / safe, 0.0)
    rows[~ok, 3, :2] = 1.0 / 3.0
    return rows


def barycentric(rows, which, at):
    """``(k, 3)`` float32: the weights of the corners of triangles ``which (k,)`` (their
    :func:`barycentric_rows`) that make the points ``at (k, 3)``."""
    r = rows[which]
    rel = at - r[:, 0]
    w1 = np.einsum("kc,kc->k", rel, r[:, 1]) + r[:, 3, 0]
    w2 = np.einsum("kc,kc->k", rel, r[:, 2]) + r[:, 3, 1]
    return np.stack([1.0 - w1 - w2, w1, w2], axis=1).astype(np.float32)


# Each 10-bit coordinate with its bits spread 3 apart (bit k to bit 3k): a Morton code is
# three of them interleaved (a table look-up each, not 30 passes over the triangles).
_SPREAD = sum(((np.arange(1024, dtype=np.uint64) >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit) for bit in range(10))


def _spatial_order(centres):
    """An order of points ``(t, 3)`` along a Morton (Z-order) curve of a 1024^3 grid over
    their box: neighbours in space end up near each other in the order."""
    lo, hi = centres.min(axis=0), centres.max(axis=0)
    q = ((centres - lo) / np.maximum(hi - lo, 1e-30) * 1023.0).astype(np.uint64) & np.uint64(1023)  # (a NaN: its low bits)
    code = _SPREAD[q[:, 0]] | (_SPREAD[q[:, 1]] << np.uint64(1)) | (_SPREAD[q[:, 2]] << np.uint64(2))
    return np.argsort(code, kind="stable")


def _chunk_boxes(corners, starts):
    """The 8 corners ``(c, 8, 4)`` (homogeneous) of the box of each run of triangles
    ``corners (t, 3, 3)`` from each of ``starts (c,)`` to the next."""
    lo, hi = geometry.corner_box(corners)
    lo, hi = np.minimum.reduceat(lo, starts, axis=0), np.maximum.reduceat(hi, starts, axis=0)
    pick = np.array([[i >> 0 & 1, i >> 1 & 1, i >> 2 & 1] for i in range(8)], dtype=bool)  # (8, 3)
    xyz = np.where(pick[None], hi[:, None, :], lo[:, None, :]).astype(np.float64)
    return np.concatenate([xyz, np.ones(xyz.shape[:2] + (1,))], axis=2)


def boxes_in_frusta(boxes, view_projs):
    """``(v, c)`` bool: whether box ``c`` (its corners ``(c, 8, 4)``) may reach into view
    ``v``'s clip volume. A box is left out only where all its corners lie beyond one and the
    same clip plane (exact for a convex box: each plane is linear in homogeneous space)."""
    vps = np.asarray(view_projs, dtype=np.float64)
    step = max(1, 4_000_000 // (32 * len(boxes)))  # views at a time: clip coordinates of <= 32 MB
    seen = np.empty((len(vps), len(boxes)), dtype=bool)
    for first in range(0, len(vps), step):
        clip = np.einsum("vij,ckj->vcki", vps[first : first + step], boxes)  # (v, c, 8, 4)
        x, y, z, w = clip[..., 0], clip[..., 1], clip[..., 2], clip[..., 3]
        out = (x > w).all(-1) | (x < -w).all(-1) | (y > w).all(-1) | (y < -w).all(-1) | (z > w).all(-1) | (z < -w).all(-1)
        seen[first : first + step] = ~out
    return seen
