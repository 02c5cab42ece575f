"""The sky's direct light at the points the probes cannot light (the outer face of a thick
wall, every probe inside the room), or at every point (``BakeSettings.sky_per_vertex``):
the share of the sky each sees along its own lines of sight, by rays or by orthographic
depth maps drawn as a sun's.

Pure numpy; must not import bpy.
"""

from collections import deque

import numpy as np

from . import cubemap, sh
from . import lights as lights_mod
from .eyes import SUN_BOX_MARGIN, SUN_EYE_DISTANCE, SUN_FAR, SUN_NEAR
from .gather import scene_caster, scene_occluders, sky_pattern
from .lifts import ray_starts
from .records import direct_step
from .working import WORKERS, in_background, run, start, wait

__all__ = ["unit_sky_direct", "unit_sky_direct_steps", "sky_direct", "sky_direct_steps", "SKY_DIRECTIONS", "SKY_MAP_SIZE",
           "SKY_PER_VERTEX_DIRECTIONS", "SKY_PER_VERTEX_MAP_SIZE", "SKY_RAYS_AT_MOST"]


def unit_sky_direct(scene, renderer, transport, per_vertex=False) -> np.ndarray:
    """:func:`unit_sky_direct_steps` in one go."""
    return run(unit_sky_direct_steps(scene, renderer, transport, per_vertex))


def unit_sky_direct_steps(scene, renderer, transport, per_vertex=False, step=None):
    """Diffuse light ``(s, 3)`` of a sky of unit mean radiance (its pattern, if any): what
    the probes see of it (:meth:`Transport.seen_light`), and for the vertices no probe
    lights and nothing close encloses (the outer face of a thick wall: every probe is inside
    the room) the sky along their own lines of sight (:func:`sky_direct`). ``per_vertex``:
    every vertex a probe lights with any sky takes it along its own lines of sight too,
    SKY_PER_VERTEX_DIRECTIONS of them, drawn at SKY_PER_VERTEX_MAP_SIZE."""
    light = transport.seen_light(transport.sky_coefficients(np.ones(3)))
    alone = transport.covered.copy()
    if transport.near is not None:
        # Only a point closed in nearly all round (under a rug) is left to its near field: a
        # vertex where walls meet (half its view a wall) sees the sky along its own lines of
        # sight (the Breakfast Room's walls: direct light 0.0002 against Cycles' 0.16 when
        # half-enclosed points were left out).
        alone &= ~transport.near.enclosed(len(alone), SKY_ENCLOSED)
    alone &= ~transport.resting()  # not the underside of a block standing on the ground
    if per_vertex:  # every vertex its probes give any sky (one under a roof has none)
        alone |= ~transport.covered & (light.max(axis=1) > 0)
    if transport.gathered is not None:  # their own rays say it
        alone[transport.gathered.rows] = False
    if alone.any():
        sampling = (SKY_PER_VERTEX_DIRECTIONS, SKY_PER_VERTEX_MAP_SIZE) if per_vertex else (SKY_DIRECTIONS, SKY_MAP_SIZE)
        light[alone] = yield from sky_direct_steps(scene, renderer, np.flatnonzero(alone), *sampling, step=step,
                                                   rays_at_most=SKY_RAYS_AT_MOST)
    if transport.gathered is not None:
        light[transport.gathered.rows] = transport.gathered.sky
    return light


# A covered point whose near surroundings close in at least this share of its view takes
# no sky of its own (see unit_sky_direct).
SKY_ENCLOSED = 0.9
# The sky's direct light at a vertex no probe lights: its visibility along this many
# directions (a Fibonacci sphere), each an orthographic depth map of this edge, as a sun's.
# 64 -> 32: the Breakfast Room's sky (26,793 such vertices) 3.35 -> 1.73 s, direct error
# 6.11 -> 6.35%, indirect 34.04 -> 32.88%; the courtyard 0.31 -> 0.18 s, its errors unchanged;
# a hand-made room with a window 0.41 -> 0.33 s, indirect 23.2 -> 23.3%.
SKY_DIRECTIONS = 32
SKY_MAP_SIZE = 256
# The same for every vertex (``BakeSettings.sky_per_vertex``): on the sunlit courtyard of
# the benchmark, direct error 3.5% through the probes; 64 / 128 / 256 / 512 directions at
# 256: 4.3 / 2.6 / 1.8 / 1.5%; 256 directions at 128 / 384: 2.5 / 1.6%.
SKY_PER_VERTEX_DIRECTIONS = 256
SKY_PER_VERTEX_MAP_SIZE = 256
# Sky depth maps drawn and read back at a time: a step of about a tenth of a second on llvmpipe
# (The Breakfast Room: 32 at a time took 2.5-3.2 s between two steps of the modal bake).
SKY_MAPS_AT_ONCE = 2
# Where the points' rays across those directions are at most this many, a ray each way decides
# instead of the maps: the Breakfast Room's outside faces (26,793 points, 430K rays) by rays,
# direct light 6.35 -> 5.63% off Cycles, indirect 32.9 -> 32.6%, its window wall's mean -18.9 ->
# -11.2%, 0.3 s slower; the courtyard's 1,525 points, 24K rays, 0.15 -> 0.04 s. The courtyard's
# sky per vertex (3,242 points, 415K rays) 2.1 -> 1.4 s, direct 1.77 -> 1.39%. A ray costs
# 2-30 us (long ones through a large room the most) and a map several ms to a tenth of a second:
# the Breakfast Room's sky per vertex (7.3M rays) took 205 s by rays, 65 s by maps.
SKY_RAYS_AT_MOST = 500_000
# Every SKY_FIRST_EVERY-th direction is asked first (by rays or maps, each set of directions
# as SKY_RAYS_AT_MOST decides); a receiver whose first answers, at least SKY_FIRST_AT_LEAST
# of them, all meet a surface or all reach the sky takes that answer for its other
# directions (the Breakfast Room's outside faces: 79% see no sky along any of their rays,
# 10% see it along all; by rays 318K -> about 100K of them, 1.17 -> 0.35 s).
SKY_FIRST_EVERY, SKY_FIRST_AT_LEAST = 4, 3


