"""A simplified copy of the scene for the probes' cube maps.

Pure numpy; must not import bpy. The paper: "each face of the cube was rendered with full
level of detail of the scene, whereas simplified geometry would be sufficient for the
purpose of irradiance measure". A probe's texel at cube size 16-32 covers centimetres to
decimetres of surface; drawing a million triangles into it costs the capture most of its
time (on llvmpipe about 35 ns per triangle per view) and changes what the probe sees very
little.

The simplification is vertex clustering per object: the points of one object that fall
into the same cube of edge ``h`` become one cluster, placed at their area-weighted mean,
except that points facing away from the cube's mean normal form a second cluster. A
triangle whose corners land in three different clusters is kept (the others collapse);
duplicates are dropped. So a thin wall's two faces stay two surfaces facing away from each
other (no light through it), surfaces that meet in a cube are joined (no slit to see
through), and each object keeps its identity (probes that see a moved object, the rug
test). Where another object's surface runs across a cell (a wall's foot on a floor), the
cell is halved, and its finest halves are clustered on each side of that surface apart: no
cluster averages the light of both sides of a wall, and what touches stays touching.

What it costs, as a bound: every captured surface lies within ``h sqrt(3)`` of where it
is, and the radiance a probe sees is averaged over cells of edge ``h`` (each cluster sends
the area-weighted mean of its points' radiance). The shading points, their normals and
their interpolation are untouched, and direct light and shadows use the full geometry.

Objects are simplified alike: each keeps the same share of its triangles (the budget over
the scene's count), so an object modelled with few triangles (a ground plane, a wall) is
kept whole and a dense one (a sculpt, a subdivided mesh) loses the most.
"""

from dataclasses import dataclass, replace

import numpy as np

from . import crossing
from .geometry import cross, listed_ranks
from .working import checkpoint

__all__ = ["CaptureProxy", "simplify"]

# An object with at most this many triangles, or this share of the budget, is never
# simplified: clustering it saves little and smears the light of its large triangles (a
# room's walls cut to a cell's size for the light, cells of metres wide).
KEEP_WHOLE, KEEP_WHOLE_SHARE = 64, 0.01
# Rounds of adjusting the cluster size towards the budget; each one is a clustering pass, and
# a round that takes off less than STALL of the triangles a round can take off is the last.
# The least power of the cells' edge the triangles are taken to fall by (see _wider: taken
# lower, a search that fell faster than measured would land far under its target).
ROUNDS, STALL, MIN_POWER = 4, 0.1, 1.0
# The searches for the next round's edge (see _wider): at most this many, done within this
# share of the target, each step widening or narrowing the edge by at most this factor; asked
# only where the touching cells, counted as they are, leave the rest at least TARGET_FLOOR
# of its share of the budget (see simplify).
SEARCHES, SEARCH_TOLERANCE, WIDEST, TARGET_FLOOR = 6, 0.1, 4.0, 0.5
# How many times a cell that another object's surface crosses is halved before its halves
# are clustered on each side of it (see _cluster). Three -> two, alternated in one process:
# the Breakfast Room 17.2-18.1 -> 15.0-15.1 s (the wait for this 2.1 -> 0.5-0.6 s: the
# touching cells' triangles fall faster with the edge, two full rounds instead of three;
# 71.8K -> 63.4K triangles drawn), its errors against Cycles the same (direct 5.59%,
# indirect 25.60 -> 25.58%); the Room subdivided to 102K vertices the same (indirect
# 18.94%); once, 47.4 -> 44.4 s at 554K vertices (the Breakfast Room subdivided). One
# level: no faster there, and coarser contacts.
CONTACT_LEVELS = 2


