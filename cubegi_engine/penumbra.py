"""A sun's soft shadows: the receivers near a shadow's edge take rays across the sun's disk.

A sun with an Angle (its disk's angular diameter: the Sun's own is about half a degree)
blurs each shadow's edge over the occluder's distance times that angle: a window blind's
slat 3 m from a counter, about 3 cm, as wide as the gaps between the slats. Cycles samples
the disk. Here the sun's orthographic depth map still decides every receiver whose
neighbourhood within the widest penumbra (the map's own depth times the angle) holds no
shadow edge: either no surface stands before it there (lit), or every texel there sees one
(in shadow). The others take SUN_DISK_RAYS rays across the disk, each weighted by its cosine,
through the host's ray caster; without a caster the map's sharp answer stands.

Pure numpy; must not import bpy.
"""

import numpy as np

from . import cubemap
from .hemisphere import GOLDEN_ANGLE, TURN_HASH
from .lifts import ray_starts
from .lights import MIN_COS, ortho_lookup, ortho_visibility
from .working import made_once

__all__ = ["sun_visibility", "disk_directions", "SUN_DISK_RAYS"]

# Rays across the sun's disk for a receiver near a shadow's edge (a sunflower pattern, turned
# per receiver): FIRST_RAYS and one to the middle, then SUN_DISK_RAYS where those disagree; and
# the widest neighbourhood searched for an edge, in texels each way.
SUN_DISK_RAYS, FIRST_RAYS = 16, 6
MAX_WINDOW = 32
# A group of receivers asked together (see _shared_disk_share): its depths step by at most
# GROUP_DEPTH texels and its normals turn by at most GROUP_TURN (a cosine) between neighbours.
GROUP_DEPTH, GROUP_TURN = 0.5, 0.9


def sun_visibility(receivers, occluders, view, depth_map, angle):
    """``(s,)`` in [0, 1]: how much of a sun of angular diameter ``angle`` (radians) reaches
    each receiver, its shadows from ``depth_map`` drawn along ``view`` (an OrthoView)."""
    if angle <= 0.0 or occluders.rays is None or not len(receivers):
        return ortho_visibility(receivers, occluders, view, depth_map)
    n = depth_map.size
    spread = np.tan(0.5 * angle)
    lookup, inside = ortho_lookup(receivers, view, n, occluders)  # (made once: the sharp map's test reads it too)
    sharp = ortho_visibility(receivers, occluders, view, depth_map, (lookup, inside))
    edge = inside & (receivers.normals @ -view.axis > -spread) & _near_an_edge(depth_map, lookup, spread, n)
    ask = np.flatnonzero(edge)
    if not len(ask):
        return sharp
    share, centre_open = _shared_disk_share(receivers, occluders, view.axis, spread, lookup, ask, n, sharp[ask])
    out = sharp.copy()
    # Where the map shadows a receiver that the ray from its middle of the disk passes, the
    # map knows better: a surface standing on the receiver's own (a wall on a floor, whose
    # bottom edge a ray starting on it slips under), where Cycles has no light either.
    out[ask] = np.where((sharp[ask] == 0.0) & centre_open, 0.0, share)
    return out


def _near_an_edge(depth_map, lookup, spread, n):
    """``(s,)`` bool: whether a shadow's edge may lie within each receiver's penumbra: within
    ``w`` texels of it, its map holds a surface in front of it and one that is not.

    An occluder ``D`` in front of a receiver blurs its edge over ``D`` times ``spread``, so it
    can reach the receiver only from within ``w = D spread / texel + 1`` texels. Every occluder
    within the widest window (the map's own depth times the angle) is at most as far as the
    nearest surface there, which bounds ``w`` (the Breakfast Room's sun asked 71,589 receivers'
    rays from the widest window, 63,029 so; 8,042 of them stand in a penumbra). ``w`` is taken
    up to a power of two: a few windows' filters, made for this call alone (the widest is
    kept with the map)."""
    widest = int(min(MAX_WINDOW, np.ceil(n * spread) + 1))
    nearest = _window(depth_map, widest)[0][0, lookup.row, lookup.col]
    reach = np.minimum(np.maximum(lookup.depth - nearest, 0.0) * spread / lookup.footprint, widest)
    window = np.clip(2 ** np.ceil(np.log2(np.ceil(reach) + 1)), 1, widest)
    window = np.where(nearest < lookup.depth, window, 0).astype(np.int64)
    edge = np.zeros(len(window), dtype=bool)
    for w in np.unique(window[window > 0]):  # (0: nothing in front, no edge)
        some = np.flatnonzero(window == w)
        near, far = _window(depth_map, int(w)) if w == widest else _filters(depth_map, int(w))
        pick = (0, lookup.row[some], lookup.col[some])
        # Depth changes across the window on a receiver's own tilted surface; that is no edge.
        level = lookup.depth[some] - w * lookup.footprint[some] / np.maximum(lookup.cos[some], MIN_COS)
        edge[some] = (near[pick] < level) & (far[pick] >= level)
    return edge


