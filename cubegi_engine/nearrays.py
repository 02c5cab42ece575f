"""The near field's rays: each point's cosine-weighted rays to what is within its reach,
through the host's ray caster where it has one, else through the voxel index (:mod:`.spatial`).

Pure numpy; must not import bpy. Crowded points (see :mod:`.nearfield`) cast only where the
host has a caster, and by clusters: one point per cluster casts, the others gather what it
gathers (:func:`clusters`, :func:`shared_rows`).
"""

from dataclasses import dataclass

import numpy as np

from . import sh
from .geometry import in_pieces, run_offsets
from .hemisphere import TURN_HASH, hemisphere_rays
from .spatial import COORD_SLACK, SLACK

__all__ = ["Rays", "cast_points", "cast_rays", "cast_by_caster", "host_rays", "clusters", "shared_rows", "open_basis_of", "FADE", "CASTER_RAYS",
           "CASTER_REACH"]

# Hits fade out over this last share of the reach.
FADE = 0.25
# Crowded points cast their rays through the host's caster (a BVH tree), where it has one:
# not each point, but one per cluster of them (the points of one object in one cube of edge
# reach / CLUSTERS_PER_REACH whose normals fall in one bin of a grid of 1 / NORMAL_BINS),
# CASTER_RAYS rays each; the cluster's other points gather what it gathers. Their rays reach
# CASTER_REACH times as far, or across their object where that is more (a white teapot's
# inside is wider than a quarter cell: rays that leave it take the probes' darker light). Whole objects, the smallest first (a cup's
# inside, a teapot's: the probes never see in), while the clusters' rays are at most
# CASTER_RAYS_AT_MOST (about a second of Blender's BVH tree), CASTER_POINTS_AT_ONCE
# clusters' rays at a time. Measured on the Breakfast Room (indirect rel. RMSE against Cycles
# at 256 samples; the bake's time, one process, this 2-core machine): without 32.6%, 21.5 s;
# 16 rays, 250K at most: 27.7%, 24.7 s (the teapot fits: a budget of 125K leaves it out,
# 31.6%); 16 rays, 500K: 27.5%, +3.5 s more; 32 rays, 1M: 27.4%, +5.5 s more. Clusters of a
# quarter and half the reach instead of an eighth: 28.9% and 29.4%.
CLUSTERS_PER_REACH, NORMAL_BINS, CASTER_REACH = 8.0, 2, 2.0
CASTER_RAYS, CASTER_RAYS_AT_MOST, CASTER_POINTS_AT_ONCE = 16, 250_000, 4096
# Points whose rays are cast through the voxel index at a time (their per-ray arrays: about
# 220 bytes a ray), and the fewest a worker thread casts as one piece.
POINTS_AT_ONCE, CAST_PIECE = 1 << 15, 256


@dataclass(frozen=True)
class Rays:
    """The hits of some points' rays, one row each: ``point`` (the caster's index),
    ``triangle``, ``corners`` (the points whose light it takes: the triangle's, or its
    twin's on a sheet met from behind), ``uv`` (its barycentrics), ``front``, ``weight``
    (its share of its point's view: faded by distance, over the point's rays that count),
    ``at`` (where it lies); per point with a hit, in order, ``open_basis`` and ``share``
    (:func:`open_basis_of`); per point, ``openness`` (the share of its rays that meet nothing
    within reach, faded)."""

    point: np.ndarray
    triangle: np.ndarray
    corners: np.ndarray
    uv: np.ndarray
    front: np.ndarray
    weight: np.ndarray
    at: np.ndarray
    open_basis: np.ndarray
    share: np.ndarray
    openness: np.ndarray

    @classmethod
    def joined(cls, parts):
        return cls(*(np.concatenate([getattr(part, f) for part in parts]) for f in cls.__dataclass_fields__))


