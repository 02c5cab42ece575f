"""Which probes light a point: the trilinear weights of a grid (:mod:`.grid`) with the
probes that cannot see the point, or stand behind it, left out (:func:`visibility_weights`),
and the test of a triangle of another object between a probe and a point (:class:`Cover`).

Pure numpy; must not import bpy.
"""

from dataclasses import dataclass, replace

import numpy as np

from . import cubemap
from .geometry import chunks, cuts_ahead, edge_neighbours, first_of_twins, in_pieces, piece_size, sorted_unique, triangle_planes, twin_triangles
from .rays import RayCaster

__all__ = ["visibility_weights", "probes_in_front", "seen_corners_only", "Cover", "CastCover", "Probes", "PointProbes", "ProbeWeights", "BEHIND",
           "seen_from_behind"]


@dataclass(frozen=True)
class Probes:
    """The probes as captured: ``positions (p, 3)``, ``dist (p, 6, n, n)`` each texel's
    distance to the first surface (inf where the probe sees sky), ``valid (p,)`` bool."""

    positions: np.ndarray
    dist: np.ndarray
    valid: np.ndarray


@dataclass(frozen=True)
class PointProbes:
    """Points (``points``, ``normals`` ``(s, 3)``) with their 8 probes and trilinear weights
    (``index``, ``weight`` ``(s, 8)``: :meth:`ProbeGrid.trilinear`)."""

    points: np.ndarray
    normals: np.ndarray
    index: np.ndarray
    weight: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def __getitem__(self, which) -> "PointProbes":
        return PointProbes(self.points[which], self.normals[which], self.index[which], self.weight[which])


@dataclass(frozen=True)
class ProbeWeights:
    """Which probes light each point, and how much: ``weights (s, 8)`` over its 8 probes
    (normalised; zeros where none does); ``behind (s, 8)``, where asked for: the weights
    with which a point that no probe in front of it sees keeps the probes behind its plane
    that see it (else as ``weights``)."""

    weights: np.ndarray
    behind: np.ndarray | None = None


@dataclass(frozen=True)
class _Texels:
    """Each (point, probe) pair's texel towards the point: ``face``, ``row``, ``col`` ``(s, 8)``
    on cube faces of edge ``n``."""

    face: np.ndarray
    row: np.ndarray
    col: np.ndarray
    n: int

    def __getitem__(self, which) -> "_Texels":
        return _Texels(self.face[which], self.row[which], self.col[which], self.n)


# How far behind a point's tangent plane (in cells) a probe may stand and still light it.
BEHIND = 0.1


def probes_in_front(probe_pos, probe_valid, points, normals, index, weight):
    """``(s, 8)``: the weights ``weight`` of each point's valid probes in front of its
    tangent plane, whether they see it or not, normalised (zeros where there is none)."""
    height = np.einsum("skc,sc->sk", probe_pos[index] - points[:, None, :], normals)
    w = weight * probe_valid[index] * (height > 0)
    return w / np.maximum(w.sum(axis=1, keepdims=True), 1e-300)