def sky_direct(scene, renderer, which, directions=SKY_DIRECTIONS, size=SKY_MAP_SIZE, rays_at_most=0) -> np.ndarray:
    """Diffuse light ``(k, 3)`` of a sky of unit mean radiance (its pattern, if any) at the
    points ``which (k,)``, with the scene's shadows: the unoccluded sky for each normal (exact
    for a uniform sky; the pattern's 9 SH coefficients otherwise) times the share of it the
    point sees, measured along ``directions`` directions, each an orthographic depth map of
    ``size`` drawn with the sun's machinery, weighted by the sky's radiance and the cosine.
    ``rays_at_most``: where the points' lines of sight are at most this many, a ray each way
    decides instead of the maps (see SKY_RAYS_AT_MOST)."""
    return run(sky_direct_steps(scene, renderer, which, directions, size, rays_at_most=rays_at_most))


def sky_direct_steps(scene, renderer, which, directions=SKY_DIRECTIONS, size=SKY_MAP_SIZE, step=None, rays_at_most=0):
    """:func:`sky_direct` as a generator handing control back after each direction.

    Every SKY_FIRST_EVERY-th direction is asked first; a receiver whose first answers (at
    least SKY_FIRST_AT_LEAST of them) all agree takes that answer for its other directions,
    and only the others ask them (see SKY_FIRST_EVERY)."""
    dirs = sh.fibonacci_sphere(directions)  # towards the sky
    pattern = sky_pattern(scene, dirs)  # (k, 3)
    nrm = scene.normals[which]
    seen = np.zeros((len(which), 3))
    facing = np.zeros((len(which), 3))
    asked, opened = np.zeros(len(which), dtype=np.int64), np.zeros(len(which), dtype=np.int64)

    def add(done, first=False):
        for k, on, vis in done:
            w = (nrm[on] @ dirs[k])[:, None] * pattern[k][None, :]
            seen[on] += w * vis[:, None]
            facing[on] += w
            if first:
                asked[on] += 1
                opened[on] += vis > 0.5

    tests = _SkyTests(scene, renderer, which, dirs, size, rays_at_most, step)
    first = np.arange(len(dirs)) % SKY_FIRST_EVERY == 0
    add((yield from tests.run(np.flatnonzero(first), np.arange(len(which)))), first=True)
    decided = (asked >= SKY_FIRST_AT_LEAST) & ((opened == 0) | (opened == asked))
    agreed = (opened > 0).astype(np.float64)
    add([(k, on, agreed[on]) for k in np.flatnonzero(~first) for on in [np.flatnonzero(decided & (nrm @ dirs[k] > 0))] if len(on)])
    add((yield from tests.run(np.flatnonzero(~first), np.flatnonzero(~decided))))
    open_sky = np.ones((len(which), 3))
    if getattr(scene, "sky_map", None) is not None:  # the pattern's SH, as diffuse light per normal
        n = 16
        texel_dirs = cubemap.texel_directions(n).reshape(-1, 3)
        coeffs = sh.project(sky_pattern(scene, texel_dirs), texel_dirs, np.tile(cubemap.texel_solid_angles(n).ravel(), 6))
        open_sky = np.maximum(sh.diffuse_basis(nrm) @ coeffs, 0.0)
    return open_sky * np.where(facing > 0, seen / np.maximum(facing, 1e-300), 0.0)


