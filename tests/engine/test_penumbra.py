"""A sun's soft shadows (pure numpy, no bpy): the rays across its disk, and the share of it a
straight edge leaves a point (the real scenes' soft shadows against Cycles: the conformance
suite's 10-degree sun)."""

import numpy as np
import pytest

from cubegi.cubegi_engine import penumbra
from cubegi.cubegi_engine.lights import Occluders, Receivers
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