def visibility_weights(grid, probes: Probes, at: PointProbes, cover=None, both=False, sheet=None) -> ProbeWeights:
    """Trilinear weights with probes that cannot see a point, or are invalid, left out.

    A probe is kept for a point if the point, lifted off its surface along the normal by a
    tenth of the smallest cell edge, is no farther from the probe than the first surface the
    probe's cube map records in that direction (the depth test of a shadow map), and the
    probe stands no more than BEHIND cells behind the point's tangent plane. This stops
    light leaking through walls thinner than a cell, and round convex edges (a probe just
    above a block's sunlit top would light the block's sides with it). If every probe of a
    point is left out, the point keeps its plain trilinear weights over the valid probes in
    front of its surface; with none, it gets no probe light (a block's underside below the
    lowest probes: the near field lights it). With ``both``, also the weights where such a
    point keeps the probes behind its plane that see it (:attr:`ProbeWeights.behind`).

    ``probes``: the probes as captured; ``at``: the points and their probes. Returns a
    :class:`ProbeWeights`.

    ``cover`` (a :class:`Cover` of the triangles the probes drew) adds a
    test the depth map's tolerance is too coarse for: a triangle of another object (or of
    the same object, facing away from the point: the far side of a thin wall) that the
    probe's texel sees towards the point, whose plane the exact ray from the probe crosses
    in front of the point, inside that triangle, covers the point (a rug over a floor, a
    thin wall between rooms). A point that every probe misses and some other object covers
    gets no probe light, instead of falling back to its plain weights. ``sheet``: ``(s,)``
    bool, points of two-sided sheets, which only probes in front of their plane light.
    """
    if len(at) > piece_size():
        parts = in_pieces(lambda sl: visibility_weights(grid, probes, at[sl], None if cover is None else cover.rows(sl), both,
                                                        None if sheet is None else sheet[sl]), len(at))
        weights = np.concatenate([p.weights for p in parts])
        return ProbeWeights(weights, np.concatenate([p.behind for p in parts]) if both else None)
    points, normals, index, weight = at.points, at.normals, at.index, at.weight
    cell = grid.point_cell_edge(points)[:, None]  # (s, 1)
    visible, texels = _depth_test(probes, at, cell)
    eyes = probes.positions[index]
    # How far each probe stands in front of the point's tangent plane.
    height = np.einsum("skc,sc->sk", eyes - points[:, None, :], normals)
    if sheet is not None:
        # A point of a two-sided sheet: a probe behind its plane is on the sheet's other side,
        # whose own twin point it lights (the depth test cannot tell the two apart).
        visible &= ~sheet[:, None] | (height > 0)
    valid = probes.valid[index]
    hidden = np.zeros(len(at), dtype=bool)
    if cover is not None:
        # The pairs that light the point are asked first; a point that none of them lights
        # after that is dark if any other probe's ray to it is covered too (see ``dark``).
        ask = visible & valid & (weight > 0)
        covered = _covered(cover, at, eyes, texels, cell, ask)
        visible &= ~covered
        hidden = covered.any(axis=1)
        # (The other pairs light no point whatever their cover: only whether one is covered counts.)
        unlit = np.flatnonzero((weight * (ask & ~covered)).sum(axis=1) <= 1e-9)
        hidden[unlit] |= _any_covered(cover.rows(unlit), at[unlit], eyes[unlit], texels[unlit], cell[unlit], ~ask[unlit])
    # A probe more than BEHIND cells behind the point's tangent plane sees its hemisphere from
    # the far side: at a convex edge nothing hides it.
    seen_by = weight * (visible & valid)
    w = seen_by * (height >= -BEHIND * cell)
    total = w.sum(axis=1, keepdims=True)
    # A point no probe sees takes the valid probes in front of its surface (a vertex in a
    # corner too tight for the grid); none behind it (the outer face of a wall, whose probes
    # are all inside the room: their light would leak out).
    fallback = probes_in_front(probes.positions, probes.valid, points, normals, index, weight)
    dark = (seen_by.sum(axis=1) <= 1e-9) & hidden  # no probe, on either side, sees it

    def settled(fallback):
        out = np.where(total > 1e-9, w, fallback)
        out = out / np.maximum(out.sum(axis=1, keepdims=True), 1e-300)  # a point with no probe at all keeps zeros
        out[dark] = 0.0
        return out

    if not both:
        return ProbeWeights(settled(fallback))
    return ProbeWeights(settled(fallback), settled(np.where(fallback.sum(axis=1, keepdims=True) > 1e-9, fallback, seen_by)))