def cast_points(index, points, normals, reach, pair_p, pair_t, by_caster, caster_reach, caster, tri, sheets, rays):
    """Cast the rays of the points with candidate pairs (``rays`` each, through the host's
    ``caster`` where it has one, else through the voxel ``index``) and of the points
    ``by_caster`` (CASTER_RAYS each, reaching ``caster_reach``): ``(cast (c,), traced, hits
    (a Rays), reach (c,), turn (c,))``, the points that cast, the first ``traced`` of them
    the points with candidate pairs."""
    # Each point's pattern is turned by an angle hashed from its position (not its index:
    # the same scene in another object order bakes the same), decorrelating neighbours.
    # Only the points with candidates cast rays; their arrays are theirs alone (a million
    # points with a few thousand near surfaces do not make (s, rays) arrays), and their
    # per-ray arrays are made POINTS_AT_ONCE points at a time: what is kept of them is their
    # hits.
    cast, pair_local = np.unique(pair_p, return_inverse=True)
    pair_local = pair_local.ravel()
    order = np.argsort(pair_local, kind="stable")  # each point's pairs together, in their order
    pair_local, pair_t = pair_local[order], pair_t[order]
    traced = len(cast)
    cast = np.concatenate([cast, by_caster])  # the caster's points after the traced ones
    at, nrm, rch = points[cast], normals[cast], reach[cast]
    rch[traced:] = caster_reach
    turn = 2.0 * np.pi * ((at / np.maximum(rch, 1e-300)[:, None]) @ TURN_HASH % 1.0)
    # Rays start this far off their surface, and a surface within twice that of a ray's start counts
    # as met there: float32 meshes put points on another surface up to a few 1e-7 of their coordinates off it.
    slack = SLACK * rch + COORD_SLACK * np.abs(at).max(axis=1)
    mine = tuple(x[:traced] for x in (at, nrm, rch, slack, turn))  # (a piece's slice may run past its end)
    if caster is not None and traced:
        # The host's caster takes them too: on the GPU module (llvmpipe here) the Breakfast
        # Room's 181K such rays took 0.19 s, the voxel index's trace 1.16 s on one core. A
        # point whose caster's answers are in doubt casts again through the index.
        def again(ids, dirs):
            p, t = _pairs_of(pair_local, pair_t, ids)
            best, hit_tri, uv, front = index.trace(mine[0][ids], mine[1][ids], dirs, mine[2][ids], mine[3][ids], p, t)
            return best, hit_tri, tri[np.maximum(hit_tri, 0)], uv, front

        hits = cast_by_caster(caster, points, tri, sheets, cast[:traced], *mine, rays, 0, again=again)
    else:
        hits = list(in_pieces(lambda sl: cast_rays(index, tri, *mine, rays, pair_local, pair_t, sl),
                              max(traced, 1), POINTS_AT_ONCE, least=CAST_PIECE)) if traced or not len(by_caster) else []
    if len(by_caster):
        hits += cast_by_caster(caster, points, tri, sheets, by_caster, *(x[traced:] for x in (at, nrm, rch, slack, turn)), CASTER_RAYS, traced)
    return cast, traced, Rays.joined(hits), rch, turn


def _pairs_of(pair_local, pair_t, ids):
    """The candidate pairs (``pair_local`` sorted) of the points ``ids`` (sorted), numbered
    among them: ``(pair_p, pair_t)``."""
    first, end = np.searchsorted(pair_local, ids), np.searchsorted(pair_local, ids, side="right")
    count = end - first
    return np.repeat(np.arange(len(ids)), count), pair_t[np.repeat(first, count) + run_offsets(count)]


def cast_rays(index, tri, at, nrm, rch, slack, turn, rays, pair_local, pair_t, sl):
    """The hits of the rays of the points ``sl`` (a slice) of ``at`` (``pair_local``: the
    pairs' points, sorted) among ``tri``, through the voxel ``index``: a :class:`Rays`, its
    ``point`` counted as ``at``'s."""
    first, end = np.searchsorted(pair_local, [sl.start, sl.stop])
    at, nrm, rch, slack, turn = at[sl], nrm[sl], rch[sl], slack[sl], turn[sl]
    dirs = hemisphere_rays(nrm, rays, turn)  # (c, rays, 3)
    best, hit_tri, hit_uv, hit_front = index.trace(at, nrm, dirs, rch, slack, pair_local[first:end] - sl.start, pair_t[first:end])
    return _hits(at, nrm, rch, dirs, best, hit_tri, tri[np.maximum(hit_tri, 0)], hit_uv, hit_front, sl.start)


