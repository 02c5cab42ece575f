"""Emissive surfaces as area lights: their direct light per point, exact, from both faces.

Pure numpy; must not import bpy.

Cycles counts the light that reaches a point straight from an emissive surface as direct
light, and an emissive face emits from both sides. Each emissive triangle of radiance L
gives a point the diffuse light ``L F`` with F the exact form factor of the triangle seen
from the point (Lambert's polygon formula, clipped to the point's hemisphere,
:func:`cubegi_engine.lights.polygon_form_factor`), from whichever side the point is on.
Shadows come from cube depth maps drawn at sample points on the emitters (an emissive
object's area split in ``SAMPLES`` equal shares), lifted off each side; a point is tested
against the samples on its side of each sample's face, weighted as an area light's are, each
flat face with samples enough by its own (a glowing box's top and bottom are shadowed apart).

Cost: one form factor per flat group of emissive triangles and point (a subdivided panel is
one group, walked by its outline), the lone triangles of a curved emitter summed at once
(far ones as small patches, :func:`_lone_ff`), and ``SAMPLES`` cube maps per emissive
object at the area-shadow size.
"""

from dataclasses import dataclass

import numpy as np

from . import cubemap
from . import lights as lights_mod
from .cubemap import capture_cubes, clip_planes
from .geometry import run_offsets

__all__ = ["balanced_landing", "emissive_triangles", "emitting_points", "emitting_triangles", "emitter_direct", "gap_closed", "trapped_light",
           "TrappedLight", "SAMPLES"]

# Shadow sample points per emissive object (each drawn from both faces). The white box's
# 0.5 m panel (8 triangles), direct light against Cycles: 8 points at the triangles'
# centroids 1.9-2.1%; 16 spread over the triangles 1.1-1.5% (four seeds of the maps' turns),
# 0.05 s more on a 0.4 s bake.
SAMPLES = 16
# A flat group of an emissive object (a glowing box's face) with at least this many of the
# object's samples on it is shadowed by its own (see emitter_direct); the rest share all.
OWN_SHARE_SAMPLES = 2
# Sample eyes sit this share of the scene's size off the emitter, on each side.
EYE_LIFT = 1e-4


def emissive_triangles(scene):
    """``(corners (e, 3), radiance (e, 3))``: the triangles whose three corners emit, by point
    indices, with the mean of their corners' emission. Where the bake cut emissive triangles
    to sample the light they reflect (``scene.emitting``), the triangles as modelled: their
    light is the same, and a panel stays one flat group walked by its outline."""
    corners = np.asarray(scene.triangles, dtype=np.int64).reshape(-1, 3)[emitting_triangles(scene)]
    if scene.emitting is not None:  # an emitter's pieces give way to it (it may emit no more)
        modelled = np.asarray(scene.emitting, dtype=np.int64).reshape(-1, 3)
        corners = np.concatenate([corners, modelled[emitting_points(scene)[modelled].all(axis=1)]])
    return corners, scene.emission[corners].mean(axis=1)


def emitting_points(scene) -> np.ndarray:
    """``(s,)`` bool: the points of ``scene`` that emit light."""
    return np.any(np.asarray(scene.emission) > 0, axis=1)


def emitting_triangles(scene) -> np.ndarray:
    """``(t,)`` bool: the triangles of ``scene.triangles`` whose three corners emit, but a
    sheet's twins (they emit what the sheet does, from the same place: counted once) and the
    pieces of an emitter the bake cut (``scene.emitter_pieces``: it counts as modelled)."""
    out = np.all(emitting_points(scene)[scene.triangles], axis=1) & ~scene.back_triangles()
    return out & ~np.asarray(scene.emitter_pieces, dtype=bool) if scene.emitter_pieces is not None else out