class _SkyTests:
    """:func:`sky_direct_steps`' shadow tests of the points ``which`` along ``dirs``: by a
    ray each way where the receivers' lines of sight asked at once are at most
    ``rays_at_most`` and the renderer has a ray caster, else by an orthographic depth map
    of edge ``size`` per direction, drawn with the sun's machinery."""

    def __init__(self, scene, renderer, which, dirs, size, rays_at_most, step):
        self.scene, self.renderer, self.which, self.dirs, self.size = scene, renderer, which, dirs, size
        self.rays_at_most, self.step = rays_at_most, step
        lo, hi = scene.bounds()
        self.centre, self.radius = 0.5 * (lo + hi), 0.5 * scene.scale * SUN_BOX_MARGIN
        self.occluders = scene_occluders(scene)

    def run(self, ks, rows):
        """``[(k, receivers (indices into which), their visibility)]`` for the directions
        ``ks`` and the receivers ``rows`` (a generator, handing control back)."""
        if not len(rows) or not len(ks):
            return []
        at, dirs = self.which[rows], self.dirs[ks]
        receivers = lights_mod.Receivers(self.scene.points[at], self.scene.normals[at], at)
        nrm = receivers.normals
        rays = int(np.count_nonzero(nrm @ dirs.T > 0))
        if getattr(self.renderer, "rays", None) is not None and rays <= self.rays_at_most:  # a ray each way, not a map
            working = direct_step(self.step, f"direct light: the sky, {rays:,} rays")
            yield working  # a step of its own, however fast the rays
            done = yield from in_background(_sky_rays, working, receivers, self.occluders, scene_caster(self.scene, self.renderer),
                                            dirs, 2.0 * self.radius / self.size)
        else:
            done = yield from self._by_maps(receivers, dirs)
        return [(int(ks[j]), rows[on], vis) for j, on, vis in done]

    def _by_maps(self, receivers, dirs):
        eyes = self.centre + dirs * self.radius * SUN_EYE_DISTANCE
        vps = np.stack([cubemap.orthographic(self.radius, SUN_NEAR * self.radius, SUN_FAR * self.radius)
                        @ cubemap.look_matrix(e, -d, cubemap.any_perpendicular(d)) for e, d in zip(eyes, dirs)])

        def tests(first, tid, dist, back):
            """The shadow tests of a batch of maps: ``[(k, receivers, their visibility)]``."""
            out = []
            for j in range(len(tid)):
                k = first + j
                on = np.flatnonzero(receivers.normals @ dirs[k] > 0)
                if len(on):
                    view = lights_mod.OrthoView(vps[k], -dirs[k], eyes[k], self.radius)
                    depth = lights_mod.DepthMap(tid[j:j + 1], dist[j:j + 1], back[j:j + 1])
                    out.append((k, on, lights_mod.ortho_visibility(receivers[on], self.occluders, view, depth)))
            return out

        # Each batch's maps are drawn (the GPU's work, on this thread) while the batches before
        # are tested in threads, up to WORKERS at once; the results are taken in order.
        jobs, done, step = deque(), [], self.step
        for first in range(0, len(dirs), SKY_MAPS_AT_ONCE):  # (a few hundred MB of maps at once, not more)
            batch = slice(first, first + SKY_MAPS_AT_ONCE)
            tid, _, dist, back = self.renderer.render(vps[batch], eyes[batch], -dirs[batch], self.size, with_bary=False)
            while len(jobs) >= WORKERS:
                done += yield from wait(jobs.popleft(), direct_step(step, f"direct light: the sky, {first} of {len(dirs)} directions"))
            jobs.append(start(tests, first, tid, dist, back))
            yield direct_step(step, f"direct light: the sky, {first + len(tid)} of {len(dirs)} directions drawn")
        while jobs:
            done += yield from wait(jobs.popleft(), direct_step(step, f"direct light: the sky, {len(dirs)} of {len(dirs)} directions"))
        return done


def _sky_rays(receivers, occluders, caster, dirs, footprint):
    """The sky's shadow tests by rays: ``[(k, receivers, their visibility)]`` for each
    direction ``dirs[k]``, one ray from each receiver facing it (started off its surface as
    a map's doubtful receiver's ray is: ``footprint``, the map's texel)."""
    facing = receivers.normals @ dirs.T > 0  # (r, k)
    row, k = np.nonzero(facing)
    origins = ray_starts(receivers[row], occluders, np.full(len(row), footprint), np.arange(len(row)))
    open_ = ~caster.blocked(origins, dirs[k], None)
    order = np.argsort(k, kind="stable")  # each direction's rays together (not one mask per direction)
    bounds = np.searchsorted(k[order], np.arange(len(dirs) + 1))
    return [(j, row[order[a:b]], open_[order[a:b]].astype(np.float64))
            for j, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])) if b > a]
