"""How many points each soft light's shadows are drawn from: an area light's stratified
points, a soft point or spot light's points on its sphere, each a depth cube map drawn and
every lit point tested against it (:mod:`cubegi_engine.direct`).

Pure numpy; must not import bpy.
"""

import numpy as np

from . import lights as lights_mod

__all__ = ["shadow_eyes", "fewer_samples", "soft", "soft_count", "reach", "SHADOW_EYES"]

# A point or spot light whose radius is at least this share of its median distance to the
# scene's points casts soft shadows: its visibility is averaged over depth cube maps drawn
# from SOFT_SAMPLES points on its sphere (each at half the sharp map's edge, and no smaller
# than an area light's). Smaller ones keep one sharp map from the centre (a 1 cm bulb).
SOFT_RADIUS_SHARE = 0.02
SOFT_SAMPLES = 32
# Every sample draws the whole scene six times: past this many triangles the samples drop in
# proportion (to no fewer than MIN_SOFT_SAMPLES), so a heavy scene's soft light costs about
# what a light scene's does (on a GPU the drawing is cheap and this could go).
SOFT_TRIANGLES, MIN_SOFT_SAMPLES = 100_000, 8
# Soft shadows are drawn from several eyes (an area light's stratified points, a soft light's
# sphere points), each a cube map drawn and every lit point tested against it. How many a
# light gets (see shadow_eyes): what its size subtends from the points it lights, all of
# them at FULL_SOFT_ANGLE (radians) or more, a coarser square below it (a 10 cm panel across
# a hall: one); and a scene's soft lights share SHADOW_EYES between them equally, none more
# than it needs (not by their power: a power edit then keeps every light's maps, as an
# update does). An update that moves a light draws it again from the eyes the bake gave it
# (relight.solved_light): where the move takes its need past a grid's count (1, 4, 16, 64),
# a fresh bake would share them otherwise, until the next full bake. Measured against Cycles, the benchmark's Cornell box lit by one square area
# light, direct rel. RMSE with 1 / 4 / 16 / 64 eyes: a 0.6 m light 13.6 / 5.1 / 2.4 / 1.6%,
# 0.25 m 8.9 / 4.4 / 1.9 / 1.6%, 0.08 m 2.0 / 2.5 / 2.1 / 3.2% (given 64, 64 and 16). A hall
# lit by thirteen 1.2 x 0.5 m lamps (benchmark --lights): 4 eyes each instead of 64, its
# direct light 26.3 s -> 3.7 s (1.3x the bake of one lamp) and its error 3.2% -> 3.5%.
FULL_SOFT_ANGLE = 0.25
SHADOW_EYES = 128
# Sun shadow map frustum: a box around the scene's bounding sphere (radius grown by 1% so
# that its surface is inside), seen from two radii away along the sun's direction; near
# and far leave a margin of a thousandth of the radius and two radii beyond the scene.
SUN_BOX_MARGIN = 1.01
SUN_EYE_DISTANCE = 2.0
SUN_NEAR, SUN_FAR = 1e-3, 4.0


def soft(light, points) -> bool:
    """Whether a point or spot light's radius makes its shadows soft (see SOFT_RADIUS_SHARE)."""
    if light.kind not in ("POINT", "SPOT") or light.radius <= 0.0 or not len(points):
        return False
    return light.radius >= SOFT_RADIUS_SHARE * float(np.median(np.linalg.norm(points - light.position, axis=1)))


def fewer_samples(samples, count):
    """An area light's stratified ``samples`` ``(m^2, 3)`` (an m x m grid, as
    :func:`~cubegi_engine.lights.area_samples` lays them) as at most ``count`` points, one per
    square block of them, a side that divides m: on a square or rectangle (a grid even in
    both directions) the blocks' means, the stratified points of a coarser grid; on a disk
    or ellipse (rings and angles: a block's mean would sit inside its ring, the eyes drawn
    together) each block's middle sample, and one eye at the centre. Samples that are not such a grid are kept."""
    m = int(round(np.sqrt(len(samples))))
    if count is None or m * m != len(samples) or count >= len(samples):
        return samples
    side = max(k for k in range(1, m + 1) if m % k == 0 and k * k <= max(int(count), 1))
    grid = samples.reshape(m, m, 3)
    blocks = grid.reshape(side, m // side, side, m // side, 3)
    even = m < 3 or (np.allclose(np.diff(grid, 2, axis=0), 0.0, atol=1e-9 * np.ptp(samples))
                     and np.allclose(np.diff(grid, 2, axis=1), 0.0, atol=1e-9 * np.ptp(samples)))
    if even or side == 1:  # (one eye: the light's centre)
        return blocks.mean(axis=(1, 3)).reshape(-1, 3)
    return blocks[:, (m // side) // 2, :, (m // side) // 2].reshape(-1, 3)


def soft_count(scene):
    """A soft point or spot light's own eye count (see SOFT_TRIANGLES)."""
    return int(np.clip(SOFT_SAMPLES * SOFT_TRIANGLES / max(len(scene.triangles), 1), MIN_SOFT_SAMPLES, SOFT_SAMPLES))


def shadow_eyes(scene, lights, distances):
    """How many eyes each of ``lights`` is drawn from: a list of ints, None for a light with
    one eye of its own (a sun, a sharp point light: nothing to share). ``distances``:
    ``(n,)`` the light-weighted mean distance of the points each lights. See FULL_SOFT_ANGLE
    and SHADOW_EYES."""
    own, need = [], []
    for light, distance in zip(lights, distances):
        if light.kind == "AREA" and light.samples is not None and len(light.samples) > 1 and light.polygon is not None:
            full, poly = len(light.samples), np.asarray(light.polygon, dtype=np.float64)
            extent = float(np.max(np.linalg.norm(poly[:, None] - poly[None], axis=2)))
            wanted = full * min(extent / max(float(distance), 1e-12) / FULL_SOFT_ANGLE, 1.0) ** 2
            m = int(round(np.sqrt(full)))  # a grid's need is rounded up to a coarser grid's count
            count = min(k * k for k in range(1, m + 1) if m % k == 0 and k * k >= wanted) if m * m == full else int(np.ceil(wanted))
        elif light.kind in ("POINT", "SPOT") and light.casts_shadow and soft(light, scene.points):
            full = count = soft_count(scene)  # its own count already follows its size (SOFT_RADIUS_SHARE)
        else:
            own.append(None)
            need.append(0)
            continue
        own.append(full)
        need.append(int(np.clip(count, 1, full)))
    need = np.array(need, dtype=np.float64)
    given = need.copy()
    if need.sum() > SHADOW_EYES:  # shared equally; a light given all it needs leaves the rest to the others
        free, left = need > 0, float(SHADOW_EYES)
        while free.any():
            offer = left / free.sum()
            small = free & (need <= offer)
            if not small.any():
                given[free] = offer
                break
            left -= float(need[small].sum())
            free &= ~small
    return [None if o is None else len(fewer_samples(light.samples, int(g))) if light.kind == "AREA" else max(1, int(g))
            for light, o, g in zip(lights, own, given)]


def reach(scene):
    """Each light's strongest unshadowed light at any point, and the light-weighted mean
    distance of the points it lights: two lists."""
    areas = scene.point_areas()
    reach, distances = [], []
    for light in scene.lights:
        value = lights_mod.unshadowed(light, scene.points, scene.normals)
        w = value.mean(axis=1) * areas
        reach.append(float(value.max(initial=0.0)))
        d = np.linalg.norm(scene.points - light.position, axis=1)
        distances.append(float(np.sum(w * d) / w.sum()) if w.sum() > 0 else 1.0)
    return reach, distances