# Receivers are moved this share of the scene's size off their surface and into their own
# faces before the form factors, as Cycles moves a ray's origin a little into the face. A
# point on a box's edge lies in the plane of the face across the edge, which Lambert's
# formula then sees edge-on (no light); moved into its face it sees that face's light, and
# a coplanar emitter beside it (a panel set into a ceiling) falls below its hemisphere.
RECEIVER_NUDGE = 1e-5
# A surface point is between an emitter and itself (light trapped in the gap) where emissive
# surfaces fill at least this share of its cosine-weighted view within the near field's reach.
TRAPPED_VIEW = 0.5
# ... and where they fill at least this share, the light is held in a gap (see balanced_landing).
GAP_VIEW = 0.9


@dataclass(frozen=True)
class TrappedLight:
    """An emitter close in front of a surface, nearer than the near field's reach (a share of
    a probe cell): the light bouncing between them is gathered by the near field alone.
    ``emitter``, ``surface``: object indices (``SceneArrays.point_object``); ``gap``: the
    median distance of the surface's points from the emitter, along their normals;
    ``points``: the surface's points that face it; ``view``: the largest share of such a
    point's view the emitter fills."""

    emitter: int
    surface: int
    gap: float
    points: int
    view: float


def trapped_light(scene, near, at_least=TRAPPED_VIEW):
    """Where an emitter fills at least ``at_least`` of a surface point's view within the
    near field's reach (``near``: :class:`~cubegi_engine.nearfield.NearField`): a list of
    :class:`TrappedLight`, one per (emitter, surface) pair, largest first. Empty without a
    near field or emitters, or where ``scene.point_object`` is not given."""
    if near is None or not near.count or scene.point_object is None:
        return []
    emits = np.any(scene.emission > 0, axis=1)
    if not emits.any():
        return []
    on_emitter = near.hit_weight * emits[near.hit_corner]  # (h, 3)
    view = np.bincount(near.hit_row, on_emitter.sum(axis=1), minlength=near.count)
    rows = np.flatnonzero((view >= at_least) & ~emits[near.rows])
    if not len(rows):
        return []
    owner = scene.point_object
    hits = np.flatnonzero(np.isin(near.hit_row, rows) & (on_emitter.sum(axis=1) > 0))
    point = near.rows[near.hit_row[hits]]
    # Each hit's distance along the point's normal, and the emitter object it lands on.
    corner = near.hit_corner[hits]
    offset = np.einsum("hkj,hj->hk", scene.points[corner] - scene.points[point][:, None], scene.normals[point])
    dist = (on_emitter[hits] * offset).sum(axis=1) / on_emitter[hits].sum(axis=1)
    emitter = owner[corner[np.arange(len(hits)), np.argmax(on_emitter[hits], axis=1)]]
    found = []
    for e, surface in np.unique(np.stack([emitter, owner[point]], axis=1), axis=0).tolist():
        mine = (emitter == e) & (owner[point] == surface)
        facing = np.unique(point[mine])
        found.append(TrappedLight(e, surface, float(np.median(np.abs(dist[mine]))), len(facing),
                                  float(view[np.isin(near.rows, facing)].max())))
    return sorted(found, key=lambda t: -t.points)


def balanced_landing(scene, transport):
    """``transport``'s :meth:`~cubegi_engine.transport.Transport.landing_share`, or None where
    the energy balance cannot hold: where an emitter closes a surface point in over GAP_VIEW of
    its view (:func:`trapped_light`: a lamp close in front of a ceiling; not a glowing wall's
    foot on the floor, which it fills half the view of). The balance weighs the power the
    points send that lands against the light the probes bring; the light bouncing in such a
    gap is sent and received within it, by the near field alone, so it counts on one side
    only (McGuire's Cornell box, its ceiling sampled finely over the lamp: the walls 1.6x
    Cycles' indirect light, 1.05x without the balance; a hand-made room with a panel 1 cm
    under its ceiling 1.7x and 1.00x)."""
    if gap_closed(trapped_light(scene, transport.near)):
        return None
    return transport.landing_share()


def gap_closed(traps) -> bool:
    """Whether any of ``traps`` (:func:`trapped_light`'s) closes a surface point in over
    GAP_VIEW of its view: where the bake leaves out the energy balance (:func:`balanced_landing`)."""
    return any(trap.view >= GAP_VIEW for trap in traps)