@dataclass
class CaptureProxy:
    """The simplified geometry the probes draw (see the module docstring).

    points: ``(c, 3)`` cluster positions; triangles: ``(t', 3)`` indices into them;
    cluster: ``(s,)`` each scene point's cluster; share: ``(s,)`` its area share of the
    cluster (summing to 1 per cluster); triangle_object: ``(t',)`` object index (None
    without objects); cell: ``(objects,)`` the cluster edge per object (0: kept whole);
    source_triangles: the scene's triangle count.
    """

    points: np.ndarray
    triangles: np.ndarray
    cluster: np.ndarray
    share: np.ndarray
    triangle_object: np.ndarray | None
    cell: np.ndarray
    source_triangles: int

    @property
    def count(self) -> int:
        return len(self.points)

    def radiance(self, point_radiance) -> np.ndarray:
        """Each cluster's radiance ``(c, 3)`` float32: the area-weighted mean of its points'."""
        r = np.asarray(point_radiance)
        return np.stack([np.bincount(self.cluster, r[:, c] * self.share, minlength=self.count) for c in range(3)], axis=1).astype(np.float32)

    def sheet_triangles(self, scene) -> np.ndarray | None:
        """``(t',)`` bool: this copy's triangles of ``scene``'s two-sided objects (it keeps each
        object's sheets whole or not at all), or None where the scene has none."""
        sheet = scene.sheet_triangles()
        if sheet is None or self.triangle_object is None:
            return None
        return np.isin(self.triangle_object, np.unique(scene.triangle_object()[sheet]))

    def reordered(self, order) -> "CaptureProxy":
        """The same proxy over the scene's points taken in ``order`` (their clusters and
        shares reordered: :meth:`radiance` of point radiance in that order)."""
        return replace(self, cluster=self.cluster[order], share=self.share[order])

    def expand_columns(self, per_cluster) -> np.ndarray:
        """A matrix over clusters ``(n, c)`` as one over the scene's points ``(n, s)``
        (each point's column: its cluster's, times its share)."""
        return per_cluster[:, self.cluster] * self.share[None, :].astype(per_cluster.dtype)

    def max_offset(self) -> float:
        """The bound on how far a captured surface lies from where it is."""
        return float(np.max(self.cell, initial=0.0) * np.sqrt(3.0))

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in (self.points, self.triangles, self.cluster, self.share)))


def simplify(scene, budget) -> CaptureProxy | None:
    """The scene's capture proxy with about ``budget`` triangles, or None where the scene has
    no more than that (it is drawn as it is), within 10% of it where ROUNDS of clustering
    reach it; the report says what was drawn. The triangles that cutting long ones for the
    bake added (``scene.sampled_triangles``) are added to the budget, and an object is kept
    whole by the triangles it was modelled with: a floor cut into 200 pieces counts as the
    two triangles it was (the Breakfast Room's cut walls, clustered 1.45 m wide, let more sky
    through to the table: the cups' direct light +18%)."""
    sheets = scene.sheets() if hasattr(scene, "sheets") else None
    if sheets is not None:
        return _simplify_sheets(scene, sheets, budget)
    tris = np.asarray(scene.triangles)
    sampled = getattr(scene, "sampled_triangles", None)
    if budget is not None and sampled is not None:
        budget = int(budget) + int(np.sum(sampled))
    if budget is None or len(tris) <= budget:
        return None
    points = np.asarray(scene.points, dtype=np.float64)
    s = len(points)
    owner = scene.point_object if scene.point_object is not None else np.zeros(s, dtype=np.int64)
    owner = np.asarray(owner, dtype=np.int64)
    objects = int(owner.max()) + 1 if s else 0
    prep = crossing.Prepared(points, np.asarray(scene.normals, dtype=np.float64), tris, owner, objects, scene.point_areas())
    tri_count = np.bincount(prep.tri_owner, minlength=objects)
    area = np.bincount(prep.tri_owner, prep.tri_area, minlength=objects)
    simplified = _modelled(tri_count, sampled) > max(KEEP_WHOLE, KEEP_WHOLE_SHARE * budget)
    kept_whole = int(tri_count[~simplified].sum())
    if kept_whole >= budget or not simplified.any():
        return None
    # A surface of area A tessellated into clusters of edge h has about 2 A / h^2 triangles.
    ratio = (budget - kept_whole) / max(int(tri_count[simplified].sum()), 1)
    cell = np.where(simplified, np.sqrt(2.0 * area / np.maximum(tri_count * ratio, 1.0)), 0.0)
    best, before = None, None
    for round_ in range(ROUNDS):
        checkpoint()  # (a cancelled bake's simplification stops here)
        proxy = _cluster(prep, cell)
        # A round that takes off less than STALL of what it can (objects kept whole are in
        # every count) is the last, and the fewest seen are kept.
        if best is not None and len(proxy.triangles) - kept_whole > (1.0 - STALL) * (len(best.triangles) - kept_whole):
            return best if len(best.triangles) <= len(proxy.triangles) else proxy
        best = proxy if best is None or len(proxy.triangles) < len(best.triangles) else best
        got = len(proxy.triangles) - kept_whole
        if len(proxy.triangles) <= budget * 1.1 or got <= 0:
            return proxy
        if round_ == ROUNDS - 1:  # no next round to find an edge for
            break
        # Wider cells. Where objects touch, cells are clustered finer, and their triangles
        # change little with the edge (the Breakfast Room's 14-20K over a fourfold edge):
        # where they leave the rest at least TARGET_FLOOR of its share of the budget, the
        # edge is searched on rounds that leave those cells out (a tenth of a round's cost),
        # counting them as this round found them. Where they hold most of the budget (pegs
        # along a wall's foot), the cells widen by the power the whole count fell by in the
        # round before (2, a surface's, at the first), and the stall above ends the rounds.
        plain = max(len(_cluster(prep, cell, contact=False).triangles) - kept_whole, 1)
        left = budget - kept_whole
        target = left - max(got - plain, 0)
        if target >= TARGET_FLOOR * plain * left / got:
            step = _wider(prep, cell, plain, target, kept_whole)
        else:
            power = 2.0 if before is None else _fall_power(before[0], before[1], got)
            step = (got / max(left, 1)) ** (1.0 / power) * 1.05
        cell, before = cell * step, (step, got)
    return best


