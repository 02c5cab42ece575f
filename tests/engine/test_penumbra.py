"""A sun's soft shadows (pure numpy, no bpy): the rays across its disk, and the share of it a
straight edge leaves a point (the real scenes' soft shadows against Cycles: the conformance
suite's 10-degree sun)."""

import numpy as np
import pytest

from cubegi.cubegi_engine import cubemap, lights, penumbra
from cubegi.cubegi_engine.lights import DepthMap, Occluders, OrthoView, Receivers
from cubegi.cubegi_engine.rays import NumpyRays


def test_disk_directions_fill_the_sun_s_cone_and_are_its_middle_without_an_angle():
    rng = np.random.default_rng(3)
    origins = rng.uniform(-5, 5, (200, 3))
    to_sun = np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9])
    angle = np.radians(10.0)
    dirs = penumbra.disk_directions(to_sun, angle, origins, 10.0, 16)
    assert dirs.shape == (200, 16, 3)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=2), 1.0)
    off = np.arccos(np.clip(dirs @ to_sun, -1.0, 1.0))
    assert off.max() <= 0.5 * angle + 1e-9
    # Spread over the disk: the mean direction is the middle, and rays reach its rim.
    np.testing.assert_allclose(dirs.mean(axis=(0, 1)) / np.linalg.norm(dirs.mean(axis=(0, 1))), to_sun, atol=1e-3)
    assert off.max() > 0.45 * angle
    np.testing.assert_allclose(penumbra.disk_directions(to_sun, 0.0, origins, 10.0, 4), np.broadcast_to(to_sun, (200, 4, 3)))


def _plate_edge():
    """A large opaque plate 1 m up over x < 0: its edge runs along y above x = 0."""
    points = np.array([[-50.0, -50.0, 1.0], [0.0, -50.0, 1.0], [0.0, 50.0, 1.0], [-50.0, 50.0, 1.0]])
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    caster = NumpyRays(points, triangles)
    return Occluders(triangles, points, 100.0, None, lambda: caster)


@pytest.mark.parametrize("x, share", [(0.0, 0.5), (-0.5, 0.0), (0.5, 1.0)])
def test_a_straight_edge_over_a_point_leaves_it_the_share_of_the_disk_past_the_edge(x, share):
    """A sun of 10 degrees straight overhead: its penumbra under the plate's edge is about
    17 cm wide. Under the edge, half the disk is seen; a point well inside the shadow sees
    none of it, one well outside all of it."""
    occluders = _plate_edge()
    receivers = Receivers(np.array([[x, 0.0, 0.0], [x, 0.3, 0.0], [x, -0.7, 0.0]]), np.tile([0.0, 0.0, 1.0], (3, 1)),
                          np.full(3, -1))
    got, centre_open = penumbra._disk_share(receivers, occluders, np.array([0.0, 0.0, -1.0]), np.tan(np.radians(5.0)),
                                            np.full(3, 1e-3), np.arange(3))
    assert np.abs(got - share).max() <= 0.13, got  # 16 rays: steps of 1/16, and the pattern's turn
    if x:  # (under the edge itself the middle ray grazes it)
        assert centre_open.tolist() == [x > 0.0] * 3


def _two_ledges():
    """A ground at z = 0 under two ledges running along y: a low one 0.5 m up over x < -1,
    a high one 3 m up over x > 1.5 (see _sun_map)."""
    big = 50.0
    return _sun_map([[(-big, -big, 0.0), (big, -big, 0.0), (big, big, 0.0), (-big, big, 0.0)],
                     [(-big, -big, 0.5), (-1.0, -big, 0.5), (-1.0, big, 0.5), (-big, big, 0.5)],
                     [(1.5, -big, 3.0), (big, -big, 3.0), (big, big, 3.0), (1.5, big, 3.0)]])


