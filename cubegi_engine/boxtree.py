"""A tree of boxes over a scene's triangles, flat for a GPU compute shader to walk.

Pure numpy; must not import bpy. The add-on's ray caster
(:class:`cubegi_addon.gpu_rays.GpuRays`) uploads it and walks it in a compute shader; the
engine walks it in numpy (:func:`walk`) to test the shader's answers.

The tree is a linear bounding volume hierarchy (Lauterbach et al., "Fast BVH Construction on
GPUs", Eurographics 2009): the triangles sorted along a Morton curve through their centres,
and each node's run of them split where the highest bit of their codes changes (the middle
of the node's cell of the curve, as an octree would), down to runs of at most LEAF. Each
level is a few array operations over all of its nodes at once, so building it is a sort
and about thirty such steps (a second or two for 2.5M triangles). The nodes are kept in
depth-first order, each with where its subtree ends (a skip), so a shader walks it without
a stack: into a node's first child where the ray meets its box, else past its subtree.

On the Breakfast Room's sun rays a walk took 117 box and 25 triangle tests a ray; the same
triangles' leaves paired into a balanced tree took 271 and 62, and a tree split by surface
area (binned, 20 s to build in numpy) 52 and 10.

Everything is in float32 less the centre of the scene's box (a scene far from the origin
keeps the precision of one at it). A cut counts within EDGE_SLACK outside a triangle's
edges (no ray slips between two triangles along their shared edge), and each box is
widened by BOX_SLACK of the scene's size and rounded outwards, so that a ray the shader's
cut finds in a triangle is never kept out by its box.
"""

from dataclasses import dataclass

import numpy as np

__all__ = ["BoxTree", "build", "walk", "LEAF", "LARGEST", "FAR", "EDGE_SLACK"]

# Triangles a leaf holds at most. Of 2, 4 and 8, 4 took the Breakfast Room's sun rays fewest
# tests (box tests plus triangle tests: 2 took 148, 4 142 and 8 143).
LEAF = 4
# Morton bits per axis (30 in all, in an int64; 21 a axis changed the walks by under 3%).
MORTON_BITS = 10
# A cut counts within EDGE_SLACK (of barycentric weight) outside a triangle's edges: in
# float32 a ray along the edge two triangles share can miss both (a floor vertex's shadow ray
# along a cut plate's edge came out lit). Boxes are widened by BOX_SLACK of the scene's size,
# more than that (and float32 rounding of corners and cuts).
EDGE_SLACK = 1e-5
BOX_SLACK = 2e-5
# The shader reads node and triangle indices as float32, exact up to 2^24: a larger scene's
# tree is refused (its caster uses another).
LARGEST = 1 << 24


@dataclass(frozen=True)
class BoxTree:
    """A tree of ``m`` nodes in depth-first order, the root first.

    ``boxes (m, 2, 3)`` float32: each node's box (low, high corner); ``skip (m,)``: the node
    after its subtree (``m`` past the last); ``first (m,)``, ``count (m,)``: a leaf's run of
    triangle slots (``count`` 0 for an inner node, whose children are the next node and that
    node's skip). ``corners (t, 3, 3)`` float32: each slot's triangle as its first corner and
    its two edges from it (the shader's Moller-Trumbore test); ``order (t,)``: the caller's
    triangle index of each slot; ``centre (3,)`` float64: what every coordinate is less;
    ``scale``: the largest side of the triangles' box."""

    boxes: np.ndarray
    skip: np.ndarray
    first: np.ndarray
    count: np.ndarray
    corners: np.ndarray
    order: np.ndarray
    centre: np.ndarray
    scale: float = 0.0

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in (self.boxes, self.skip, self.first, self.count, self.corners, self.order)))


def _spread_bits(v):
    """Each of the low MORTON_BITS bits of ``v`` (int64) moved to every third bit."""
    v = v & 0x3FF
    v = (v | (v << 16)) & 0x030000FF
    v = (v | (v << 8)) & 0x0300F00F
    v = (v | (v << 4)) & 0x030C30C3
    return (v | (v << 2)) & 0x09249249


def morton_codes(centres, lo, hi):
    """``(t,)`` int64: the Morton code of each of ``centres (t, 3)`` in the box ``lo``-``hi``."""
    cells = (1 << MORTON_BITS) - 1
    span = np.maximum(hi - lo, 1e-300)
    q = np.clip(((centres - lo) / span * cells).astype(np.int64), 0, cells)
    return (_spread_bits(q[:, 0]) << 2) | (_spread_bits(q[:, 1]) << 1) | _spread_bits(q[:, 2])