def _two_sided_ff(points, normals, tri):
    """Lambert's form factor of ``tri (3, 3)`` (or ``(s, 3, 3)``, one per point) from either face."""
    return np.maximum(lights_mod.polygon_form_factor(points, normals, tri),
                      lights_mod.polygon_form_factor(points, normals, tri[..., ::-1, :]))


# A lone emissive triangle (a curved emitter's: a glowing sphere is hundreds of flat groups of
# one) seen from farther than FAR_RADII times its bounding radius lights a point as its area at
# its centroid would (off by about (r / d)^2: 0.4% here); nearer, Lambert's formula. A point
# and FAR_PAIRS triangles' temporaries at a time.
FAR_RADII, FAR_PAIRS = 16.0, 1 << 22


def _lone_ff(points, normals, verts, radiance):
    """The two-sided light ``(s, 3)`` of the lone triangles ``verts (g, 3, 3)`` of radiance
    ``(g, 3)`` at the points: their form factors, each as :func:`_two_sided_ff` gives it near
    and as a small patch far (see FAR_RADII), summed by matrix products, not a pass over the
    points per triangle (a glowing subdivided ball's 1,500 triangles: 53 s -> under a second
    in a small room)."""
    centre = verts.mean(axis=1)
    cross = np.cross(verts[:, 1] - verts[:, 0], verts[:, 2] - verts[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    unit = cross / np.maximum(area2, 1e-300)[:, None]
    far2 = (FAR_RADII * np.linalg.norm(verts - centre[:, None], axis=2).max(axis=1)) ** 2
    out = np.zeros((len(points), 3))
    near_p, near_t = [], []
    step = max(1, FAR_PAIRS // len(verts))
    for first in range(0, len(points), step):
        sl = slice(first, first + step)
        to = centre[None] - points[sl, None]  # (c, g, 3)
        d2 = np.einsum("cgk,cgk->cg", to, to)
        far = d2 > far2[None]
        cos_r = np.maximum(np.einsum("cgk,ck->cg", to, normals[sl]), 0.0)
        cos_e = np.abs(np.einsum("cgk,gk->cg", to, unit))
        ff = np.where(far, 0.5 * area2[None] * cos_r * cos_e / (np.pi * np.maximum(d2, 1e-300) ** 2), 0.0)
        out[sl] += ff @ radiance
        p, t = np.nonzero(~far)
        near_p.append(p + first)
        near_t.append(t)
    p, t = np.concatenate(near_p), np.concatenate(near_t)
    ahead = np.einsum("mkc,mc->mk", verts[t] - points[p, None], normals[p]).max(axis=1) > 0.0
    p, t = p[ahead], t[ahead]  # (wholly behind a point's tangent plane: none of its light; a ball's own points)
    if len(p):
        np.add.at(out, p, _two_sided_ff(points[p], normals[p], verts[t])[:, None] * radiance[t])
    return out


# Emissive triangles lie in one plane if their unit normals agree to this and their planes'
# offsets to this share of the scene's size.
FLAT_NORMAL, FLAT_OFFSET = 1e-6, 1e-6


def _flat_groups(verts, radiance, owner, scale):
    """The emissive triangles ``verts (e, 3, 3)`` in groups (index arrays) that share an
    object, a radiance and a plane, facing one way: a subdivided panel is one group."""
    cross = np.cross(verts[:, 1] - verts[:, 0], verts[:, 2] - verts[:, 0])
    length = np.linalg.norm(cross, axis=1)
    unit = cross / np.maximum(length, 1e-300)[:, None]
    offset = np.einsum("ec,ec->e", unit, verts[:, 0])
    key = np.concatenate([owner[:, None].astype(np.float64), np.round(unit / FLAT_NORMAL),
                          np.round(offset / (FLAT_OFFSET * max(scale, 1e-300)))[:, None], radiance], axis=1)
    key[length <= 0, 1:4] = np.arange(np.sum(length <= 0))[:, None] + 1e12  # no plane: alone
    _, which = np.unique(key, axis=0, return_inverse=True)
    order = np.argsort(which.ravel(), kind="stable")
    bounds = np.flatnonzero(np.diff(which.ravel()[order])) + 1
    return np.split(order, bounds)


def _group_ff(points, normals, corner_ids, verts):
    """The two-sided form factor ``(s,)`` of a flat group of triangles (corner indices
    ``corner_ids (g, 3)``, positions ``verts (g, 3, 3)``): the sum of its triangles'. Lambert's
    formula is a sum over edges, and an edge two triangles of the group share is walked once
    each way: for a receiver whose tangent plane does not cut the group, only the group's
    outline counts (a 16 x 16 panel: 64 edges, not 1,536). The receivers it cuts (clipped to
    their hemispheres triangle by triangle) take the triangles one by one."""
    if len(verts) == 1:
        return _two_sided_ff(points, normals, verts[0])
    edges = np.stack([corner_ids, np.roll(corner_ids, -1, axis=1)], axis=2).reshape(-1, 2).astype(np.int64)
    ends = np.stack([verts, np.roll(verts, -1, axis=1)], axis=2).reshape(-1, 2, 3)
    base = int(edges.max()) + 1
    single = ~np.isin(edges[:, 0] * base + edges[:, 1], edges[:, 1] * base + edges[:, 0])
    outline = ends[single]  # (m, 2, 3)
    loop = _loop(edges[single], outline)
    out = np.zeros(len(points))
    cut = np.zeros(len(points), dtype=bool)
    step = max(1, (1 << 22) // len(outline))
    for first in range(0, len(points), step):  # (step, m) heights at a time
        sl = slice(first, first + step)
        # A flat region's extremes along any direction lie on its outline.
        height = normals[sl] @ outline[:, 0].T - np.einsum("sc,sc->s", normals[sl], points[sl])[:, None]
        lo, hi = height.min(axis=1), height.max(axis=1)
        cut[sl] = (lo < 0) & (hi > 0)
        whole = np.flatnonzero(lo >= 0) + first  # wholly in front (wholly behind: none)
        if len(whole):
            out[whole] = np.clip(np.abs(_edge_sum(points[whole], normals[whole], outline)), 0.0, 1.0)
    if cut.any():
        if loop is not None:  # one outline: clipped whole (a 16 x 16 panel: 64 corners, not 512 triangles)
            out[cut] = _two_sided_ff(points[cut], normals[cut], loop)
        else:
            for tri in verts:
                out[cut] += _two_sided_ff(points[cut], normals[cut], tri)
    return out


def _loop(edges, ends):
    """The outline's corners ``(m, 3)`` in order, where its edges ``edges (m, 2)`` (point
    indices, each walked from its first to its second; positions ``ends (m, 2, 3)``) make one
    closed loop; else None (holes, several pieces, a corner met twice)."""
    after = {int(a): k for k, a in enumerate(edges[:, 0])}
    if len(after) != len(edges):
        return None
    order, k = [], 0
    for _ in range(len(edges)):
        order.append(k)
        k = after.get(int(edges[k, 1]), -1)
        if k < 0:
            return None
        if k == 0:
            break
    if k != 0 or len(order) != len(edges):
        return None
    return ends[np.array(order), 0]


def _edge_sum(points, normals, edges):
    """Lambert's ``1/(2 pi) sum theta n . g`` over ``edges (m, 2, 3)`` (unclipped)."""
    total = np.zeros(len(points))
    for a, b in edges:
        u = a - points
        w = b - points
        u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-30)
        w /= np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-30)
        cross = np.cross(w, u)
        sin_t = np.linalg.norm(cross, axis=1)
        theta = np.arctan2(sin_t, np.einsum("sc,sc->s", u, w))
        total += theta * np.einsum("sc,sc->s", cross, normals) / np.maximum(sin_t, 1e-30)
    return total / (2.0 * np.pi)


def _into_faces(scene, step):
    """Every point moved ``step`` along its normal and ``step`` towards the centroids of its
    own triangles (into its faces)."""
    tri = scene.triangles
    centroids = scene.points[tri].mean(axis=1)  # (t, 3)
    count = np.bincount(tri.ravel(), minlength=len(scene.points)).astype(np.float64)
    mean = np.stack([np.bincount(tri.ravel(), np.repeat(centroids[:, c], 3), minlength=len(scene.points)) for c in range(3)], axis=1)
    inward = mean / np.maximum(count, 1.0)[:, None] - scene.points
    inward -= np.einsum("sc,sc->s", inward, scene.normals)[:, None] * scene.normals  # along the surface
    inward /= np.maximum(np.linalg.norm(inward, axis=1, keepdims=True), 1e-300)
    return scene.points + step * (scene.normals + inward)


def emitter_direct(scene, renderer, shadow_size, shadows=True):
    """Diffuse light ``(s, 3)`` straight from every emissive triangle of ``scene``. A flat
    group of an object's triangles (a face of a glowing box) with OWN_SHARE_SAMPLES samples
    on it is shadowed by those, the rest by all of the object's: a ceiling 1 cm over a box
    lamp sees the box's top lit and its bottom (whose light the top stops) dark, where one
    share of the whole box, weighted by each sample's nearness, gave the ceiling's two
    vertices over it 1.9 and 0.02 times Cycles' light."""
    corners, radiance = emissive_triangles(scene)
    out = np.zeros((len(scene.points), 3))
    if not len(corners):
        return out
    verts = scene.points[corners]  # (e, 3, 3)
    lifted = _into_faces(scene, RECEIVER_NUDGE * scene.scale)
    owner = np.zeros(len(corners), dtype=np.int64) if scene.point_object is None else np.asarray(scene.point_object)[corners[:, 0]]
    groups = _flat_groups(verts, radiance, owner, scene.scale)
    group = np.zeros(len(corners), dtype=np.int64)
    for g, members in enumerate(groups):
        group[members] = g
    for obj in np.unique(owner):
        mine = np.flatnonzero(owner == obj)
        centres, normals, picked = _samples(verts[mine], radiance[mine], SAMPLES)
        taken, count = np.unique(group[mine[picked]], return_counts=True)
        own = taken[count >= OWN_SHARE_SAMPLES] if shadows else taken[:0]
        form = {}  # the own groups' form factors (s,)
        rest = np.zeros_like(out)  # the other groups' light
        lone = [g for g in np.unique(group[mine]) if len(groups[g]) == 1 and g not in own]
        if lone:
            at = np.concatenate([groups[g] for g in lone])
            rest += _lone_ff(lifted, scene.normals, verts[at], radiance[at])
        for g in np.unique(group[mine]):
            if len(groups[g]) == 1 and g not in own:
                continue  # (above)
            ff = _group_ff(lifted, scene.normals, corners[groups[g]], verts[groups[g]])
            if g in own:
                form[g] = ff
            else:
                rest += ff[:, None] * radiance[groups[g][0]]
        if not shadows:
            out += rest
            continue
        lit = np.flatnonzero(np.any(rest > 0, axis=1) | np.any([f > 0 for f in form.values()] or [False], axis=0))
        label = np.searchsorted(own, group[mine[picked]])
        label[~np.isin(group[mine[picked]], own)] = len(own)  # the object's other samples
        num, den = _visibility(scene, renderer, shadow_size, centres, normals, lit, np.tile(label, 2), len(own) + 1)
        whole = _share(num.sum(axis=0), den.sum(axis=0), 1.0)
        out[lit] += rest[lit] * whole[:, None]
        for j, g in enumerate(own):
            out[lit] += (form[g][lit] * _share(num[j], den[j], whole))[:, None] * radiance[groups[g][0]]
    return out


def _share(num, den, otherwise):
    return np.where(den > 0, num / np.maximum(den, 1e-300), otherwise)


def _samples(verts, radiance, count):
    """Up to ``count`` sample points on triangles ``verts (e, 3, 3)``, spread by emitted
    power (area x radiance); with each its unit normal and triangle (index into verts). Fewer
    triangles than ``count`` (a quad panel) share the points by power, spread inside each
    triangle (a Hammersley set mapped onto it, area kept), not heaped at their centroids."""
    cross = np.cross(verts[:, 1] - verts[:, 0], verts[:, 2] - verts[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    power = area * radiance.sum(axis=1)
    if power.sum() <= 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    normals = cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-30)
    if len(verts) < count:
        keep = np.flatnonzero(power > 0)
        per = np.maximum(1, np.floor(count * power[keep] / power.sum()).astype(np.int64))
        tri = np.repeat(keep, per)
        k = run_offsets(per)
        m = per[np.repeat(np.arange(len(keep)), per)]
        r, t = np.sqrt((k + 0.5) / m), (_radical_inverse(k) + 0.5 / m) % 1.0
        b1, b2 = r * (1.0 - t), r * t  # the square onto the triangle, area kept
        a, b, c = verts[tri, 0], verts[tri, 1], verts[tri, 2]
        return a + b1[:, None] * (b - a) + b2[:, None] * (c - a), normals[tri], tri
    centroids = verts.mean(axis=1)
    # Equal shares of the power along the cumulative sum: the triangles at each quantile.
    cum = np.cumsum(power) / power.sum()
    picks = np.searchsorted(cum, (np.arange(count) + 0.5) / count)
    return centroids[picks], normals[picks], picks


def _radical_inverse(k):
    """Van der Corput's base-2 radical inverse of integers ``k``: ``(k,)`` in [0, 1)."""
    k = np.asarray(k, dtype=np.int64).copy()
    out, scale = np.zeros(len(k)), 0.5
    while k.any():
        out += (k & 1) * scale
        k >>= 1
        scale *= 0.5
    return out


def _visibility(scene, renderer, size, centres, normals, lit, label, labels):
    """``(visible weight, weight)``, each ``(labels, l)``, of the eyes lifted off both sides
    of one emissive object's samples ``centres``/``normals (k, 3)`` (the first k on the
    normals' side), summed by the eyes' ``label (2k,)``, for the ``lit (l,)`` points."""
    num, den = np.zeros((labels, len(lit))), np.zeros((labels, len(lit)))
    if not len(centres) or not len(lit):
        return num, den
    lift = EYE_LIFT * scene.scale
    eyes = np.concatenate([centres + lift * normals, centres - lift * normals])
    sides = np.concatenate([normals, -normals])
    near, far = clip_planes(scene.scale)
    turns = cubemap.turns(len(eyes))  # each map its own way: see cubemap.turns
    cap = capture_cubes(renderer, eyes, size, near, far, with_bary=False, turns=turns)
    pts, nrm = scene.points[lit], scene.normals[lit]
    occluders = lights_mod.Occluders(scene.triangles, scene.points, scene.scale, scene.sides())
    for k, (eye, side) in enumerate(zip(eyes, sides)):
        rel = eye - pts
        d2 = np.einsum("sc,sc->s", rel, rel)
        dist = np.sqrt(np.maximum(d2, 1e-300))
        cos_r = np.maximum(0.0, np.einsum("sc,sc->s", nrm, rel)) / dist
        cos_l = np.maximum(0.0, -(rel @ side)) / dist  # the receiver is on this eye's side
        w = cos_r * cos_l / np.maximum(d2, 1e-300)
        use = w > 0
        if not use.any():
            continue
        depth = lights_mod.DepthMap(cap.tid[k], cap.dist[k], cap.backface[k])
        v = lights_mod.shadow_visibility(lights_mod.Receivers(pts[use], nrm[use], lit[use]), occluders, eye, depth, reach=0,
                                         turn=turns[k])
        num[label[k], use] += w[use] * v
        den[label[k], use] += w[use]
    return num, den