def seen_corners_only(bary, corners, covered):
    """``bary (p, t, 3)`` (each texel's barycentric weights of its triangle's ``corners (p,
    t, 3)``) with the weight of the corners no probe sees (``covered (s,)``) moved to the
    triangle's other corners, in their proportions (evenly where they had none).

    A covered corner's light is that of the side no probe sees: a ceiling point 1 cm above
    a lamp has the light trapped in the gap, a floor point under a wall the light inside
    the wall. The part of its triangle a probe does see lies on the seen corners' side, so
    it takes their light, not a blend that carries the hidden side's (the gap's light
    spread along every ceiling triangle around the lamp; the thin wall's floor and walls
    darkened towards the dark inside of the partition)."""
    if not covered.any():
        return bary
    hidden = covered[corners]  # (p, t, 3)
    mixed = hidden.any(axis=-1) & ~hidden.all(axis=-1)
    if not mixed.any():
        return bary
    b, h = bary[mixed], hidden[mixed]
    total = b.sum(axis=-1, keepdims=True)
    seen = np.where(h, 0.0, b)
    share = seen.sum(axis=-1, keepdims=True)
    even = (~h).astype(np.float32) / (~h).sum(axis=-1, keepdims=True)
    out = bary.copy()
    out[mixed] = np.where(share > 1e-6, seen / np.maximum(share, 1e-30), even) * total
    return out


def _depth_test(probes: Probes, at: PointProbes, cell):
    """The shadow-map test of :func:`visibility_weights`: ``(visible (s, 8) bool, texels)``,
    whether each point lifted off its surface by a tenth of its cell edge ``cell (s, 1)`` is
    no farther from its probe than the first surface that probe's texel towards it records,
    and that texel."""
    probe_dist, index = probes.dist, at.index
    n = probe_dist.shape[-1]
    q = at.points[:, None, :] + 0.1 * cell[..., None] * at.normals[:, None, :]  # (s, 1, 3)
    v = q - probes.positions[index]  # (s, 8, 3)
    dist = np.linalg.norm(v, axis=-1)
    face, row, col, _, _ = cubemap.direction_to_texel(np.where(dist[..., None] > 0, v, 1.0), n)
    seen = probe_dist[index, face, row, col]
    # Tolerance: two texels' worth of angle at that distance plus a hundredth of a cell.
    tol = dist * (4.0 / n) + 0.01 * cell
    return dist <= seen + tol, _Texels(face, row, col, n)


# How many edges away from a seen triangle the cover test looks for the one the ray crosses,
# and how many (point, probe) pairs it searches at a time.
COVER_RINGS, RING_CHUNK = 2, 65536


@dataclass(frozen=True)
class Cover:
    """What the cover test of :func:`visibility_weights` asks: the triangle each probe
    texel saw ``probe_tid (p, 6, n, n)`` (-1: none), each triangle's object ``(t,)``, its
    :func:`~.geometry.triangle_planes` ``(t, 4, 3)`` and :func:`~.geometry.edge_neighbours`
    ``(t, 3)``, each point's object ``(s,)``, and ``cast``: the exact rays' test where the
    host has a ray caster (:class:`CastCover`), which decides the rays that cut another
    object's seen triangles' planes outside of them (else their rings are searched)."""

    probe_tid: np.ndarray
    triangle_object: np.ndarray
    planes: np.ndarray
    neighbours: np.ndarray
    point_object: np.ndarray
    cast: "CastCover | None" = None

    @classmethod
    def of(cls, probe_tid, triangles, vertices, triangle_object, point_object, cast=None):
        return cls(probe_tid, triangle_object, triangle_planes(triangles, vertices), edge_neighbours(triangles), point_object, cast)

    def rows(self, sl):
        """The same cover for the points ``sl``."""
        return replace(self, point_object=self.point_object[sl], cast=None if self.cast is None else self.cast.rows(sl))


# The cover test casts the exact rays it cannot decide from what the probes' texels saw
# through the host's ray caster, where the tables have one (CastCover). How many times such a
# ray is cast on past a triangle of the point's own object that faces it (a fold of the same
# surface), and how far past it (of the scene's size).
COVER_BY_RAYS = True
COVER_ROUNDS, PAST_OWN = 4, 1e-6