def clusters(crowded, points, normals, owner, reach, rays, caster):
    """The crowded points that cast through the host's ``caster`` (None: none do): ``(reps
    (k,), members (m,), member_of (m,), reach (k,))``, the clusters' points that cast (see
    CLUSTERS_PER_REACH), the crowded points they stand for (themselves included), each
    one's cluster (an index into reps), and how far the reps' rays reach: CASTER_REACH times
    their own reach, or their object's size where that is more (a cup in a fine grid's cells:
    its inside is lit by all of itself)."""
    none = np.zeros(0, dtype=np.int64)
    ids = np.flatnonzero(crowded)
    if caster is None or not len(ids):
        return none, none, none, np.zeros(0)
    p, n = points[ids], normals[ids]
    obj = np.zeros(len(ids), dtype=np.int64) if owner is None else np.asarray(owner, dtype=np.int64)[ids]
    edge = reach[ids] / CLUSTERS_PER_REACH
    key = np.column_stack([obj, np.floor(p / edge[:, None]), np.floor(n * NORMAL_BINS), np.round(np.log2(edge) * 4.0)]).astype(np.int64)
    _, cluster = np.unique(np.ascontiguousarray(key).view(np.dtype((np.void, key.itemsize * key.shape[1]))).ravel(), return_inverse=True)
    cluster = cluster.ravel()  # (one sort of whole rows as bytes: np.unique(axis=0) takes 3x as long)
    k = int(cluster.max()) + 1
    count = np.bincount(cluster, minlength=k)
    mean = np.stack([np.bincount(cluster, p[:, j], minlength=k) for j in range(3)], axis=1) / count[:, None]
    order = np.lexsort((np.linalg.norm(p - mean[cluster], axis=1), cluster))
    rep = order[np.searchsorted(cluster[order], np.arange(k))]  # the point nearest its cluster's middle
    # Whole objects, the smallest first, within the budgets.
    objects, local = np.unique(obj, return_inverse=True)
    local = local.ravel()
    by_object = np.argsort(local, kind="stable")
    starts = np.searchsorted(local[by_object], np.arange(len(objects)))
    size = np.linalg.norm(np.maximum.reduceat(p[by_object], starts) - np.minimum.reduceat(p[by_object], starts), axis=1)
    by_size = np.argsort(size, kind="stable")
    fits = np.cumsum(np.bincount(local[rep], minlength=len(objects))[by_size]) * rays <= CASTER_RAYS_AT_MOST
    chosen = np.zeros(len(objects), dtype=bool)
    chosen[by_size[fits]] = True
    kept = np.flatnonzero(chosen[local[rep]])
    place = np.full(k, -1, dtype=np.int64)
    place[kept] = np.arange(len(kept))
    member = np.flatnonzero(chosen[local])
    reps = rep[kept]
    return ids[reps], ids[member], place[cluster[member]], np.maximum(CASTER_REACH * reach[ids[reps]], size[local[reps]])


def host_rays(caster):
    """The host's :class:`~cubegi_engine.rays.RayCaster` that ``caster`` gives (see
    :func:`cast_by_caster`), or None."""
    return None if caster is None else caster()[0]


def shared_rows(rows, open_basis, share, members, rep, normals):
    """The near field's rows with the ``members``' added: each gathers what its cluster's
    point ``rep`` gathers (where that has any hits; the rep itself is left as it is), and
    its open basis is turned to its own normal (the probes' light it keeps is the same
    directions', see :func:`open_basis_of`). ``(rows, open_basis, share, alias)``: ``alias``
    the members' places among the rows and their reps'."""
    place = np.full(len(normals), -1, dtype=np.int64)
    place[rows] = np.arange(len(rows))
    q = place[rep]
    keep = (q >= 0) & (members != rep)
    members, q = members[keep], q[keep]
    turned = open_basis[q] + share[q, None] * (sh.diffuse_basis(normals[members]) - sh.diffuse_basis(normals[rows[q]]))
    alias = (len(rows) + np.arange(len(members)), q)
    return np.concatenate([rows, members]), np.concatenate([open_basis, turned]), np.concatenate([share, share[q]]), alias