def _wider(prep, cell, plain, target, kept_whole):
    """How much wider than ``cell`` (a factor) rounds without the touching cells
    (:func:`_cluster`'s ``contact``) give about ``target`` triangles (``plain`` at ``cell``,
    both less the ``kept_whole``). Each step takes the triangles to fall as the square of the
    edge, then by the power the last two steps measured (at least MIN_POWER), and moves the
    edge by at most WIDEST either way; once two tries lie on either side of the target, the
    next is their geometric mean. At most SEARCHES steps; the factor returned is the try
    nearest the target at or under it, else the one with the fewest triangles."""
    tries = [(1.0, plain)]
    scale = 1.0
    for _ in range(SEARCHES):
        over = [s for s, n in tries if n > target]
        under = [s for s, n in tries if n <= target]
        if over and under and max(over) < min(under):  # bracketed: halve the gap (in log)
            scale = float(np.sqrt(max(over) * min(under)))
        else:
            (s0, n0), (s1, n1) = (tries[-2] if len(tries) > 1 else (None, None)), tries[-1]
            power = 2.0 if s0 is None or n0 <= n1 else _fall_power(s1 / s0, n0, n1)
            scale = s1 * float(np.clip((n1 / target) ** (1.0 / power), 1.0 / WIDEST, WIDEST))
        checkpoint()
        tries.append((scale, max(len(_cluster(prep, cell * scale, contact=False).triangles) - kept_whole, 1)))
        if abs(tries[-1][1] - target) <= SEARCH_TOLERANCE * target:
            break
    near = [(abs(target - n), s) for s, n in tries if n <= target * (1.0 + SEARCH_TOLERANCE)]
    return min(near)[1] if near else min(tries, key=lambda t: t[1])[0]


def _fall_power(step, before, now):
    """The power of the cells' edge that the triangles fell by, ``before`` -> ``now``, when
    the edge grew by ``step``: between MIN_POWER and 2 (a surface's)."""
    return float(np.clip(np.log(before / now) / np.log(step), MIN_POWER, 2.0))


