"""Light sampled finely enough: long triangles split into smaller ones for the bake.

Pure numpy; must not import bpy.

A bake knows the light at the shading points, and everything it passes on (what the probes
see of a surface, what the near field's rays meet) is the barycentric mix of a triangle's
corners' light. A triangle larger than a probe cell (a room's floor as two triangles, a wall
as one quad) then passes on the light of its far-apart corners, not the light across it:
a sun patch in its middle is lost, and a corner that stands a few centimetres outside the
room (a floor running under the walls, a wall's end past the next wall: common in real
files) spreads the outside's sky and sun over the whole surface. The Breakfast Room's floor
is 6 vertices over 14 x 11 m, two of them outside the room: its chairs got 3 to 4 times
Cycles' indirect light.

:func:`refine` splits every triangle whose longest edge is longer than the given length into
``n x n`` smaller ones (its edges cut into ``n`` equal parts); the new points lie in the
triangle, with its corners' normal, albedo and emission mixed barycentrically. The bake
lights them as any point; the light written to a mesh is the light at its own vertices.
"""

from dataclasses import dataclass

import numpy as np

from .emitters import emitting_triangles
from .geometry import all_three, cross, in_box, mix64, near_any_triangle, sorted_columns
from .scene import SceneArrays

__all__ = ["refine", "refine_for_grid", "refine_near_emitters", "split_counts", "MAX_SPLIT", "MAX_NEW_SHARE"]

# A triangle is cut into at most MAX_SPLIT parts along its edges (MAX_SPLIT^2 triangles), and
# a scene gains at most MAX_NEW_SHARE times its points (plus MIN_NEW_POINTS): past that the
# length is raised for every triangle alike (a huge low-poly scene under a fine grid).
MAX_SPLIT = 32
MAX_NEW_SHARE, MIN_NEW_POINTS = 0.5, 20_000