@dataclass(frozen=True)
class CastCover:
    """The cover test of :func:`visibility_weights` through the host's ray caster: the exact
    ray of each (point, probe) pair its texels leave open is cast, and the first triangle
    it meets covers the point if it is another object's, or its own object's facing away
    from it (the far side of a thin wall); one facing it is passed. ``caster``: a
    :class:`~.rays.RayCaster` over ``triangles (k, 3)`` (indices into ``vertices``); per
    caster triangle, its ``triangle_object (k,)`` and ``sheet (k,)`` (met from behind: its
    twin, facing the other way); ``point_object (s,)``; ``scale``: the scene's size. A ray
    that passes COVER_ROUNDS of its own object's triangles is taken as not covered.

    Where the seen triangles' rings fall short (a wall cut three times over: the Room's
    indirect error 18.9% with rings of two edges, 16.1% with the exact rays; the scene drawn
    whole, not simplified: 33.6% against 15.7%), the exact ray does not."""

    caster: RayCaster
    triangles: np.ndarray
    vertices: np.ndarray
    triangle_object: np.ndarray
    sheet: np.ndarray
    point_object: np.ndarray
    scale: float

    @classmethod
    def of(cls, caster, triangles, vertices, triangle_object, sheet, point_object, scale):
        return cls(caster, np.asarray(triangles), np.asarray(vertices), triangle_object, sheet, point_object, float(scale))

    @classmethod
    def of_scene(cls, scene, near_caster) -> "CastCover | None":
        """The cover of ``scene``'s points through the caster ``near_caster()`` gives (over
        the scene's triangles it names: :func:`~.gather.near_caster`), or None where there is
        none or COVER_BY_RAYS is off."""
        if near_caster is None or not COVER_BY_RAYS:
            return None
        caster, front, _ = near_caster()
        sheet = scene.sheet_triangles()
        return cls.of(caster, np.asarray(scene.triangles)[front], scene.points, scene.triangle_object()[front],
                      np.zeros(len(front), dtype=bool) if sheet is None else sheet[front], scene.point_object, scene.scale)

    @classmethod
    def of_capture(cls, scene, proxy, near_caster, make) -> "CastCover | None":
        """The cover for a capture of ``scene`` itself (``proxy`` None: :meth:`of_scene`) or of
        its simplified copy (:meth:`of_proxy`)."""
        return cls.of_scene(scene, near_caster) if proxy is None else cls.of_proxy(scene, proxy, make)

    @classmethod
    def of_proxy(cls, scene, proxy, make) -> "CastCover | None":
        """The cover of ``scene``'s points through a caster the host's ``make`` (a renderer's
        ``rays``) builds over ``proxy``'s triangles, the simplified copy the probes saw (a
        two-sided object's twins cast once); None without one, or with COVER_BY_RAYS off.
        (Through the scene's own caster, built before the tables' peak, the Room at 993K
        vertices held 2.59 -> 3.07 GB.)"""
        if make is None or not COVER_BY_RAYS or not len(proxy.triangles):
            return None
        triangles = np.asarray(proxy.triangles, dtype=np.int64)
        sheet = proxy.sheet_triangles(scene)
        twin = np.full(len(triangles), -1, dtype=np.int64) if sheet is None else twin_triangles(proxy.points, triangles, sheet)
        cast = first_of_twins(twin, np.arange(len(triangles)))
        return cls.of(make(proxy.points, triangles[cast]), triangles[cast], proxy.points, proxy.triangle_object[cast], twin[cast] >= 0,
                      scene.point_object, scene.scale)

    def rows(self, sl):
        """The same cover for the points ``sl``."""
        return replace(self, point_object=self.point_object[sl])


def _cast_covered(cover: CastCover, eye, u, depth, owner, normals):
    """``(m,)``: whether the rays ``eye + t u`` (0 < t < depth) first meet a triangle that
    covers points of ``owner`` facing ``normals`` (see :class:`CastCover`)."""
    found = np.zeros(len(eye), dtype=bool)
    todo, start = np.arange(len(eye)), np.zeros(len(eye))
    for _ in range(COVER_ROUNDS + 1 if len(eye) else 0):
        hits = cover.caster.cast(eye[todo] + start[todo, None] * u[todo], u[todo], depth[todo] - start[todo])
        met = hits.hit
        todo, tri, t = todo[met], hits.triangle[met], hits.t[met]
        side = np.where(cover.sheet[tri] & ~hits.front[met], -1.0, 1.0)
        normal = triangle_planes(cover.triangles[tri], cover.vertices)[:, 1]  # (the ones met alone)
        away = side * np.einsum("ij,ij->i", normal, normals[todo]) < -0.5
        blocks = (cover.triangle_object[tri] != owner[todo]) | away
        found[todo[blocks]] = True
        todo = todo[~blocks]
        start[todo] += t[~blocks] + PAST_OWN * cover.scale
        todo = todo[start[todo] < depth[todo]]
        if not len(todo):
            break
    return found