def _simplify_sheets(scene, sheets, budget):
    """:func:`simplify` of a scene with two-sided sheets: its front sides alone are simplified
    (within the budget, as one-sided), then each sheet object's clusters and triangles get
    twins facing the other way, over its back points (see ``SceneArrays.back``)."""
    front = np.flatnonzero(~sheets.back)
    index = np.full(len(scene.points), -1, dtype=np.int64)
    index[front] = np.arange(len(front))
    one_sided = replace(scene, points=scene.points[front], normals=scene.normals[front], albedo=scene.albedo[front],
                        emission=scene.emission[front], triangles=index[scene.triangles[~sheets.triangle_back]],
                        point_object=np.asarray(scene.point_object)[front], back=None,
                        dark=None if scene.dark is None else scene.dark[front],
                        reflectance=None if scene.reflectance is None else scene.reflectance[front], emitting=None,
                        emitter_pieces=None, cut_from=None)
    two_sided = np.zeros(int(np.max(scene.point_object, initial=0)) + 1, dtype=bool)
    two_sided[np.asarray(scene.point_object)[sheets.back]] = True
    proxy = simplify(one_sided, _front_budget(budget, one_sided, two_sided))
    if proxy is None:
        return None
    c = proxy.count
    cluster_object = np.zeros(c, dtype=np.int64)
    cluster_object[proxy.cluster] = one_sided.point_object
    mirrored = np.flatnonzero(two_sided[cluster_object])  # clusters of sheets
    twin_of = np.full(c, -1, dtype=np.int64)
    twin_of[mirrored] = c + np.arange(len(mirrored))
    cluster = np.empty(len(scene.points), dtype=np.int64)
    share = np.empty(len(scene.points))
    cluster[front], share[front] = proxy.cluster, proxy.share
    back = np.flatnonzero(sheets.back)
    cluster[back] = twin_of[proxy.cluster[index[sheets.twins[back]]]]
    share[back] = proxy.share[index[sheets.twins[back]]]
    flip = two_sided[proxy.triangle_object]
    triangles = np.concatenate([proxy.triangles, twin_of[proxy.triangles[flip][:, ::-1]]])
    return CaptureProxy(np.concatenate([proxy.points, proxy.points[mirrored]]), triangles, cluster, share,
                        np.concatenate([proxy.triangle_object, proxy.triangle_object[flip]]), proxy.cell,
                        len(scene.triangles))


def _front_budget(budget, one_sided, two_sided):
    """The share of ``budget`` the front sides ``one_sided`` (a scene) are simplified to
    where the objects ``two_sided`` will be drawn twice (their sheets' back sides): objects
    are simplified alike, so the twins take the share of the front's budget that the sheets
    hold of its triangles as modelled (those a cut added are added to it, see simplify)."""
    if budget is None or not len(one_sided.triangles):
        return budget
    count = _modelled(np.bincount(one_sided.point_object[one_sided.triangles[:, 0]], minlength=len(two_sided)),
                      getattr(one_sided, "sampled_triangles", None))
    share = float(count[two_sided[: len(count)]].sum()) / max(int(count.sum()), 1)
    return int(round(int(budget) / (1.0 + share)))


def _modelled(count, sampled):
    """Each object's triangles as modelled: ``count (objects,)`` less those that cutting long
    ones for the bake added (``sampled``, per object, or None)."""
    count = np.asarray(count, dtype=np.int64).copy()
    if sampled is not None:
        k = min(len(sampled), len(count))
        count[:k] = np.maximum(count[:k] - np.asarray(sampled, dtype=np.int64)[:k], 0)
    return count


def _unique_rows(rows):
    """``np.unique(rows, axis=0, return_inverse=True)[1]`` for non-negative int rows, through
    one int64 key where the rows' ranges allow it (far faster)."""
    span = rows.max(axis=0) + 1 if len(rows) else np.ones(rows.shape[1], dtype=np.int64)
    if np.prod(span.astype(np.float64)) < 2.0**62:
        key = np.ravel_multi_index(rows.T, span)
        return np.unique(key, return_inverse=True)[1].ravel()
    return np.unique(rows, axis=0, return_inverse=True)[1].ravel()