def _split(codes, start, end):
    """Where each run ``start``-``end`` (more than LEAF slots) of sorted ``codes`` splits:
    at the first code with the highest bit in which the run's codes differ set; runs of one
    code in the middle."""
    x = codes[start] ^ codes[end - 1]
    bit = np.where(x > 0, np.floor(np.log2(np.maximum(x, 1))).astype(np.int64), 0)
    at = np.searchsorted(codes, ((codes[start] >> bit) | 1) << bit)
    return np.clip(np.where(x > 0, at, (start + end) // 2), start + 1, end - 1)


def build(points, triangles) -> BoxTree:
    """The :class:`BoxTree` of ``triangles (t, 3)`` (indices) over ``points (s, 3)``."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    t = len(triangles)
    if not t:
        none = np.zeros(0, dtype=np.int64)
        return BoxTree(np.zeros((0, 2, 3), np.float32), none, none, none, np.zeros((0, 3, 3), np.float32), none, np.zeros(3))
    used = points[triangles.ravel()]
    lo, hi = used.min(axis=0), used.max(axis=0)
    centre = 0.5 * (lo + hi)
    a = points[triangles[:, 0]] - centre
    b = points[triangles[:, 1]] - centre
    c = points[triangles[:, 2]] - centre
    codes = morton_codes((a + b + c) / 3.0, lo - centre, hi - centre)
    order = np.argsort(codes, kind="stable")
    codes, a, b, c = codes[order], a[order], b[order], c[order]
    corners = np.stack([a, b - a, c - a], axis=1).astype(np.float32)
    # The nodes level by level: each run of more than LEAF slots splits in two.
    start, end = np.zeros(1, dtype=np.int64), np.full(1, t, dtype=np.int64)
    starts, ends, depths = [start], [end], [np.zeros(1, dtype=np.int64)]
    while True:
        inner = end - start > LEAF
        if not inner.any():
            break
        start, end = start[inner], end[inner]
        at = _split(codes, start, end)
        start, end = np.concatenate([start, at]), np.concatenate([at, end])
        starts.append(start)
        ends.append(end)
        depths.append(np.full(len(start), len(depths), dtype=np.int64))
    start, end, depth = np.concatenate(starts), np.concatenate(ends), np.concatenate(depths)
    pre = np.lexsort((start - end, start))  # depth-first: by start, a node before its first child
    start, end, depth = start[pre], end[pre], depth[pre]
    skip = np.searchsorted(start, end)  # the first node past the subtree starts where it ends
    leaf = end - start <= LEAF
    slack = BOX_SLACK * float(np.max(hi - lo)) + 4.0 * np.finfo(np.float32).eps * float(np.max(np.abs(lo - centre)))
    low, high = np.empty((len(start), 3)), np.empty((len(start), 3))
    low[leaf] = np.minimum.reduceat(np.minimum(np.minimum(a, b), c), start[leaf], axis=0) - slack
    high[leaf] = np.maximum.reduceat(np.maximum(np.maximum(a, b), c), start[leaf], axis=0) + slack
    for d in range(int(depth.max()), -1, -1):  # an inner node's box holds its two children's
        at = np.flatnonzero(~leaf & (depth == d))
        left, right = at + 1, skip[at + 1]
        low[at] = np.minimum(low[left], low[right])
        high[at] = np.maximum(high[left], high[right])
    # float32 boxes rounded outwards, so that they still hold the float32 corners.
    low32, high32 = low.astype(np.float32), high.astype(np.float32)
    low32 = np.where(low32 > low, np.nextafter(low32, np.float32(-np.inf)), low32)
    high32 = np.where(high32 < high, np.nextafter(high32, np.float32(np.inf)), high32)
    return BoxTree(np.stack([low32, high32], axis=1), skip, np.where(leaf, start, 0), np.where(leaf, end - start, 0), corners,
                   order, centre, float(np.max(hi - lo)))


def walk(tree: BoxTree, origins, dirs, reach=None, any_hit=False):
    """``(which (n,), t (n,))``: each ray's nearest hit among ``tree``'s triangles (the caller's
    index of the triangle, -1 for none; of two at one distance the lower) as the compute
    shader walks the tree, in float32, one ray at a time (tests: the shader's reference; slow). ``origins``
    and ``dirs`` are in the caller's frame; ``reach (n,)`` or None; ``any_hit``: stop at the
    first hit found (a shadow ray)."""
    origins = (np.asarray(origins, dtype=np.float64).reshape(-1, 3) - tree.centre).astype(np.float32)
    dirs = np.asarray(dirs, dtype=np.float32).reshape(-1, 3)
    n = len(origins)
    limit = np.full(n, FAR, dtype=np.float32) if reach is None else np.broadcast_to(np.asarray(reach, dtype=np.float32), (n,))
    which, ts = np.full(n, -1, dtype=np.int64), np.full(n, np.inf)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for i in range(n):
            which[i], ts[i] = _walk_one(tree, origins[i], dirs[i], limit[i], any_hit)
    return which, ts


# A ray with no reach reaches this far (float32).
FAR = 3.0e38


def _walk_one(tree, o, d, limit, any_hit):
    """One ray through the tree, as the shader's ``main`` (see gpu_rays)."""
    inv = np.float32(1.0) / np.where(np.abs(d) < 1e-30, np.float32(1e-30), d)
    best, best_t = -1, np.float32(limit)
    node = 0
    while node < len(tree.skip):
        t0 = (tree.boxes[node, 0] - o) * inv
        t1 = (tree.boxes[node, 1] - o) * inv
        enter = max(np.minimum(t0, t1).max(), np.float32(0.0))
        leave = min(np.maximum(t0, t1).min(), best_t)
        count = tree.count[node]
        if enter <= leave and count == 0:
            node += 1
            continue
        if enter <= leave:
            for k in range(tree.first[node], tree.first[node] + count):
                t = _cut(tree.corners[k], o, d)
                index = int(tree.order[k])
                if t is not None and (t < best_t or (t == best_t and (best < 0 or index < best))):
                    best, best_t = index, t
            if any_hit and best >= 0:
                break
        node = node + 1 if count else tree.skip[node]
    return best, (float(best_t) if best >= 0 else np.inf)


def _cut(corner, o, d):
    """Moller-Trumbore in float32 (as the shader): the distance to the cut, or None."""
    a, e1, e2 = corner
    p = np.cross(d, e2)
    det = np.float32(np.dot(e1, p))
    if abs(det) < 1e-30:
        return None
    s = o - a
    u = np.dot(s, p) / det
    q = np.cross(s, e1)
    v = np.dot(d, q) / det
    t = np.dot(e2, q) / det
    if u >= -EDGE_SLACK and v >= -EDGE_SLACK and u + v <= 1 + EDGE_SLACK and t > 0:
        return np.float32(t)
    return None
