"""Where a shadow test asks about a receiver: where its rays start (off its surface, and into
its own triangles) and the point a sun's maps look it up at, there too (:mod:`.lights`,
:mod:`.penumbra`, :mod:`.sky`; a lamp's cube maps lift it alone, see :func:`map_points`).

Pure numpy; must not import bpy.
"""

import numpy as np

from . import geometry
from .spatial import COORD_SLACK

__all__ = ["LIFT", "RAY_LIFT", "map_points", "ray_starts", "ray_lift", "into_own"]

# How far (in texel footprints at the receiver) a receiver is lifted along its normal before its
# shadow-map lookup: enough to step off its own curved surface, well below the gap under a rug.
LIFT = 0.25
# A ray asked where the map cannot decide starts off its receiver's surface by half the
# map's own lift (the map's whole lift, a quarter of a texel, could carry it out of the fold
# it lies in), but at most RAY_LIFT of the scene's size (never a share of the whole scene
# alone: a 5 mm gap under a rug in a scene 2 km wide must hold) and at least COORD_SLACK of
# the receiver's coordinates (a float32 mesh's rounding); and as far again into its own
# triangles (see geometry.inward). A surface through the receiver itself (a wall standing on
# the floor where the floor ends, walls meeting at a corner) then lies on one side of the
# start: it shadows the rays that go through it and no others, as the map's back-face rule
# has it. (A start moved along the ray instead went through such a wall on every ray heading
# into it: the courtyard's sky per vertex by rays, direct light 19.7% off Cycles; from starts
# into their own triangles 1.4%, by maps 1.8%.)
RAY_LIFT = 1e-5


def ray_starts(receivers, occluders, footprint, ask):
    """Where the rays of receivers ``ask`` start (see RAY_LIFT): ``(k, 3)``."""
    at, normals = receivers.points[ask], receivers.normals[ask]
    lift = ray_lift(at, occluders, footprint[ask])
    return at + lift[:, None] * normals + into_own(receivers[ask], occluders, lift)


def ray_lift(at, occluders, footprint):
    """How far off its surface, and into its own triangles, a receiver's ray starts (see
    RAY_LIFT): ``(k,)``."""
    return np.maximum(np.minimum(0.5 * LIFT * footprint, RAY_LIFT * occluders.scale), COORD_SLACK * np.abs(at).max(axis=1))


def into_own(receivers, occluders, lift):
    """``(k, 3)``: each receiver's step of ``lift (k,)`` into its own triangles, along its
    surface (:func:`~.geometry.inward`; none for a receiver not among the occluders)."""
    ids, normals = receivers.ids, receivers.normals
    if not np.any(ids >= 0):  # no receiver among these surfaces (a moving object's, against the scene's)
        return np.zeros(normals.shape)
    inward = occluders.inward() if occluders.inward is not None else geometry.inward(occluders.triangles, occluders.vertices)
    into = np.where((ids >= 0)[:, None], inward[np.maximum(ids, 0)], 0.0)
    into -= np.einsum("kc,kc->k", into, normals)[:, None] * normals  # along the surface
    return lift[:, None] * into


def map_points(receivers, occluders, footprint):
    """Where a sun's map looks each receiver up: lifted off its surface by LIFT of its texel's
    ``footprint (s,)``, and as far into its own triangles as its rays start (:func:`ray_starts`).
    A surface whose edge the receiver lies on (a window's reveal where a slat's end meets it,
    seen edge-on from the sun) then lies on one side of it, for the map as for its rays: the
    map's exact plane cut no longer lands on that edge, inside the surface beyond it. (A
    lamp's cube maps look receivers up lifted alone: there the same step put a block's top
    corner in a shadow Cycles does not cast, one eye of an emitter's in 16.)"""
    at = receivers.points
    return at + receivers.normals * (LIFT * footprint)[:, None] + into_own(receivers, occluders, ray_lift(at, occluders, footprint))
