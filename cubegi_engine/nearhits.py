"""What the near field's hits take: which covered points are hidden from them
(:func:`hidden_points`), the weight of a hit triangle's hidden corners moved to its others
(:func:`uncover`), and a hit in a gap darkened to what the gap lets in (:func:`gap_ratios`).
See :mod:`cubegi_engine.nearfield`.

Pure numpy; must not import bpy.
"""

import numpy as np

from .hemisphere import hemisphere_rays
from .nearrays import FADE
from .spatial import COORD_SLACK, SLACK, resting

__all__ = ["hidden_points", "uncover", "gap_ratios", "HIDDEN_SHARE"]

# A covered point counts as hidden from the near field's hits (its light stands for no
# surface) where at least this share of its view is closed in within reach, or where it
# lies on another surface (see resting).
HIDDEN_SHARE = 0.5
# A hit on a triangle with a corner closed in (openness below OPENNESS_CLOSED: a floor point
# under a block) and one in the open (above OPENNESS_OPEN) casts rays of its own to weigh its
# corners' light (see gap_ratios; how many: nearfield.OPENNESS_RAYS); OPENNESS_FLOOR keeps
# the ratio of two closed points near 1.
OPENNESS_CLOSED, OPENNESS_OPEN, OPENNESS_FLOOR = 0.3, 0.6, 0.05
# Hits on one triangle within the same cube of this share of their reach share one such
# test (the rays of neighbouring points land close together: the Breakfast Room's 5.6K hits
# in gaps lie on 74 triangles).
OPENNESS_CELL = 0.05


def hidden_points(covered, openness, lit_if_open, sheets, hit_point, corners, points, normals, tri, emitting=None, lying=None):
    """``((s,) bool, ((w,) int, (w,) bool))``: the ``covered`` points hidden from the near
    field's hits, and the points whose emitting or not that depends on, with whether each
    emits (:attr:`NearField.emitters`: while none of them starts or stops, the set holds).

    Hidden: covered (no probe light) and closed in or lying on another surface (under a wall
    standing on it, a block's underside). A covered point open to its own view (a thick
    wall's outer face: no probe is outside) has light of its own (the sky's, the sun's), and
    a ray that lands beside it takes it. So has a sheet's back side and a covered point
    facing one across a gap (``hit_point``, ``corners``: each hit's point and triangle
    corners): the ceiling 1 cm over a lamp's quad, lit by its top, which it lights back
    (McGuire's Cornell box: the ceiling's indirect light 0.10 -> 0.40 against Cycles' 0.56).
    A floor under a block standing 2 cm above it faces the block's own underside: hidden.
    Not so an emitter's points (``emitting (s,)``) and a point facing one across a gap
    (neither lying on another surface): a box lamp's top 1 cm under a ceiling lights it, and
    the ceiling lights it back; a glowing wall's foot on the ground stays hidden. ``lying
    (s,)``: which covered points lie on another surface, where that was asked already (else
    :func:`~.spatial.resting` is asked here)."""
    hidden = covered.copy()
    open_ = openness >= 1.0 - HIDDEN_SHARE
    if lit_if_open is not None:
        hidden &= ~(open_ & lit_if_open)
    if sheets is not None:  # a sheet's back side, and a point facing one across a gap, are surfaces
        hidden &= ~_facing(sheets.back, hit_point, corners)
    ask = np.flatnonzero(hidden)
    rest = np.zeros(len(hidden), dtype=bool)
    if lying is not None:  # the covered points' answers, asked once (Transport.resting)
        rest[ask] = lying[ask]
    elif len(ask):
        scale = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
        rest[ask] = resting(points, normals, tri, scale, ask, sheets)
    gap = hidden & ~rest & ~open_  # where an emitter across the gap counts: those points, and their hits' corners
    watched = gap.copy()
    watched[corners[gap[hit_point]].ravel()] = True
    emitting = np.zeros(len(hidden), dtype=bool) if emitting is None else np.asarray(emitting, dtype=bool)
    hidden &= ~(gap & _facing(emitting, hit_point, corners))
    hidden[hidden & open_] = rest[hidden & open_]
    watched = np.flatnonzero(watched)
    return hidden, (watched, emitting[watched])


def _facing(surface, hit_point, corners):
    """``(s,)`` bool: the ``surface`` points and the points whose rays meet one of them
    (``hit_point``, ``corners``: each hit's point and triangle corners)."""
    facing = np.asarray(surface, dtype=bool).copy()
    facing[hit_point[facing[corners].any(axis=1)]] = True
    return facing


def uncover(index, weight, corners, hidden, tri, reach, ask=None, caster=None):
    """Barycentric ``weight (h, 3)`` of hits on triangles ``tri`` with ``corners`` some of
    which are ``hidden`` (under another object: a floor point under a wall standing on it,
    whose light stands for no surface a ray can land on). The hit takes the other corners
    (none: no light):
    where the hit point itself is not covered (nothing within ``reach`` along its
    triangle's normal: the floor beside the wall), their weights made whole; where it is
    (the floor under a block standing 2 cm above it, lit only through the gap) scaled up to
    whole only where they hold at least half of the weight (a hit deeper in the gap stays
    darker, continuously). ``ask (h,)`` bool: the hits whose point is asked; the others'
    is taken as not covered. ``caster``: the host's ray caster (a
    :class:`~cubegi_engine.rays.RayCaster`), where it has one: it casts the rays, not the index."""
    mixed = np.flatnonzero(hidden[corners].any(axis=1))
    if not len(mixed):
        return weight
    free = np.ones(len(mixed), dtype=bool)
    asked = np.arange(len(mixed)) if ask is None else np.flatnonzero(ask[mixed])
    k = tri[mixed[asked]]
    at = np.einsum("hc,hcx->hx", weight[mixed[asked]], np.stack([index.a[k], index.b[k], index.c[k]], axis=1))
    free[asked] = ~_covered_along_normal(index, at, _side_normals(index, k, corners[mixed[asked]]), reach[mixed[asked]], caster)
    kept = weight[mixed] * ~hidden[corners[mixed]]
    out = weight.copy()
    out[mixed] = kept / np.maximum(kept.sum(axis=1, keepdims=True), np.where(free, 1e-2, 0.5)[:, None])
    return out