def _cluster(prep, cell, contact=True):
    """One clustering round at edge ``cell`` per object: a :class:`CaptureProxy`.
    ``contact=False``: without the touching cells (see :mod:`.crossing`), a round that only
    counts its triangles (the search in :func:`_wider`), its clusters left at their means."""
    points, normals, tris, owner, rel, point_areas = prep.points, prep.normals, prep.tris, prep.owner, prep.rel, prep.areas
    s = len(points)
    h = cell[owner]
    whole = h <= 0
    ijk = np.where(whole[:, None], 0, np.floor(rel / np.where(whole, 1.0, h)[:, None])).astype(np.int64)
    # A cell another object's surface runs across is halved, CONTACT_LEVELS times, each half
    # asked again. The points of a finest cell still crossed are clustered on each side of
    # the crossing surface apart (kept as they were, a subdivided Breakfast Room's walls'
    # feet and contacts took its capture to 138K triangles against a budget of 69K: 71K now).
    level = np.zeros(s, dtype=np.int64)
    if contact:
        touching, within, side = crossing.contact(prep, cell, ijk, sides=CONTACT_LEVELS == 0)
    else:
        touching, within, side = np.zeros(s, dtype=bool), None, np.zeros(s, dtype=np.int64)
    for k in range(1, CONTACT_LEVELS + 1):
        if not touching.any():
            break
        level[touching] = k
        h = np.where(touching, 0.5 * h, h)
        ijk[touching] = np.floor(rel[touching] / h[touching, None]).astype(np.int64)
        touching, within, side = crossing.contact(prep, cell / 2.0**k, ijk, touching, within, sides=k == CONTACT_LEVELS)
    # A finest cell still crossed is clustered on each side of the surfaces crossing it apart.
    level[touching] = CONTACT_LEVELS + 1 + side[touching]
    h = np.where(whole, 0.0, h)
    # Objects kept whole are their own clusters (numbered after the cells: one key of every
    # point's row would pass 64 bits and take the slow unique of whole rows).
    ijk[whole] = 0
    cells = np.empty(s, dtype=np.int64)
    grouped = ~whole
    cells[grouped] = _unique_rows(np.concatenate([owner[grouped, None], level[grouped, None], ijk[grouped]], axis=1))
    cells[whole] = (cells[grouped].max() + 1 if grouped.any() else 0) + np.arange(int(whole.sum()))
    # Within a cell, the points facing away from the normal of its largest point are a
    # cluster of their own: a thin wall's (or a rug's) two faces stay apart, while a floor and
    # a wall meeting in the cell are joined (no slit between them for a probe to see through).
    # (The cells are numbered 0, 1, ...: the clusters' numbers are found by flags per cell,
    # not by sorting the points.)
    count_cells = int(cells.max()) + 1 if s else 0
    largest = _largest(cells, count_cells, point_areas)
    away = np.einsum("sc,sc->s", normals, normals[largest[cells]]) < 0
    key = 2 * cells + away
    cluster = listed_ranks(key, 2 * count_cells)[1][key].astype(np.int64)
    c = int(cluster.max()) + 1 if s else 0
    weight = np.bincount(cluster, point_areas, minlength=c)
    count = np.bincount(cluster, minlength=c).astype(np.float64)
    share = np.where(weight[cluster] > 0, point_areas / np.maximum(weight[cluster], 1e-300), 1.0 / count[cluster])
    centres = np.stack([np.bincount(cluster, points[:, a] * share, minlength=c) for a in range(3)], axis=1)
    if contact:  # (a round that only counts keeps the means: a third of its time at a million points)
        centres = _place(prep, _Clusters(cells, away, cluster, ijk, h, whole), centres)
    mapped = cluster[tris]
    ok = (mapped[:, 0] != mapped[:, 1]) & (mapped[:, 1] != mapped[:, 2]) & (mapped[:, 0] != mapped[:, 2])
    # A triangle that turned over when its corners moved to their clusters' centres would
    # face the other way (a floor seen as a ceiling): dropped.
    after = _normals(centres, mapped[ok])
    ok[ok] = np.einsum("tc,tc->t", prep.tri_normal[ok], after) > 0
    mapped = mapped[ok]
    # Drop duplicates with the same corners in the same turn (rotated so the smallest leads).
    first = np.argmin(mapped, axis=1)
    rolled = np.stack([mapped[np.arange(len(mapped)), (first + k) % 3] for k in range(3)], axis=1)
    _, keep = np.unique(_unique_rows(rolled), return_index=True)
    keep.sort()
    triangles = mapped[keep]
    cluster_object = np.zeros(c, dtype=np.int64)
    cluster_object[cluster] = owner
    triangle_object = cluster_object[triangles[:, 0]]
    return CaptureProxy(centres, triangles, cluster, share, triangle_object, cell.copy(), len(tris))