def _blocks(cover, tid, point_object, normals):
    """Whether triangles ``tid`` may cover points of ``point_object`` facing ``normals``:
    another object's, or the far side of a thin part of the same one (facing away)."""
    safe = np.maximum(tid, 0)
    facing_away = np.einsum("...c,...c->...", cover.planes[safe, 1], normals) < -0.5
    return (cover.triangle_object[safe] != point_object) | facing_away


def _covered(cover, at: PointProbes, eyes, texels: _Texels, cell, ask):
    """``(s, 8)``: another object's triangle lies between each probe and point (see above),
    for the pairs ``ask (s, 8)`` (False elsewhere).

    The texel towards the point and its 8 neighbours are asked which triangles they see;
    the exact ray from the probe to the point is cut with each one's plane (each triangle
    once per pair), and it covers the point if the cut lies inside that triangle or one
    across its edges, in front of the point. (At a grazing angle the texels around the ray
    may all see neighbours of the triangle it really crosses, near a rug's edge; a cut near
    but outside the other object must not count, or the floor around a rug would go dark.)
    """
    covered = np.zeros(ask.shape, dtype=bool)
    rows, cols = np.nonzero(ask)
    if not len(rows):
        return covered
    normals = at.normals[rows]
    eye = eyes[rows, cols]
    ray = at.points[rows] + 1e-3 * cell[rows] * normals - eye
    d = np.linalg.norm(ray, axis=-1)
    u = ray / np.maximum(d, 1e-300)[:, None]
    depth = d - 1e-4 * cell[rows, 0]  # a cut this far along the ray lies in front of the point
    tid = _texel_triangles(cover.probe_tid, at.index[rows, cols], texels[rows, cols])
    pair, slot = np.nonzero(tid >= 0)
    tid = tid[pair, slot]
    owner = cover.point_object[rows[pair]]
    keep = _blocks(cover, tid, owner, normals[pair])
    pair, tid, owner = pair[keep], tid[keep], owner[keep]
    ahead, inside = cuts_ahead(eye[pair], u[pair], tid, cover.planes, depth[pair])
    hit = np.zeros(len(rows), dtype=bool)
    hit[pair[inside & ahead]] = True
    # Where no seen triangle holds the cut, but another object's one (a rug over a floor: a
    # thin part's far side is seen whole by the texels around the ray) lies ahead outside
    # of it: the exact ray cast, where the cover has a caster (:class:`CastCover`); else the
    # same objects' triangles up to COVER_RINGS edges around the seen ones, each tried once
    # per pair (a finely cut rug's triangle under the ray may lie farther than that).
    missed = ahead & ~inside & (cover.triangle_object[tid] != owner)
    missed &= ~hit[pair]
    need = sorted_unique(pair[missed])  # (pair comes sorted)
    if cover.cast is not None:
        for sl in chunks(len(need), RING_CHUNK):  # bounded temporaries
            some = need[sl]
            hit[some] = _cast_covered(cover.cast, eye[some], u[some], depth[some], cover.point_object[rows[some]], normals[some])
        need = need[:0]  # (no rings to search)
    local, seen = np.searchsorted(need, pair[missed]), tid[missed]
    for start in range(0, len(need) if COVER_RINGS else 0, RING_CHUNK):  # bounded temporaries
        lo, hi = np.searchsorted(local, [start, start + RING_CHUNK])
        some = need[start : start + RING_CHUNK]
        found = _ring_search(cover, local[lo:hi] - start, seen[lo:hi], eye[some], u[some], depth[some])
        hit[some[found]] = True
    covered[rows[hit], cols[hit]] = True
    return covered