def _side_normals(index, tri, corners):
    """``(h, 3)``: the unit normal of each hit's triangle ``tri`` on the side its ``corners``
    lie. A sheet's back side met through its front's triangle (as the host's caster meets it:
    :func:`~.nearrays.cast_by_caster`) faces the other way."""
    up = index.unit[tri]
    sheets = index.sheets
    if sheets is None:
        return up
    return np.where((sheets.back[corners[:, 0]] != sheets.triangle_back[tri])[:, None], -up, up)


def _covered_along_normal(index, at, up, reach, caster=None):
    """``(h,)`` bool: whether a surface lies over each point ``at`` along its unit normal
    ``up``, within ``reach`` (one ray each; through ``caster`` where given)."""
    slack = SLACK * reach + COORD_SLACK * np.abs(at).max(axis=1)
    if caster is not None:
        return np.isfinite(_distances(caster, at, up, up[:, None, :], reach, slack)[:, 0])
    start = at + slack[:, None] * up
    pair_p, pair_t = index.segment_candidates(start, start + reach[:, None] * up)  # the ray trace casts
    t, _, _, _ = index.trace(at, up, up[:, None, :], reach, slack, pair_p, pair_t)
    return np.isfinite(t[:, 0])


def _distances(caster, at, up, dirs, reach, slack):
    """``(m, k)``: how far each ray ``at + slack up + t dirs`` (``dirs (m, k, 3)``) goes to
    the first surface it meets, from either side, within ``reach`` (inf: none), through the
    host's ``caster`` (what the voxel index's trace answers, without its candidate pairs)."""
    m, k = dirs.shape[:2]
    found = caster.cast(np.repeat(at + slack[:, None] * up, k, axis=0), dirs.reshape(-1, 3), np.repeat(reach, k))
    return np.where(found.triangle >= 0, found.t, np.inf).reshape(m, k)


def gap_ratios(index, corners, openness, at, tri, front, reach, turn, rays, caster=None):
    """``(ask (a,), ratio (a, 3))``: the barycentric weights of hits at ``at (h, 3)`` on
    triangles ``tri`` that lie in a gap (their rows ``ask``), each corner's share scaled by
    ``ratio``: how open the hit point is against how open the corner is
    (``openness (s,)``: the share of a point's view with nothing within its reach), at most
    1. A triangle whose corners' light was gathered in the open but whose hit point lies in a
    gap (a floor under a block standing 2 cm above it: the corners a floor cell away outside
    the block, the hit point under it) sends only the share of that light the gap lets in.
    Only hits on front faces of triangles with a corner closed in and one in the open
    (OPENNESS_CLOSED, OPENNESS_OPEN), with something over them along their normal within
    reach, are asked (``rays`` rays each, about the hit triangle's normal; hits close
    together on one triangle share them: OPENNESS_CELL). ``caster``: as in :func:`uncover`."""
    open_c = openness[corners]  # (h, 3)
    ask = np.flatnonzero(front & (open_c.min(axis=1) < OPENNESS_CLOSED) & (open_c.max(axis=1) > OPENNESS_OPEN))
    none = (ask[:0], np.ones((0, 3)))
    if not len(ask):
        return none
    # In a gap: something over the hit point along its normal, within reach (a floor beside a
    # wall is open overhead: its corners' light stands).
    up, r = _side_normals(index, tri[ask], corners[ask]), reach[ask]
    slack = SLACK * r + COORD_SLACK * np.abs(at[ask]).max(axis=1)
    gap = _covered_along_normal(index, at[ask], up, r, caster)
    if not gap.any():
        return none
    keep = np.flatnonzero(gap)
    ask, up, r, slack = ask[keep], up[keep], r[keep], slack[keep]
    cell = np.floor(at[ask] / (OPENNESS_CELL * r[:, None])).astype(np.int64)
    _, first, shared = np.unique(np.column_stack([tri[ask], cell]), axis=0, return_index=True, return_inverse=True)
    one, up1, r1 = ask[first], up[first], r[first]
    dirs = hemisphere_rays(up1, rays, turn[one])
    if caster is not None:
        best = _distances(caster, at[one], up1, dirs, r1, slack[first])
    else:
        pair_p, pair_t, _ = index.candidates(at[one], up1, r1)
        best, _, _, _ = index.trace(at[one], up1, dirs, r1, slack[first], pair_p, pair_t)
    open_hit = (1.0 - np.clip((r1[:, None] - best) / (FADE * r1[:, None]), 0.0, 1.0).mean(axis=1))[shared.ravel()]
    return ask, np.minimum(1.0, (open_hit[:, None] + OPENNESS_FLOOR) / (open_c[ask] + OPENNESS_FLOOR))