def _shared_disk_share(receivers, occluders, axis, spread, lookup, ask, n, sharp):
    """:func:`_disk_share` of the receivers ``ask`` (their map's answers ``sharp``), the first
    rays of a group of them cast from its outermost members alone.

    A group is the receivers of one texel on one surface (their depths step by at most
    GROUP_DEPTH texels, their normals turn by at most GROUP_TURN); its
    outermost members are those farthest along each of 8 directions across the map. A
    penumbra's straight edge that reaches into the group reaches the member nearest it, an
    outermost one: where those all see the whole disk, or none of it, alike, so do the others
    (a texel the map answers differently holds a shadow's corner: none share there). (A
    subdivided mesh puts many receivers in a texel: the Breakfast Room subdivided twice asks
    545,940 receivers, whose disk rays are 4.98M each on its own and 4.27M so.)"""
    texel = lookup.row[ask] * n + lookup.col[ask]
    depth, normals, at = lookup.depth[ask], receivers.normals[ask], lookup.origins[ask]
    order = np.lexsort((depth, texel))
    change = np.ones(len(order), dtype=bool)
    change[1:] = texel[order][1:] != texel[order][:-1]
    starts = np.flatnonzero(change)
    # A texel the map answers differently holds a shadow's corner, which cuts a notch into a
    # group: the receivers about it stand in a penumbra that the outermost members, beyond
    # the notch, do not see. None there shares an answer.
    mixed = np.empty(len(ask), dtype=bool)
    mixed[order] = np.repeat(np.minimum.reduceat(sharp[order], starts) != np.maximum.reduceat(sharp[order], starts),
                             np.diff(np.append(starts, len(order))))
    change[1:] |= ((np.diff(depth[order]) > GROUP_DEPTH * lookup.footprint[ask][order][1:])
                   | (np.einsum("kc,kc->k", normals[order][1:], normals[order][:-1]) < GROUP_TURN))
    group = np.empty(len(ask), dtype=np.int64)
    group[order] = np.cumsum(change) - 1
    e1 = cubemap.any_perpendicular(np.asarray(axis, dtype=np.float64))
    e2 = np.cross(axis, e1)
    firsts = np.flatnonzero(change)  # each group's run in ``order``
    sizes = np.diff(np.append(firsts, len(order)))
    outer = np.zeros(len(ask), dtype=bool)
    for d in (e1, e2, e1 + e2, e1 - e2):
        along = at[order] @ d
        for x in (along, -along):  # the first of each group's farthest (one of a row of ties)
            at_most = np.flatnonzero(x >= np.repeat(np.maximum.reduceat(x, firsts), sizes))
            run = group[order[at_most]]
            outer[order[at_most[np.append(True, run[1:] != run[:-1])]]] = True
    outer &= ~mixed
    reps = np.flatnonzero(outer)
    share, centre_open, split = np.zeros(len(ask)), np.zeros(len(ask), dtype=bool), np.zeros(len(ask), dtype=bool)
    start = ray_starts(receivers, occluders, lookup.footprint, ask[reps])
    share[reps], centre_open[reps], split[reps] = _disk_rays(normals[reps], occluders, axis, spread, start, FIRST_RAYS)
    # A group agrees where its outermost members are none split and alike (one code each:
    # the share, 0 or 1, the middle ray's answer and whether split).
    k = group[reps]
    groups = int(group.max()) + 1
    code = share[reps] + 2.0 * centre_open[reps] + 4.0 * split[reps]
    lo, hi = np.full(groups, np.inf), np.full(groups, -np.inf)
    np.minimum.at(lo, k, code)
    np.maximum.at(hi, k, code)
    agree = (lo == hi) & (lo < 4.0)
    rest = np.flatnonzero(~outer & ~agree[group])
    inner = np.flatnonzero(~outer & agree[group])
    if len(inner):  # each takes its group's answer (any outermost member's)
        one = np.empty(groups, dtype=np.int64)
        one[k] = reps
        share[inner], centre_open[inner] = share[one[group[inner]]], centre_open[one[group[inner]]]
    if len(rest):  # an edge passes among them: each asks its own
        share[rest], centre_open[rest] = _disk_share(receivers, occluders, axis, spread, lookup.footprint, ask[rest])
    again = reps[split[reps]]
    if len(again):
        share[again], _, _ = _disk_rays(normals[again], occluders, axis, spread, start[split[reps]], SUN_DISK_RAYS)
    return share, centre_open


