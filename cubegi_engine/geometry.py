"""Rays against triangles (the one kernel, :func:`ray_cut`: the shadow maps' and the probes'
cover tests, the near field's and the placement's rays), and points near triangles. Pure
numpy; must not import bpy."""

import numpy as np

from . import working

__all__ = ["sorted_unique", "run_offsets", "triangle_planes", "planes_of", "cross", "ray_cut", "cut_planes", "cuts_ahead", "cut_triangles",
           "listed_ranks", "near_any_triangle", "edge_neighbours", "chunks", "POINT_CHUNK", "GRAZING", "twin_triangles", "mix64", "sorted_columns",
           "position_hash", "corner_box", "corner_triangles", "triangles_at", "in_box", "all_three",
           "first_of_twins"]

# Per-point tests that make several (s, 9, 3) float64 arrays run this many points at a time:
# a million points then need tens of megabytes, not gigabytes, and stay in cache.
POINT_CHUNK = 65536


def chunks(count, size=POINT_CHUNK):
    """Slices that cover ``range(count)`` in pieces of ``size``."""
    return [slice(start, start + size) for start in range(0, count, size)]


# The smallest piece :func:`in_pieces` cuts (below it, numpy's per-call overhead dominates).
MIN_PIECE = 4096


def piece_size(size=POINT_CHUNK):
    """What :func:`in_pieces` cuts ``size`` into: one share per worker thread, at least
    MIN_PIECE (``size`` itself with one worker)."""
    return min(size, max(MIN_PIECE, -(-size // working.WORKERS)))


def in_pieces(fn, count, size=POINT_CHUNK, least=MIN_PIECE):
    """``[fn(sl) for sl in slices]`` over slices covering ``range(count)``, run on the
    worker threads (:func:`~.working.in_parallel`): one share of ``count`` per worker, but
    no more than :func:`piece_size` (what is in memory at once stays about one piece of
    ``size``) and no fewer than ``least`` (work that costs much per item can take less)."""
    share = -(-count // working.WORKERS)
    return working.in_parallel(fn, chunks(count, max(1, min(piece_size(size), max(least, share)))))


# The one ray-triangle kernel (:func:`ray_cut`) and its tolerances. A test that compares a
# cut's distance with a depth map's (the shadow maps, the probes' cover test) takes no cut
# within GRAZING (a cosine: 0.06 degrees) of a triangle's plane, whose distance along the ray
# is ill-conditioned: the map's own depth decides there; a cut counts inside the exact
# triangle. A ray that asks for its nearest hit within a reach (the near field's, the
# placement's: spatial.intersect_pairs) takes every cut of a triangle of some area (grazing
# 0), counts a cut within BARY_SLACK outside the triangle's edges, and a front face before a
# back face as near (spatial.TIE).
GRAZING = 1e-3


def sorted_unique(keys):
    """``np.unique`` of an int array, by a stable sort (timsort takes the sorted runs that
    (point, triangle) keys come in; numpy 2's hashed unique is tens of times slower on
    millions of keys)."""
    keys = np.sort(keys, kind="stable")
    return keys[np.concatenate([[True], keys[1:] != keys[:-1]])] if len(keys) else keys


def run_offsets(count):
    """``(sum(count),)``: ``0 .. count[i] - 1`` for each run ``i``, one run after another (with
    ``np.repeat(start, count)``, the indices of every run ``start[i] ..``)."""
    count = np.asarray(count, dtype=np.int64)
    return np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)


def corner_triangles(triangles, count):
    """``(start (s,), per (s,), members (3t,))``: each of ``count`` points' triangles, listed
    under their corners point by point (point ``i``'s are ``members[start[i]:][:per[i]]``)."""
    corners = np.asarray(triangles, dtype=np.int64).ravel()
    per = np.bincount(corners, minlength=count)
    return np.cumsum(per) - per, per, np.argsort(corners, kind="stable") // 3


def triangles_at(runs, at):
    """``(triangles, per)``: the triangles at each of points ``at`` (``runs``:
    :func:`corner_triangles`), one point's after another, and how many each has."""
    start, per, members = runs
    per = per[at]
    return members[np.repeat(start[at], per) + run_offsets(per)], per


def in_box(x, lo, hi):
    """``(...)`` bool: whether each point ``x (..., 3)`` lies in the box ``lo, hi`` (each
    ``(..., 3)``, broadcast against ``x``), bounds included; a coordinate at a time (numpy's
    ``np.all`` over an axis of three took 5-10 times as long: 8.3 -> 0.8 ms for 200K points)."""
    out = (x[..., 0] >= lo[..., 0]) & (x[..., 0] <= hi[..., 0])
    for j in (1, 2):
        out &= (x[..., j] >= lo[..., j]) & (x[..., j] <= hi[..., j])
    return out


def all_three(mask):
    """``np.all(mask, axis=-1)`` of a ``(..., 3)`` bool array, a column at a time (see in_box)."""
    return mask[..., 0] & mask[..., 1] & mask[..., 2]


def corner_box(corners):
    """``(lo, hi)``, each ``(t, 3)``: the box of each triangle's corners ``(t, 3, 3)``, by
    elementwise minimum and maximum (the same numbers as ``corners.min(axis=1)``; numpy's
    reduction over an axis of three took twice as long: 0.76 -> 0.37 s at 2.7M triangles)."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    return np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)


def triangle_planes(triangles, vertices):
    """:func:`planes_of` the triangles ``(t, 3)`` (indices into ``vertices``)."""
    tri = np.asarray(triangles).reshape(-1, 3)
    return planes_of(vertices[tri[:, 0]], vertices[tri[:, 1]], vertices[tri[:, 2]])


def planes_of(a, b, c):
    """``(t, 4, 3)``: per triangle of corners ``a, b, c`` (each ``(t, 3)``) its first corner
    ``a``, its unit normal, and the gradients ``g1, g2`` of its barycentric coordinates: a
    point ``x`` of its plane has the weights ``(x - a) . g1`` of its second corner and
    ``(x - a) . g2`` of its third. All zero but ``a`` for a triangle of no area."""
    e1, e2 = b - a, c - a
    n = cross(e1, e2)
    area2 = np.einsum("tc,tc->t", n, n)
    inv = np.divide(1.0, area2, out=np.zeros_like(area2), where=area2 > 0)[:, None]
    out = np.empty((len(a), 4, 3), dtype=np.result_type(a, n, inv))
    out[:, 0] = a
    np.multiply(n, np.sqrt(inv), out=out[:, 1])
    np.multiply(cross(e2, n), inv, out=out[:, 2])
    np.multiply(cross(n, e1), inv, out=out[:, 3])
    return out


def cross(a, b):
    """``np.cross`` of ``(..., 3)`` vectors, by components (half the time of ``np.cross``,
    whose axis handling costs as much as its arithmetic: the planes of a million triangles)."""
    a, b = np.asarray(a), np.asarray(b)
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), dtype=np.result_type(a, b))
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    np.multiply(a1, b2, out=out[..., 0])
    out[..., 0] -= a2 * b1
    np.multiply(a2, b0, out=out[..., 1])
    out[..., 1] -= a0 * b2
    np.multiply(a0, b1, out=out[..., 2])
    out[..., 2] -= a1 * b0
    return out


def cut_planes(origins, u, tid, planes):
    """Where the rays ``origins + t u`` cut the planes of triangles ``tid``.

    origins, u: ``(..., 3)`` (u unit); tid: ``(...)`` triangle index, -1 for none; planes:
    :func:`triangle_planes` of every triangle. Returns ``(t, inside)``: the distance along
    each ray (nan where there is no triangle or the ray grazes its plane, within 1e-3 of
    parallel) and whether the cut lies inside the triangle.
    """
    tid = np.asarray(tid)
    t, b, c, ok, _ = ray_cut(origins, u, planes, tid >= 0, tid=tid)
    return t, ok & (b >= 0) & (c >= 0) & (b + c <= 1)


def cuts_ahead(origins, u, tid, planes, depth):
    """``(ahead, inside)``: whether the rays ``origins + t u`` cut the planes of triangles
    ``tid`` ahead of them, ``0 < t < depth``, and whether that cut lies inside the triangle
    (False where not ahead): :func:`cut_planes`, the corners' weights worked out only for
    the cuts ahead (a probe's cover test: a quarter of the triangles seen around a point lie
    in front of it)."""
    def is_ahead(t, _front):
        return (t > 0) & (t < depth)

    t, b, c, ok, _ = ray_cut(origins, u, planes, tid >= 0, tid=tid, wanted=is_ahead)
    ahead = ok & is_ahead(t, None)
    return ahead, ahead & (b >= 0) & (c >= 0) & (b + c <= 1)


def cut_triangles(origins, u, tid, triangles, vertices):
    """:func:`cut_planes` for triangles given by corners: the planes of ``tid`` alone are
    made (for a few rays against many triangles)."""
    tid = np.asarray(tid)
    safe = np.maximum(tid, 0)
    if 8 * safe.size < len(triangles):  # each plane made once (receivers in one texel share its triangles)
        seen, local = np.unique(safe, return_inverse=True)
        return cut_planes(origins, u, np.where(tid >= 0, local.reshape(tid.shape), -1), triangle_planes(triangles[seen], vertices))
    # Many rays: each triangle's plane made once (a shadow map's receivers share few).
    listed, local = listed_ranks(safe, len(triangles))
    return cut_planes(origins, u, np.where(tid >= 0, local[safe], -1), triangle_planes(triangles[listed], vertices))


def listed_ranks(keys, count):
    """``(listed (count,) bool, rank (count,))``: which of ``0 .. count - 1`` occur in ``keys``
    (non-negative ints, any shape) and each one's place among those that do:
    ``np.unique(keys, return_inverse=True)``'s inverse is ``rank[keys]``, found by flags
    instead of a sort."""
    listed = np.zeros(count, dtype=bool)
    listed[keys] = True
    return listed, np.cumsum(listed) - 1


def ray_cut(origins, u, planes, present=True, grazing=GRAZING, tid=None, wanted=None):
    """The one ray-triangle kernel: where rays ``origins + t u`` (``(..., 3)``, ``u`` unit)
    cut the planes of their triangles (:func:`planes_of`, ``(..., 4, 3)``; with ``tid
    (m,)``, every triangle's, the rays' being ``tid``, gathered only as far as asked).
    Returns ``(t, b, c, ok, front)``: the distance along each ray (nan where not ``ok``), the
    barycentric weights of the cut's second and third corners, whether the ray cuts the
    plane at all (a triangle ``present``, of some area, not within ``grazing`` of parallel:
    see :data:`GRAZING`), and whether it meets the triangle's front. ``wanted(t, front)``
    (paired rays, ``(m,)``): the cuts whose weights are asked, zeros elsewhere (most of a
    test's cuts lie out of its range: its weights cost as much as the cut)."""
    if tid is not None:
        safe = np.maximum(tid, 0)
        a, n = planes[safe, 0], planes[safe, 1]
    else:
        a, n = planes[..., 0, :], planes[..., 1, :]
    denom = np.einsum("...c,...c->...", u, n)
    ok = present & (np.abs(denom) > grazing)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("...c,...c->...", a - origins, n) / np.where(ok, denom, 1.0)
        if wanted is None:
            x = origins + t[..., None] * u - a
            g1, g2 = (planes[..., 2, :], planes[..., 3, :]) if tid is None else (planes[safe, 2], planes[safe, 3])
            return np.where(ok, t, np.nan), np.einsum("...c,...c->...", x, g1), np.einsum("...c,...c->...", x, g2), ok, denom < 0
    t, front = np.where(ok, t, np.nan), denom < 0
    k = np.flatnonzero(wanted(t, front))
    x = origins[k] + t[k, None] * u[k] - a[k]
    rows = k if tid is None else safe[k]
    b, c = np.zeros(len(t)), np.zeros(len(t))
    b[k] = np.einsum("...c,...c->...", x, planes[rows, 2])
    c[k] = np.einsum("...c,...c->...", x, planes[rows, 3])
    return t, b, c, ok, front


def near_any_triangle(centres, radius, a, b, c, tiles=8, centre_normals=None, across=None, least=False, apart=0.0, facing=None):
    """``(m,)`` bool: whether each of ``centres (m, 3)`` may lie within ``radius`` of any of
    the triangles ``a, b, c`` (each ``(k, 3)``). Conservative: the point is within ``radius``
    of the triangle's plane and its box and, projected onto it, within ``radius`` of the
    inside of every edge (near a sharp corner this takes in more than the true distance would). The
    centres are tested tile by tile (about ``tiles`` along the longest side, no smaller than
    eight radii) against the triangles whose boxes reach the tile. With ``centre_normals``
    ``(m, 3)`` and ``across``, a triangle counts for a centre only where the cosine between
    their normals is below ``across`` in magnitude (it runs across the centre's surface).
    ``least``: also ``(m,)`` the least index of such a triangle for each centre (-1: none).
    ``apart``: a triangle counts only where the centre lies farther than this from its plane
    (not in it: a panel set into a ceiling is not in front of the ceiling around it); with
    ``centre_normals`` and ``facing``, only where the cosine between their normals is at
    least ``facing`` in magnitude (it faces the centre's surface)."""
    m = len(centres)
    out = np.zeros(m, dtype=bool)
    found = np.full(m, len(a), dtype=np.int64)
    tri = _Near(a, b, c, radius, apart)
    if not m or not len(tri.a):
        return (out, np.full(m, -1, dtype=np.int64)) if least else out
    lo = centres.min(axis=0)
    edge = max(float(np.max(centres.max(axis=0) - lo)) / tiles, 8.0 * radius, 1e-300)
    tile = np.floor((centres - lo) / edge).astype(np.int64)
    ids, which = np.unique(tile, axis=0, return_inverse=True)
    which = which.ravel()
    order = np.argsort(which, kind="stable")
    bounds = np.searchsorted(which[order], np.arange(len(ids) + 1))
    # Each triangle's box, walked in tiles: (tile, triangle) pairs, by tile.
    shape = ids.max(axis=0) + 1
    first = np.clip(np.ceil((tri.box_lo - lo) / edge) - 1, 0, shape - 1).astype(np.int64)
    span = np.maximum(np.clip(np.floor((tri.box_hi - lo) / edge), -1, shape - 1).astype(np.int64) - first + 1, 0)
    count = np.prod(span, axis=1)
    k = np.repeat(np.arange(len(count)), count)
    step = run_offsets(count)
    at = first[k] + np.stack([step % span[k, 0], (step // span[k, 0]) % span[k, 1], step // (span[k, 0] * span[k, 1])], axis=1)
    tiles_at = np.searchsorted(np.ravel_multi_index(ids.T, shape), np.ravel_multi_index(at.T, shape))
    occupied = all_three(ids[np.minimum(tiles_at, len(ids) - 1)] == at)
    k, tiles_at = k[occupied], tiles_at[occupied]
    by_tile = np.argsort(tiles_at, kind="stable")
    k = k[by_tile]
    tile_bounds = np.searchsorted(tiles_at[by_tile], np.arange(len(ids) + 1))
    for t in range(len(ids)):
        sel = k[tile_bounds[t] : tile_bounds[t + 1]]
        if not len(sel):
            continue
        cells = order[bounds[t] : bounds[t + 1]]
        pts = centres[cells]
        # The boxes (and the normals) first, over every pair; the planes and edges over the
        # pairs left (few: a tile's triangles' boxes hold few of its centres each).
        near = in_box(pts[:, None, :], tri.box_lo[None, sel], tri.box_hi[None, sel])
        if centre_normals is not None:
            cosine = np.abs(centre_normals[cells] @ tri.n[sel].T)
            if across is not None:
                near &= cosine < across
            if facing is not None:
                near &= cosine >= facing
        pi, ki = np.nonzero(near)
        hit = tri.near(pts[pi], sel[ki])
        out[cells[pi[hit]]] = True
        np.minimum.at(found, cells[pi[hit]], tri.index[sel[ki[hit]]])
    return (out, np.where(out, found, -1)) if least else out


class _Near:
    """The triangles ``a, b, c`` that :func:`near_any_triangle` tests (the degenerate ones
    left out): their unit normals, edges' inward directions and boxes grown by ``radius``."""

    def __init__(self, a, b, c, radius, apart=0.0):
        n = cross(b - a, c - a)
        length = np.linalg.norm(n, axis=1)
        keep = length > 0
        self.index = np.flatnonzero(keep)  # each one's place among those given
        self.a, self.b, self.c, self.n = a[keep], b[keep], c[keep], n[keep] / length[keep, None]
        self.radius, self.apart = radius, apart
        self.edges = [(self.a, self.b), (self.b, self.c), (self.c, self.a)]
        self.inward = []  # inward unit directions of the three edges, in the plane
        for p, q in self.edges:
            d = cross(self.n, q - p)
            self.inward.append(d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300))
        self.box_lo = np.minimum(np.minimum(self.a, self.b), self.c) - radius
        self.box_hi = np.maximum(np.maximum(self.a, self.b), self.c) + radius

    def near(self, x, k):
        """``(p,)`` bool: whether each point ``x (p, 3)`` (within triangle ``k (p,)``'s box) lies
        within the radius of its plane (and farther than ``apart``) and of the inside of each
        of its edges."""
        r = self.radius
        height = np.abs(np.einsum("pc,pc->p", x - self.a[k], self.n[k]))
        ok = (height <= r) & (height > self.apart) if self.apart > 0 else height <= r
        for (p, _), d in zip(self.edges, self.inward):
            ok &= np.einsum("pc,pc->p", x - p[k], d[k]) >= -r
        return ok


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


def inward(triangles, vertices) -> np.ndarray:
    """``(v, 3)``: for each vertex, the mean of the unit vectors from it to the middles of its
    triangles: about nothing inside a surface, up to a unit pointing away from the edge on a
    surface's edge or corner. A triangle with no extent at a corner (all three corners in one
    place) adds nothing there, not a unit vector in a direction of rounding."""
    count = len(vertices)
    corners = [vertices[triangles[:, k]] for k in range(3)]
    middle = (corners[0] + corners[1] + corners[2]) / 3.0
    slack = 1e-9 * np.abs(middle).max(axis=1, initial=0.0) + 1e-300
    total = np.zeros((count, 3))
    for k in range(3):
        to = middle - corners[k]
        length = np.sqrt(np.einsum("tc,tc->t", to, to))
        to *= np.where(length > slack, 1.0 / np.maximum(length, 1e-300), 0.0)[:, None]
        for c in range(3):
            total[:, c] += np.bincount(triangles[:, k], to[:, c], count)
    return total / np.maximum(np.bincount(triangles.ravel(), None, count), 1)[:, None]


def twin_triangles(points, triangles, sheet):
    """Each triangle's twin (``(t,)``, -1: none): among ``sheet`` triangles, the other one of
    a pair over the same three positions, wound the other way. Exact positions (the twins
    are copies), hashed."""
    t = len(triangles)
    twin = np.full(t, -1, dtype=np.int64)
    ids = np.flatnonzero(sheet)
    if len(ids) < 2:
        return twin
    points = np.asarray(points)
    if len(points) < 3 * len(ids):  # each position hashed once (a vertex is the corner of several)
        corner = position_hash(points)[triangles[ids]]  # (k, 3)
    else:
        corner = position_hash(points[triangles[ids]].reshape(-1, 3)).reshape(-1, 3)
    low, mid, high = sorted_columns(corner)
    key = mix64(mix64(mix64(low) ^ mid) ^ high)
    del low, mid, high
    order = np.argsort(key, kind="stable")
    k = key[order]
    pair = np.flatnonzero((k[1:] == k[:-1]) & np.append(k[2:] != k[1:-1], True) & np.insert(k[1:-1] != k[:-2], 0, True))
    a, b = order[pair], order[pair + 1]
    # Same corners (not just the same hash), and wound the other way: b's corners are a's in
    # a reversed cycle.
    match = (corner[b][:, None, :] == corner[a][:, :, None])  # (m, 3 of a, 3 of b)
    same = match.any(axis=2).all(axis=1) & match.any(axis=1).all(axis=1)
    where = np.argmax(match, axis=2)  # a's corner j is b's corner where[j]
    reversed_ = (where[:, 1] - where[:, 0]) % 3 == 2
    a, b = a[same & reversed_], b[same & reversed_]
    twin[ids[a]], twin[ids[b]] = ids[b], ids[a]
    return twin


def first_of_twins(twin, among):
    """The triangles of ``among`` (indices) with each twin pair (``twin``, see
    :func:`twin_triangles`) taken once, as its first: what a caster meeting both sides of a
    triangle needs of a two-sided object."""
    among = np.asarray(among, dtype=np.int64)
    return among[(twin[among] < 0) | (twin[among] > among)]


def sorted_columns(triples):
    """``(low, middle, high)``, each ``(k,)``: the three integers of each row of ``triples (k,
    3)`` in order (min and max, the middle one by XOR: np.sort along an axis of three is
    several times slower)."""
    a, b, c = triples[:, 0], triples[:, 1], triples[:, 2]
    low, high = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
    return low, a ^ b ^ c ^ low ^ high, high


def mix64(x):
    """SplitMix64's finaliser (every input bit moves every output bit)."""
    x = x ^ (x >> np.uint64(30))
    x = x * np.uint64(0xBF58476D1CE4E5B9)
    x = x ^ (x >> np.uint64(27))
    x = x * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def position_hash(p):
    """``(n,)`` uint64: a hash of each float32 position's exact bits."""
    bits = (np.ascontiguousarray(p, dtype=np.float32) + np.float32(0.0)).view(np.uint32).astype(np.uint64)
    return mix64(mix64(mix64(bits[:, 0]) ^ bits[:, 1]) ^ bits[:, 2])