def _sun_map(quads):
    """``(occluders, view, depth map)`` of ``quads`` (each 4 corners) under a sun straight
    overhead, its depth map 256 texels over 8 m (texels of 3.1 cm), traced by rays as the
    GPU would draw it."""
    points = np.array([c for quad in quads for c in quad], dtype=np.float64)
    triangles = np.array([(k, k + 1, k + 2) for k in range(0, len(points), 4)] + [(k, k + 2, k + 3) for k in range(0, len(points), 4)])
    caster = NumpyRays(points, triangles)
    occluders = Occluders(triangles, points, 100.0, None, lambda: caster)
    axis, eye, half, n = np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 10.0]), 4.0, 256
    vp = cubemap.orthographic(half, 0.1, 20.0) @ cubemap.look_matrix(eye, axis, cubemap.any_perpendicular(axis))
    ndc = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    x, y = np.meshgrid(ndc, ndc)  # (row: ndc y, col: ndc x)
    corner = np.stack([x.ravel(), y.ravel(), -np.ones(n * n), np.ones(n * n)], axis=1) @ np.linalg.inv(vp).T
    starts = corner[:, :3] / corner[:, 3:]
    found = caster.cast(starts, np.broadcast_to(axis, starts.shape))
    dist = ((starts + found.t[:, None] * axis - eye) @ axis).reshape(1, n, n).astype(np.float32)
    depth = DepthMap(found.triangle.reshape(1, n, n), dist, ~found.front.reshape(1, n, n))
    return occluders, OrthoView(vp, axis, eye, half), depth


def test_a_receiver_asks_rays_only_within_the_penumbra_its_own_occluders_can_cast():
    """The high ledge blurs its shadow's edge over 3 m x tan(1 degree) = 5 cm each way, the
    low one over 9 mm. Every receiver whose disk is partly covered is asked (rays decide it,
    within 16 rays' steps), and the ground more than two texels from the low ledge's edge is
    not: the widest window (6 texels, for occluders up to the map's depth) asked it."""
    occluders, view, depth = _two_ledges()
    x = np.linspace(-1.5, 2.2, 600)
    receivers = Receivers(np.stack([x, np.full_like(x, 0.013), np.zeros_like(x)], axis=1), np.tile([0.0, 0.0, 1.0], (len(x), 1)),
                          np.full(len(x), -1))
    angle = np.radians(2.0)
    lookup, _ = lights.ortho_lookup(receivers, view, depth.size, occluders)
    asked = penumbra._near_an_edge(depth, lookup, np.tan(0.5 * angle), depth.size)
    truth, _ = penumbra._disk_share(receivers, occluders, view.axis, np.tan(0.5 * angle), np.full(len(x), 1e-3), np.arange(len(x)))
    partial = (truth > 0.0) & (truth < 1.0)
    assert partial.sum() > 10 and not (partial & ~asked).any(), x[partial & ~asked]
    beyond_low = (np.abs(x + 1.0) > 0.07) & (np.abs(x + 1.0) < 0.18)
    assert beyond_low.sum() > 10 and not asked[beyond_low].any(), x[beyond_low & asked]
    assert asked[np.abs(x - 1.5) < 0.05].all()
    got = penumbra.sun_visibility(receivers, occluders, view, depth, angle)
    assert np.abs(got - truth).max() <= 0.13 and np.abs(got[x < -1.02]).max() == 0.0 and np.all(got[(x > -0.9) & (x < 1.4)] == 1.0)


class _Counting:
    """A ray caster that counts the rays asked of it."""

    def __init__(self, caster):
        self.caster, self.rays = caster, 0

    def blocked(self, origins, dirs, reach=None):
        self.rays += len(origins)
        return self.caster.blocked(origins, dirs, reach)


def test_receivers_sharing_a_texel_ask_the_first_rays_from_their_outermost_alone():
    """About a hundred receivers to a texel (a finely subdivided ground) under the two ledges: the
    groups whose outermost receivers see all or none of the sun's disk lend their answer to
    the rest, so far fewer rays are cast than a ray set each, and every receiver's share is
    the one its own rays give (within 16 rays' steps); those a penumbra crosses ask their own."""
    occluders, view, depth = _two_ledges()
    counting = _Counting(occluders.rays())
    occluders = Occluders(occluders.triangles, occluders.vertices, occluders.scale, None, lambda: counting)
    x, y = np.meshgrid(np.arange(-1.3, -0.7, 0.0025), np.linspace(0.001, 0.029, 8))  # about the low ledge's edge
    points = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    receivers = Receivers(points, np.tile([0.0, 0.0, 1.0], (len(points), 1)), np.full(len(points), -1))
    spread = np.tan(np.radians(1.0))
    lookup, _ = lights.ortho_lookup(receivers, view, depth.size, occluders)
    ask = np.flatnonzero(penumbra._near_an_edge(depth, lookup, spread, depth.size))
    sharp = lights.ortho_visibility(receivers, occluders, view, depth)[ask]
    counting.rays = 0
    got, _ = penumbra._shared_disk_share(receivers, occluders, view.axis, spread, lookup, ask, depth.size, sharp)
    shared, counting.rays = counting.rays, 0
    truth, _ = penumbra._disk_share(receivers, occluders, view.axis, spread, lookup.footprint, ask)
    assert shared < 0.65 * counting.rays, (shared, counting.rays)  # (two of its four texels hold the penumbra)
    assert np.abs(got - truth).max() <= 0.13
    partial = (truth > 0.0) & (truth < 1.0)
    assert partial.sum() >= 16 and np.all((got[partial] > 0.0) & (got[partial] < 1.0))