# Quadric placement: directions whose curvature is below this share of a cluster's largest
# are left at the mean (a flat cell's centre stays where its points are, in its plane).
QUADRIC_RANK_SHARE = 1e-3


@dataclass(frozen=True)
class _Clusters:
    """How one clustering round grouped the points, each ``(s,)`` (``ijk``: ``(s, 3)``): its
    ``cells`` (one per object and grid cell), the points that face ``away`` from their cell's
    largest point, each point's ``cluster``, its cell's grid index ``ijk`` and edge ``h``,
    and the points kept ``whole`` (their own clusters)."""

    cells: np.ndarray
    away: np.ndarray
    cluster: np.ndarray
    ijk: np.ndarray
    h: np.ndarray
    whole: np.ndarray


def _place(prep, clusters: _Clusters, mean):
    """Each cluster's position (``mean (c, 3)``: its points' area-weighted mean): the point nearest (least squares) to the planes of the
    cell's points that do not face away from it (its own, and a perpendicular neighbour's: a
    wall's bottom face, a floor), nearest the mean where they leave it free, kept inside
    its cell. So a cluster at a wall's foot sits on the edge where the wall meets its
    bottom, as in the scene: nothing lifts off the floor (no slit under a wall), and a
    cluster on a flat patch stays in its plane (Lindstrom's vertex clustering with quadrics)."""
    points, normals, areas, rel = prep.points, prep.normals, prep.areas, prep.rel
    cells, away, cluster, ijk, h, whole = clusters.cells, clusters.away, clusters.cluster, clusters.ijk, clusters.h, clusters.whole
    c = len(mean)
    ref = _largest(cluster, c, areas)  # each cluster's largest point
    ncell = int(cells.max()) + 1
    main_of, away_of = np.full(ncell, -1), np.full(ncell, -1)
    main_of[cells[~away]] = cluster[~away]
    away_of[cells[away]] = cluster[away]
    other = np.where(away, main_of[cells], away_of[cells])
    share = (other >= 0) & (np.einsum("sc,sc->s", normals, normals[ref[np.maximum(other, 0)]]) > -0.5) & ~whole
    target = np.concatenate([cluster, other[share]])
    n = np.concatenate([normals, normals[share]])
    w = np.concatenate([areas, areas[share]]) + 1e-30
    d = np.concatenate([np.einsum("sc,sc->s", normals, points), np.einsum("sc,sc->s", normals[share], points[share])])
    q = np.stack([np.bincount(target, w * n[:, j] * n[:, k], minlength=c) for j in range(3) for k in range(3)], axis=1)
    q = q.reshape(c, 3, 3)
    b = np.stack([np.bincount(target, w * n[:, j] * d, minlength=c) for j in range(3)], axis=1)
    vals, vecs = np.linalg.eigh(q)
    inv = np.where(vals > QUADRIC_RANK_SHARE * vals[:, -1:], 1.0 / np.maximum(vals, 1e-300), 0.0)
    r = b - np.einsum("cjk,ck->cj", q, mean)
    placed = mean + np.einsum("cjk,ck->cj", vecs, inv * np.einsum("ckj,ck->cj", vecs, r))
    # Inside the cell (the bound every point keeps to its cluster), and where the cluster
    # is a whole object's point, that point.
    first = np.empty(c, dtype=np.int64)
    first[cluster] = np.arange(len(cluster))
    lo = (points[first] - rel[first]) + ijk[first] * h[first, None]
    placed = np.clip(placed, lo, lo + h[first, None])
    return np.where(whole[first, None], mean, placed)


def _largest(group, count, areas):
    """``(count,)``: the point of largest ``areas`` in each of ``count`` groups (``group (s,)``
    numbered 0, 1, ...; of equal ones the last; -1 for an empty group), without sorting."""
    most = np.full(count, -np.inf)
    np.maximum.at(most, group, areas)
    largest = np.full(count, -1, dtype=np.int64)
    at_most = np.flatnonzero(areas == most[group])
    np.maximum.at(largest, group[at_most], at_most)
    return largest


def _normals(vertices, triangles):
    v = vertices[triangles]
    return cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