def _disk_share(receivers, occluders, axis, spread, footprint, ask):
    """``(share (k,), centre_open (k,) bool)``: the cosine-weighted share of the sun's disk (a
    cone of half-angle tangent ``spread`` about ``-axis``) that rays leave unblocked from
    receivers ``ask``, and whether the ray to the disk's middle passes. FIRST_RAYS rays first;
    where they disagree (the receiver is in a penumbra), SUN_DISK_RAYS."""
    start = ray_starts(receivers, occluders, footprint, ask)
    share, centre_open, split = _disk_rays(receivers.normals[ask], occluders, axis, spread, start, FIRST_RAYS)
    if split.any():
        share[split], _, _ = _disk_rays(receivers.normals[ask[split]], occluders, axis, spread, start[split], SUN_DISK_RAYS)
    return share, centre_open


def _disk_rays(normals, occluders, axis, spread, start, count):
    """``count`` rays across the disk and one to its middle from each of ``start (m, 3)``:
    ``(share (m,), centre_open (m,), split (m,))``, split where the rays disagree."""
    to_sun = -np.asarray(axis, dtype=np.float64)
    dirs = np.concatenate([disk_directions(to_sun, 2.0 * np.arctan(spread), start, occluders.scale, count),
                           np.broadcast_to(to_sun, (len(start), 1, 3))], axis=1)
    weight = np.maximum(np.einsum("mkc,mc->mk", dirs, normals), 0.0)
    origins = np.repeat(start, dirs.shape[1], axis=0)
    open_ = ~occluders.rays().blocked(origins, dirs.reshape(-1, 3), None).reshape(weight.shape)
    total = weight[:, :-1].sum(axis=1)
    share = np.where(total > 0, (weight[:, :-1] * open_[:, :-1]).sum(axis=1) / np.maximum(total, 1e-300), 0.0)
    return share, open_[:, -1], open_.any(axis=1) & ~open_.all(axis=1)


def disk_directions(to_sun, angle, origins, scale, count):
    """``(k, count, 3)`` unit directions from each of ``origins (k, 3)`` over the disk of a sun
    of angular diameter ``angle`` about the unit ``to_sun``: a sunflower pattern of ``count``
    rays, turned by a hash of the origin (``scale``: the scene's size)."""
    to_sun = np.asarray(to_sun, dtype=np.float64)
    k = np.arange(count)
    radius = np.sqrt((k + 0.5) / count)
    turn = 2.0 * np.pi * ((np.asarray(origins, dtype=np.float64) / max(scale, 1e-300)) @ TURN_HASH % 1.0)
    theta = k[None, :] * GOLDEN_ANGLE + turn[:, None]
    e1 = cubemap.any_perpendicular(to_sun)
    e2 = np.cross(to_sun, e1)
    offset = np.tan(0.5 * angle) * radius[None, :, None] * (np.cos(theta)[..., None] * e1 + np.sin(theta)[..., None] * e2)
    dirs = to_sun + offset
    return dirs / np.linalg.norm(dirs, axis=2, keepdims=True)


def _window(depth_map, window):
    """:func:`_filters`, made once per map and window (kept with the map)."""
    return made_once(depth_map, f"_window_{window}", lambda: _filters(depth_map, window))


def _filters(depth_map, window):
    """``(nearest, farthest)``, each ``(f, n, n)``: over each texel and those within ``window``
    of it on its face, the nearest surface's distance (front or back: either stands in the
    sun's way) and the farthest (a texel that sees none: infinitely far)."""
    seen = np.where(depth_map.tid >= 0, depth_map.dist, np.inf).astype(np.float32)
    return cubemap.square_filter(seen, window, np.minimum), cubemap.square_filter(seen, window, np.maximum)