def cast_by_caster(caster, points, tri, sheets, ids, at, nrm, rch, slack, turn, rays, first, again=None):
    """:func:`cast_rays` of the points ``ids`` (at ``at``, counted from ``first``; ``tri`` over ``points``) through the host's
    caster (``caster()``: ``(RayCaster, its triangles' indices among tri, each point's
    inward direction)``, see :func:`~cubegi_engine.gather.near_caster`): a list of
    :class:`Rays`. A sheet is met on the side a ray comes from: a hit on a sheet's triangle
    from behind takes its twin points' light, as :func:`~cubegi_engine.gather.gather` does.
    ``again(which, dirs)``: where given, the points ``which`` (indices among ``ids``, with
    their rays ``dirs``) any of whose rays met a back face first, or a triangle behind
    their start, cast again by it: ``(best, triangle, corners, uv, front)`` per ray, as
    :meth:`~.spatial.VoxelIndex.trace` (coincident faces, one each way, are one distance
    to float32: the voxel index takes the front one, whatever the order of the objects)."""
    rays_by, whose, inward = caster()
    # From a vertex where two faces meet, a ray lifted off one face can start behind the
    # other: the rays start as far again into the vertex's own triangles (as shadow rays do:
    # :func:`~cubegi_engine.lifts.ray_starts`).
    into = inward[ids] - np.einsum("kc,kc->k", inward[ids], nrm)[:, None] * nrm
    at = at + slack[:, None] * into
    twins = None if sheets is None else sheets.twins
    out = []
    for lo in range(0, len(at), CASTER_POINTS_AT_ONCE):
        sl = slice(lo, lo + CASTER_POINTS_AT_ONCE)
        a, n, r, k, tn = at[sl], nrm[sl], rch[sl], slack[sl], turn[sl]
        c = len(a)
        dirs = hemisphere_rays(n, rays, tn)  # (c, rays, 3)
        start = np.repeat(a + k[:, None] * n, rays, axis=0)
        found = rays_by.cast(start, dirs.reshape(-1, 3), np.repeat(r, rays))
        hit = found.triangle >= 0
        t_ = np.where(hit, whose[np.maximum(found.triangle, 0)], -1)
        corners, front = tri[np.maximum(t_, 0)], found.front.copy()
        # A hit on a triangle with no corner in front of the ray's start: the caster's float32
        # let the ray graze the edge of a surface behind the point (a floor that ends at the
        # foot of a sheet, met from the sheet's far side). The voxel index pairs no such
        # triangle with the point; the ray is no sample of what the point sees.
        behind = hit & (np.einsum("hcx,hx->hc", points[corners] - start[:, None, :], np.repeat(n, rays, axis=0)).max(axis=1) <= 0.0)
        if twins is not None:
            turned = hit & ~front & (twins[corners[:, 0]] >= 0)
            corners[turned], front[turned] = twins[corners[turned]], True
        # A ray that meets a back face first set out into a solid (or met a face turned the
        # wrong way): it is no sample of what the point sees, and its other rays stand for it.
        counts = ~(behind | (hit & ~front)).reshape(c, rays)
        best, t_, corners, uv, front = (np.where(hit, found.t, np.inf).reshape(c, rays), t_.reshape(c, rays), corners.reshape(c, rays, 3),
                                        found.bary[:, 1:].reshape(c, rays, 2), front.reshape(c, rays))
        doubt = np.flatnonzero(~counts.all(axis=1)) if again is not None else []
        if len(doubt):
            best[doubt], t_[doubt], corners[doubt], uv[doubt], front[doubt] = again(lo + doubt, dirs[doubt])
            counts[doubt] = True
        out.append(_hits(a, n, r, dirs, best, t_, corners, uv, front, first + lo, counts))
    return out


def _hits(at, nrm, rch, dirs, best, hit_tri, corners, hit_uv, hit_front, first, counts=None):
    """The :class:`Rays` of points ``at`` (counted from ``first``) whose rays ``dirs (c,
    rays, 3)`` met ``hit_tri (c, rays)`` (-1: nothing within reach) at ``best``, taking the
    light of ``corners (c, rays, 3)``. ``counts (c, rays)`` bool: the rays that count (None:
    all); a point's others are left out of its view."""
    # Hits fade out over the last FADE of the reach (their direction goes back to the
    # probes by as much): no step in the light where a surface passes out of reach.
    fade = np.clip((rch[:, None] - best) / (FADE * rch[:, None]), 0.0, 1.0)  # (c, rays); 0 where no hit
    if counts is None:
        counts = np.ones(fade.shape, dtype=bool)
    fade *= counts
    used = np.maximum(counts.sum(axis=1), 1)
    point, ray = np.nonzero((hit_tri >= 0) & counts)
    with_hits = np.unique(point)
    open_basis, share = open_basis_of(dirs[with_hits], fade[with_hits], nrm[with_hits], counts[with_hits])
    t = best[point, ray]
    return Rays(point + first, hit_tri[point, ray], corners[point, ray], hit_uv[point, ray], hit_front[point, ray],
                fade[point, ray] / used[point], at[point] + t[:, None] * dirs[point, ray], open_basis, share, 1.0 - fade.sum(axis=1) / used)


def open_basis_of(dirs, fade, normals, counts):
    """What the probes' diffuse light loses at points casting rays ``dirs (m, k, 3)`` whose
    hits weigh ``fade (m, k)`` (``counts (m, k)`` bool: the rays that count): their radiance
    in the hit directions, averaged as the rays that count average, plus the hit share of
    the pattern's own quadrature error (so a point whose rays all hit keeps no probe light,
    and one whose rays all leave keeps all). ``(open_basis (m, 9), share (m,))``."""
    y = sh.basis(dirs)  # (m, K, 9)
    used = np.maximum(counts.sum(axis=1), 1)
    share = fade.sum(axis=1) / used
    pattern_error = sh.diffuse_basis(normals) - np.einsum("mk,mkj->mj", counts.astype(float), y) / used[:, None]
    return np.einsum("mk,mkj->mj", fade, y) / used[:, None] + share[:, None] * pattern_error, share