@pytest.mark.parametrize("turn, offset", [(17.8, (-0.0007, -0.00904)), (28.5, (-0.00692, -0.00585))])
def test_a_shadows_corner_inside_a_texel_leaves_every_receiver_its_own_share(turn, offset):
    """A square plate 20 cm over the ground, turned about the vertical, its corner 9 mm from
    the middle of a texel that 400 receivers share: its sharp shadow cuts a notch into the
    texel's lit receivers, and those about the notch stand in a penumbra that the group's
    outermost members do not see. None there takes the group's answer: each share is within
    16 rays' steps of the receiver's own."""
    texel, big = 8.0 / 256, 50.0
    middle = (np.array([37, 41]) + 0.5) * texel - 4.0
    phi = np.radians(turn)
    spin = np.array([[np.cos(phi), -np.sin(phi)], [np.sin(phi), np.cos(phi)]])
    plate = np.array([[-big, -big], [0.0, -big], [0.0, 0.0], [-big, 0.0]]) @ spin.T + middle + offset
    occluders, view, depth = _sun_map([[(-big, -big, 0.0), (big, -big, 0.0), (big, big, 0.0), (-big, big, 0.0)],
                                       [(px, py, 0.2) for px, py in plate]])
    spread = np.tan(np.radians(1.0))
    worst = 0.0
    for seed in range(4):
        rng = np.random.default_rng(seed)
        r, t = np.sqrt(rng.random(400)) * 0.45 * texel, rng.random(400) * 2.0 * np.pi
        points = np.stack([middle[0] + r * np.cos(t), middle[1] + r * np.sin(t), np.zeros(400)], axis=1)
        receivers = Receivers(points, np.tile([0.0, 0.0, 1.0], (400, 1)), np.full(400, -1))
        lookup, _ = lights.ortho_lookup(receivers, view, depth.size, occluders)
        ask = np.flatnonzero(penumbra._near_an_edge(depth, lookup, spread, depth.size))
        sharp = lights.ortho_visibility(receivers, occluders, view, depth)[ask]
        got, _ = penumbra._shared_disk_share(receivers, occluders, view.axis, spread, lookup, ask, depth.size, sharp)
        own, _ = penumbra._disk_share(receivers, occluders, view.axis, spread, lookup.footprint, ask)
        assert len(ask) > 100
        worst = max(worst, np.abs(got - own).max())
    assert worst <= 0.13, worst


def test_a_receiver_on_the_edge_of_an_opening_is_looked_up_from_its_own_side():
    """A slat's end lies on the line of an opening's edge above it (slats of a blind whose
    ends meet a window's reveal): the sun's ray from that end grazes the edge. The map looks
    each receiver up where its rays start, off its surface and into its own triangles: the
    slat's end sees the sun through the opening, as Cycles' samples around it do (the map's
    exact cut landed on the edge, inside the plate: shadowed, for sure). A floor under the
    plate stays in its shadow, and the one under the opening in the sun."""
    edge = 0.79  # (the texels' middles about it: the receiver's own texel sees the plate)
    slat = [(-0.5, -0.8, 0.0), (0.5, -0.8, 0.0), (0.5, edge, 0.0), (-0.5, edge, 0.0)]  # faces up
    plate = [(-2.0, edge, 1.0), (2.0, edge, 1.0), (2.0, 2.0, 1.0), (-2.0, 2.0, 1.0)]  # over y >= edge only
    floor = [(-4.5, -4.5, -0.5), (4.5, -4.5, -0.5), (4.5, 4.5, -0.5), (-4.5, 4.5, -0.5)]  # (under the whole map)
    occluders, view, depth = _sun_map([slat, plate, floor])
    ends = [2, 3]  # the slat's corners on the edge's line
    points = np.concatenate([occluders.vertices[ends], [[0.0, 1.2, -0.5], [0.0, -1.2, -0.5]]])
    receivers = Receivers(points, np.tile([0.0, 0.0, 1.0], (4, 1)), np.array(ends + [-1, -1]))
    seen = lights.ortho_visibility(receivers, occluders, view, depth)
    assert list(seen) == [1.0, 1.0, 0.0, 1.0]