def split_counts(points, triangles, max_edge) -> np.ndarray:
    """``(t,)`` int: the parts each triangle's edges are cut into so that none is longer than
    ``max_edge`` (one length, or ``(t,)``), at least 1, at most MAX_SPLIT."""
    longest = _longest_edges(points, np.asarray(triangles, dtype=np.int64).reshape(-1, 3))
    limit = np.broadcast_to(np.asarray(max_edge, dtype=np.float64), longest.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        n = np.ceil(np.where(limit > 0, longest / limit, 1.0) - 1e-9)
    return np.clip(np.nan_to_num(n, nan=1.0, posinf=MAX_SPLIT), 1, MAX_SPLIT).astype(np.int64)


def _new_points(n) -> int:
    """Points a triangle cut ``n`` ways gains (the lattice less its 3 corners)."""
    return (n + 1) * (n + 2) // 2 - 3


def _lattice(n):
    """The barycentric lattice of a triangle cut ``n`` ways: ``(weights (L, 3), sub (n^2, 3))``,
    lattice points (i along a->b, j along a->c) with the corners first, and the smaller
    triangles over them, wound as the triangle is."""
    ij = [(0, 0), (n, 0), (0, n)] + [(i, j) for j in range(n + 1) for i in range(n + 1 - j)
                                     if (i, j) not in ((0, 0), (n, 0), (0, n))]
    at = {key: k for k, key in enumerate(ij)}
    ij_arr = np.array(ij, dtype=np.float64)
    weights = np.stack([1.0 - (ij_arr[:, 0] + ij_arr[:, 1]) / n, ij_arr[:, 0] / n, ij_arr[:, 1] / n], axis=1)
    sub = [(at[(i, j)], at[(i + 1, j)], at[(i, j + 1)]) for j in range(n) for i in range(n - j)]
    sub += [(at[(i + 1, j)], at[(i + 1, j + 1)], at[(i, j + 1)]) for j in range(n - 1) for i in range(n - 1 - j)]
    return weights, np.array(sub, dtype=np.int64)


def _budgeted(counts, refine, points):
    """``counts`` lowered (by one scale for every triangle) until the new points stay within
    the budget (MAX_NEW_SHARE of ``points`` plus MIN_NEW_POINTS)."""
    budget = MAX_NEW_SHARE * points + MIN_NEW_POINTS
    scale = 1.0
    while True:
        n = np.maximum(np.ceil(counts / scale - 1e-9), 1).astype(np.int64) if scale > 1 else counts
        if int(np.sum(_new_points(n[refine]))) <= budget:
            return n
        scale *= 1.25


def refine(scene: SceneArrays, max_edge, emitters=False) -> tuple[SceneArrays, np.ndarray]:
    """``scene`` with every triangle whose longest edge exceeds ``max_edge`` (one length, or
    ``(t,)`` per triangle) cut into smaller ones (see the module docstring), and ``(s,)``
    the index of each of ``scene``'s points in the new arrays. Emissive triangles are left
    as they are, but with ``emitters`` (to sample the light they reflect: see
    :func:`refine_near_emitters`); their light stays that of the triangles as modelled
    (``SceneArrays.emitting``).

    Each object's points stay together and in order, its own first: an object's new points
    follow its own, and a two-sided object's back side (its twins, ``SceneArrays.back``)
    follows all of them, in the same order (a refined triangle's twin is refined alike).
    Returns ``scene`` itself, and the identity, where no triangle is too long."""
    s = len(scene.points)
    tri = np.asarray(scene.triangles, dtype=np.int64).reshape(-1, 3)
    identity = np.arange(s)
    if not len(tri):
        return scene, identity
    back_pt = np.zeros(s, dtype=bool) if scene.back is None else np.asarray(scene.back, dtype=bool)
    counts = split_counts(scene.points, tri, max_edge)
    # An emitter's own light is exact from its triangles (cubegi_engine.emitters), whose flat
    # panels are clipped by their outlines: it is left as it is.
    were_pieces = pieces_of(scene)
    emits = emitting_triangles(scene) | were_pieces
    refine_tri = (counts > 1) & ~back_pt[tri[:, 0]] & (emitters | ~emits)
    if refine_tri.any():
        counts = _budgeted(counts, refine_tri, s)
        refine_tri &= counts > 1
    if not refine_tri.any():
        return scene, identity
    lay = _Layout.of(scene, tri, back_pt, refine_tri, counts)
    out = _moved_arrays(scene, lay, back_pt)
    front_parts, twin_parts = [], []
    for n in np.unique(counts[lay.rows]):
        front, twin = _split(scene, tri, lay, out, counts[lay.rows] == n, int(n))
        front_parts.append(front)
        if twin is not None:
            twin_parts.append(twin)
    kept_tri = lay.moved[tri[~refine_tri]]
    pieces = were_pieces | (emits & refine_tri)  # (t,) whether each is, or is cut into, pieces of an emitter
    kept_pieces = pieces[~refine_tri]
    if twin_parts:  # the refined triangles' old twins leave with them
        two = lay.sheet[lay.row_obj]
        left = ~_among(kept_tri, lay.moved[tri[lay.rows[two]]] + lay.twin_offset[lay.row_obj[two]][:, None])
        kept_tri, kept_pieces = kept_tri[left], kept_pieces[left]
    triangles = np.concatenate([kept_tri, *front_parts, *twin_parts]).astype(np.int64)
    piece_parts = [np.repeat(pieces[lay.rows[counts[lay.rows] == n]], n * n) for n in np.unique(counts[lay.rows])]
    piece_parts.append(np.zeros(sum(len(t) for t in twin_parts), dtype=bool))  # twins: never counted as emitters
    refined = SceneArrays(out["points"], out["normals"], out["albedo"], out["emission"], triangles, sky=scene.sky,
                          lights=scene.lights, point_object=out["point_object"] if scene.point_object is not None else None,
                          dark=out.get("dark"), object_names=list(scene.object_names), sky_map=scene.sky_map,
                          back=out["back"] if scene.back is not None else None, gathered=out.get("gathered"),
                          sampled_triangles=_added(scene, lay, counts), reflectance=out.get("reflectance"),
                          **_emitters_as_modelled(scene, tri, emits & refine_tri & ~were_pieces, lay.moved,
                                                  np.concatenate([kept_pieces, *piece_parts])))
    return refined, lay.moved


def pieces_of(scene) -> np.ndarray:
    """``(t,)`` bool: which of ``scene``'s triangles are pieces of an emissive triangle the
    bake cut (:attr:`SceneArrays.emitter_pieces`; none where it cut none)."""
    if scene.emitter_pieces is None:
        return np.zeros(len(scene.triangles), dtype=bool)
    return np.asarray(scene.emitter_pieces, dtype=bool)


def _emitters_as_modelled(scene, tri, first_cut, moved, pieces) -> dict:
    """The refined arrays' :attr:`SceneArrays.emitting` and ``emitter_pieces``: the emissive
    triangles as modelled that were cut (before, or now: ``first_cut``), by the points' new
    indices, and which of the new triangles are their pieces (both None where none was)."""
    before = np.zeros((0, 3), dtype=np.int64) if scene.emitting is None else moved[np.asarray(scene.emitting, dtype=np.int64)]
    emitting = np.concatenate([before, moved[tri[first_cut]]])
    if not len(emitting):
        return {"emitting": None, "emitter_pieces": None}
    return {"emitting": emitting, "emitter_pieces": pieces}


def _added(scene, lay, counts) -> np.ndarray:
    """Per object, the front triangles the cut added (``n^2 - 1`` a triangle cut ``n`` ways),
    with those an earlier cut added."""
    objects = len(lay.out_sizes)
    added = np.bincount(lay.row_obj, counts[lay.rows].astype(np.int64) ** 2 - 1, minlength=objects).astype(np.int64)
    if scene.sampled_triangles is not None:
        added[: len(scene.sampled_triangles)] += np.asarray(scene.sampled_triangles, dtype=np.int64)
    return added


@dataclass(frozen=True)
class _Layout:
    """Where everything goes in the refined arrays. Per object: its own points, its new
    points, then (a two-sided object) its twins and the new points' twins.

    rows ``(r,)``: the triangles refined, by object; row_obj: their objects; local_first:
    each row's first new point among its object's new points; moved ``(s,)``: each old
    point's new index; out_start, own, sheet, twin_offset: per object, its first index, its
    front (or only) side's old points, whether it is two-sided, how far after a front point
    its twin lies; total: the new point count."""

    rows: np.ndarray
    row_obj: np.ndarray
    local_first: np.ndarray
    moved: np.ndarray
    out_start: np.ndarray
    out_sizes: np.ndarray
    own: np.ndarray
    sheet: np.ndarray
    twin_offset: np.ndarray
    total: int

    @classmethod
    def of(cls, scene, tri, back_pt, refine_tri, counts):
        s = len(scene.points)
        owner = np.zeros(s, dtype=np.int64) if scene.point_object is None else np.asarray(scene.point_object, dtype=np.int64)
        objects = int(owner.max()) + 1 if s else 0
        sizes = np.bincount(owner, minlength=objects)
        sheet = np.bincount(owner[back_pt], minlength=objects) > 0
        own = np.where(sheet, sizes // 2, sizes)
        rows = np.flatnonzero(refine_tri)
        row_obj = owner[tri[rows, 0]]
        order = np.lexsort((rows, row_obj))  # by object, then triangle: each object's new points together
        rows, row_obj = rows[order], row_obj[order]
        gained = _new_points(counts[rows])
        new_per_obj = np.bincount(row_obj, gained, minlength=objects).astype(np.int64)
        local_first = (np.cumsum(gained) - gained) - (np.cumsum(new_per_obj) - new_per_obj)[row_obj]
        out_sizes = sizes + new_per_obj * np.where(sheet, 2, 1)
        out_start = np.cumsum(out_sizes) - out_sizes
        within = np.arange(s) - np.searchsorted(owner, np.arange(objects))[owner]
        moved = np.where(back_pt, out_start[owner] + own[owner] + new_per_obj[owner] + (within - own[owner]),
                         out_start[owner] + within)
        return cls(rows, row_obj, local_first, moved, out_start, out_sizes, own, sheet, own + new_per_obj, int(out_sizes.sum()))


def _moved_arrays(scene, lay, back_pt) -> dict:
    """The refined arrays with the old points in their new places (the new ones to fill)."""
    out = {}
    for name in ("normals", *_carried(scene)):
        out[name] = np.empty((lay.total, 3))
        out[name][lay.moved] = getattr(scene, name)
    out["point_object"] = np.repeat(np.arange(len(lay.out_sizes)), lay.out_sizes)
    out["back"] = np.zeros(lay.total, dtype=bool)
    out["back"][lay.moved] = back_pt
    for name in ("dark", "gathered"):  # the new points are not set aside, and stand for little surface each
        if getattr(scene, name) is not None:
            out[name] = np.zeros(lay.total, dtype=bool)
            out[name][lay.moved] = getattr(scene, name)
    return out


def _carried(scene) -> tuple:
    """The per-point arrays a new point takes from its triangle's corners, mixed."""
    return ("points", "albedo", "emission") + (("reflectance",) if scene.reflectance is not None else ())


def _split(scene, tri, lay, out, sel, n):
    """The rows ``sel`` of ``lay`` (triangles cut ``n`` ways): their new points written into
    ``out``; returns ``(their triangles (m n^2, 3), their twins' or None)``."""
    r, obj, base = lay.rows[sel], lay.row_obj[sel], lay.local_first[sel]
    weights, sub = _lattice(n)
    corners = tri[r]  # (m, 3)
    fresh = lay.out_start[obj][:, None] + lay.own[obj][:, None] + base[:, None] + np.arange(len(weights) - 3)[None, :]
    index = np.concatenate([lay.moved[corners], fresh], axis=1)
    w = weights[3:]  # (L-3, 3)
    for name in _carried(scene):
        out[name][fresh] = np.einsum("lk,mkc->mlc", w, np.asarray(getattr(scene, name), dtype=np.float64)[corners])
    nrm = np.einsum("lk,mkc->mlc", w, np.asarray(scene.normals, dtype=np.float64)[corners])
    out["normals"][fresh] = nrm / np.maximum(np.linalg.norm(nrm, axis=2, keepdims=True), 1e-300)
    two = lay.sheet[obj]
    if not two.any():
        return index[:, sub].reshape(-1, 3), None
    shift = lay.twin_offset[obj[two]][:, None]
    tw = fresh[two] + shift
    for name in _carried(scene):
        out[name][tw] = out[name][fresh[two]]
    out["normals"][tw] = -out["normals"][fresh[two]]
    out["back"][tw] = True
    twin_index = index[two] + shift  # the twins of the corners and of the new points alike
    return index[:, sub].reshape(-1, 3), twin_index[:, sub][:, :, ::-1].reshape(-1, 3)


def _among(triangles, others) -> np.ndarray:
    """``(k,)`` bool: which of ``triangles (k, 3)`` have the corners of one of ``others (m, 3)``,
    in any order (by a 64-bit hash of each sorted corner triple; the others' sorted and
    searched: ``np.isin`` sorted both together, 1.76 against 0.33 s for 2.6M and 0.8M)."""
    if not len(triangles) or not len(others):
        return np.zeros(len(triangles), dtype=bool)

    def key(t):
        low, mid, high = sorted_columns(np.asarray(t).astype(np.uint64))
        return mix64(mix64(mix64(low) ^ mid) ^ high)

    known, wanted = np.sort(key(others)), key(triangles)
    return known[np.minimum(np.searchsorted(known, wanted), len(known) - 1)] == wanted


# Light is sampled at most SAMPLE_CELLS probe cells apart on every surface (see the module
# docstring and docs/accuracy.md), and GATHERED_CELLS apart on a triangle with a gathered
# corner (:mod:`cubegi_engine.gather`): half of such a corner's rays meet the surfaces at its
# feet within centimetres (a wall's foot on the floor), and take their light as it is sampled
# there. Breakfast Room, default bake, indirect rel. RMSE against Cycles: 44.6% at 1.5 cells,
# 39.6% at 0.5 (its walls' corners at the floor were 3x too bright, from a sunlit floor
# sample 3 m away).
SAMPLE_CELLS, GATHERED_CELLS = 1.5, 0.5


def refine_for_grid(scene: SceneArrays, grid, cells=SAMPLE_CELLS, gathered_cells=GATHERED_CELLS) -> tuple[SceneArrays, np.ndarray]:
    """:func:`refine` with each triangle's longest edge held to ``cells`` of the cell edge of
    the grid at its centre (``grid``: a :class:`~cubegi_engine.grid.Grid`), ``gathered_cells``
    where a corner is one of the scene's gathered points; then :func:`refine_near_emitters`."""
    tri = np.asarray(scene.triangles, dtype=np.int64).reshape(-1, 3)
    if not len(tri):
        return scene, np.arange(len(scene.points))
    centre = np.asarray(scene.points, dtype=np.float64)[tri].mean(axis=1)
    share = np.full(len(tri), float(cells))
    if scene.gathered is not None:
        share[np.asarray(scene.gathered, dtype=bool)[tri].any(axis=1)] = gathered_cells
    scene, moved = refine(scene, share * grid.point_cell_edge(centre))
    scene, then = refine_near_emitters(scene, grid)
    return scene, then[moved]


# Light sampled finely by emitters: a triangle is cut in two along its edges while an emissive
# triangle (for an emissive one: another surface) lies within NEAR_EMITTER of its longest edge
# of its centre, round after round (at most EMITTER_ROUNDS), down to edges of EMITTER_CELLS of
# the cell edge. McGuire's Cornell box (a lamp's quad 1 cm under the ceiling, the ceiling in
# 12.6 cm squares): the ceiling's 9 vertices over the lamp got 0.45-0.86 of Cycles' indirect
# light, now 0.93-1.07 (see docs/accuracy.md, a lamp close to a surface).
NEAR_EMITTER, EMITTER_CELLS, EMITTER_ROUNDS = 0.5, 1.0 / 16.0, 8
# A surface nearer an emitter's plane than APART of the distance asked lies in it, and one
# turned from it by more than acos(FACING) does not face it (a floor meeting a glowing wall:
# no gap holds light between them; see near_any_triangle).
APART, FACING = 1e-3, 0.5


def refine_near_emitters(scene: SceneArrays, grid) -> tuple[SceneArrays, np.ndarray]:
    """``scene`` with the triangles close to emissive ones, and the emissive ones close to
    other surfaces, cut until each is no longer than twice its distance from the other (see
    NEAR_EMITTER), and ``(s,)`` each of ``scene``'s points' new index; its ``cut_from`` is
    ``scene``'s fingerprint (an edit that makes a surface start or stop emitting changes the
    cuts, not that).

    The light an emitter sends a surface close in front of it changes over the width of the
    gap between them (a lamp's quad 1 cm under a ceiling lights the ceiling over it ten
    times as much as the ceiling a centimetre past its edge), and the light bouncing in the
    gap is what each side's points gather from the other's by the near field's rays, mixed
    over the triangles they land on: sampled a cell apart, a ceiling triangle reaching past
    the lamp's edge, or the lamp's own triangle reaching to its edge (where half its view is
    open), passes that edge's light across the whole triangle. A surface in the emitter's
    plane (a panel set into a ceiling), or turned away from facing it (a floor meeting a
    glowing wall), is not in front of it. The new points are at most MAX_NEW_SHARE of the
    scene's, plus MIN_NEW_POINTS, over all rounds: the triangles nearest their emitter (the
    shortest) are cut first."""
    before, moved = scene.fingerprint(), np.arange(len(scene.points))
    budget = (1.0 + MAX_NEW_SHARE) * len(scene.points) + MIN_NEW_POINTS
    for _ in range(EMITTER_ROUNDS if emitting_triangles(scene).any() else 0):
        tri = np.asarray(scene.triangles, dtype=np.int64).reshape(-1, 3)
        longest = _longest_edges(scene.points, tri)
        split = _near_emitters(scene, grid, tri, longest, max(int(budget) - len(scene.points), 0) // 6)
        if not split.any():
            break
        cut, step = refine(scene, np.where(split, 0.5 * longest * (1.0 + 1e-9), np.inf), emitters=True)
        if len(cut.points) == len(scene.points):
            break
        scene, moved = cut, step[moved]
    scene.cut_from = before  # (a new snapshot where it cut; else the one given)
    return scene, moved


def _longest_edges(points, tri) -> np.ndarray:
    """``(t,)`` the longest edge of each of the triangles ``tri (t, 3)`` over ``points``."""
    columns = np.ascontiguousarray(np.asarray(points, dtype=np.float64).T)  # (contiguous columns: 1.5x faster)
    corners = [[axis[tri[:, k]] for axis in columns] for k in range(3)]

    def squared(a, b):
        dx, dy, dz = (p - q for p, q in zip(corners[a], corners[b]))
        return dx * dx + dy * dy + dz * dz

    return np.sqrt(np.maximum(np.maximum(squared(0, 1), squared(1, 2)), squared(2, 0)))


def _near_emitters(scene, grid, tri, longest, at_most):
    """``(t,)`` bool: the front triangles to cut in a round of :func:`refine_near_emitters`
    (``longest``: their longest edges), at most ``at_most`` of them (each adds up to 6
    points, with a sheet's twins), the shortest first."""
    p = np.asarray(scene.points, dtype=np.float64)
    a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
    split = np.zeros(len(tri), dtype=bool)
    emits = emitting_triangles(scene) | pieces_of(scene)
    if not emits.any():
        return split
    front = ~scene.back_triangles()
    centre = (a + b + c) / 3.0
    unit = cross(b - a, c - a)
    unit /= np.maximum(np.linalg.norm(unit, axis=1, keepdims=True), 1e-300)
    ask = front & (longest > 2.0 * EMITTER_CELLS * grid.point_cell_edge(centre))
    level = np.floor(np.log2(np.maximum(longest, 1e-300))).astype(np.int64)
    lo_corner, hi_corner = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
    for asked, source in ((~emits, emits), (emits, front & ~emits)):
        if not source.any():
            continue
        source_lo, source_hi = lo_corner[source].min(axis=0), hi_corner[source].max(axis=0)
        for k in np.unique(level[ask & asked]):
            radius = NEAR_EMITTER * 2.0 ** (k + 1)  # at least NEAR_EMITTER of each one's longest edge
            sel = np.flatnonzero(ask & asked & (level == k))
            sel = sel[in_box(centre[sel], source_lo - radius, source_hi + radius)]
            if not len(sel):
                continue
            lo, hi = centre[sel].min(axis=0) - radius, centre[sel].max(axis=0) + radius
            near = np.flatnonzero(source & all_three((hi_corner >= lo) & (lo_corner <= hi)))
            if len(near):
                split[sel] = near_any_triangle(centre[sel], radius, a[near], b[near], c[near], centre_normals=unit[sel],
                                               apart=APART * radius, facing=FACING)
    if split.sum() > at_most:  # the budget: the shortest first (the nearest their emitters)
        chosen = np.flatnonzero(split)
        split[chosen[np.argsort(longest[chosen], kind="stable")[at_most:]]] = False
    return split