def _any_covered(cover, at: PointProbes, eyes, texels: _Texels, cell, ask):
    """``(s,)``: whether any of each point's pairs ``ask (s, 8)`` is covered (:func:`_covered`),
    asked a probe at a time, a point no more once one is."""
    found = np.zeros(len(ask), dtype=bool)
    for k in range(ask.shape[1]):
        rows = np.flatnonzero(ask[:, k] & ~found)
        if len(rows):
            one = np.zeros((len(rows), ask.shape[1]), dtype=bool)
            one[:, k] = True
            found[rows] = _covered(cover.rows(rows), at[rows], eyes[rows], texels[rows], cell[rows], one).any(axis=1)
    return found


def _texel_triangles(probe_tid, probe, texels: _Texels):
    """``(m, 9)``: the triangles (``probe_tid``, see :class:`Cover`) that the 3 x 3 texels
    around each of ``texels (m,)`` of ``probe (m,)`` see, each once (-1: none, or seen
    before in the row)."""
    n = texels.n
    r, c = cubemap.texels_around(texels.row, texels.col, n)
    tid = probe_tid.reshape(-1)[(((probe * 6 + texels.face) * n)[:, None] + r) * n + c]
    tid.sort(axis=1)
    tid[:, 1:][tid[:, 1:] == tid[:, :-1]] = -1
    return tid


def _ring_search(cover, ray_of, seen, eye, u, depth):
    """``(m,)``: whether each ray ``eye + t u`` (0 < t < depth) crosses a triangle up to
    COVER_RINGS edges from its seen ones (``seen (k,)``, of the rays ``ray_of (k,)``) and of
    the same object. The (ray, triangle) pairs are kept flat, as keys ``ray * t + triangle``."""
    count = np.int64(len(cover.planes))
    tried = sorted_unique(np.asarray(ray_of, dtype=np.int64) * count + seen)
    frontier = tried
    found = np.zeros(len(eye), dtype=bool)
    for _ in range(COVER_RINGS):
        ray, parent = np.divmod(frontier, count)
        ring = cover.neighbours[parent]  # (f, 3)
        keep = (ring >= 0) & (cover.triangle_object[np.maximum(ring, 0)] == cover.triangle_object[parent][:, None])
        keep &= ~found[ray][:, None]
        keys = sorted_unique(ray[:, None].repeat(3, axis=1)[keep] * count + ring[keep])
        keys = keys[~_in_sorted(keys, tried)]
        if not len(keys):
            break
        ray, tid = np.divmod(keys, count)
        ahead, inside = cuts_ahead(eye[ray], u[ray], tid, cover.planes, depth[ray])
        found[ray[ahead & inside]] = True
        tried = sorted_unique(np.concatenate([tried, keys]))
        frontier = keys
    return found


def _in_sorted(keys, sorted_keys):
    """Whether each of ``keys`` is in the sorted array ``sorted_keys``."""
    at = np.minimum(np.searchsorted(sorted_keys, keys), max(len(sorted_keys) - 1, 0))
    return sorted_keys[at] == keys if len(sorted_keys) else np.zeros(len(keys), dtype=bool)


def seen_from_behind(triangle_object, count, tid, back, solid, probe_valid):
    """Per object (``scene.point_object`` index, ``count`` of them): the share of the solid
    angle in which the valid probes see it that shows its back faces, ``(objects,)``. A large
    share means flipped normals, or a one-sided surface seen from its back: such faces get
    and pass on no light."""
    use = probe_valid if probe_valid.any() else np.ones_like(probe_valid)  # none valid: all
    seen = (tid >= 0) & use[:, None]
    obj = triangle_object[np.maximum(tid, 0)]
    w = solid[None, :] * seen
    total = np.bincount(obj.ravel(), w.ravel(), minlength=count)
    behind = np.bincount(obj.ravel(), (w * back).ravel(), minlength=count)
    return np.where(total > 0, behind / np.maximum(total, 1e-300), 0.0)
