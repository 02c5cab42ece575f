"""Where a shadow ray leaves its receiver (pure numpy, no bpy): off its surface and into its
own triangles, so that a surface meeting it there (a wall standing where a floor ends, walls
meeting at a corner) shadows the rays that go into that surface and no others."""

import numpy as np
import pytest

from cubegi.cubegi_engine import geometry
from cubegi.cubegi_engine.lifts import ray_starts
from cubegi.cubegi_engine.lights import Occluders, Receivers
from cubegi.cubegi_engine.rays import NumpyRays


def _patch(origin, u, v, n):
    """A flat ``n`` x ``n`` grid of quads: ``(points, triangles)``."""
    s = np.linspace(0.0, 1.0, n + 1)
    points = (np.asarray(origin, float) + s[:, None, None] * np.asarray(u, float) + s[None, :, None] * np.asarray(v, float)).reshape(-1, 3)
    k = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    quads = np.stack([k, k + n + 1, k + n + 2, k + 1], axis=-1).reshape(-1, 4)
    return points, np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])


def test_inward_points_away_from_a_surface_s_edges_and_is_about_nothing_inside_it():
    points, triangles = _patch((0, 0, 0), (1, 0, 0), (0, 1, 0), 4)
    into = geometry.inward(triangles, points)
    inside = np.all((points[:, :2] > 0.1) & (points[:, :2] < 0.9), axis=1)
    assert np.abs(into[inside]).max() < 0.2
    edge = np.isclose(points[:, 0], 0.0) & (points[:, 1] > 0.1) & (points[:, 1] < 0.9)
    assert np.all(into[edge, 0] > 0.5) and np.all(into[edge, 0] > 2.0 * np.abs(into[edge, 1:]).max(axis=1))
    corner = np.all(np.isclose(points, [1.0, 1.0, 0.0]), axis=1)
    assert np.all(into[corner, :2] < -0.5)


def _floor_and_wall():
    """A 1 m floor (z = 0, facing up) ending at a one-sided wall (x = 0, facing +x) that
    stands on its edge: ``(occluders, receivers)`` with the floor's vertex at the wall's foot
    and the wall's vertex on the floor."""
    floor, ft = _patch((0, 0, 0), (1, 0, 0), (0, 1, 0), 2)
    wall, wt = _patch((0, 0, 0), (0, 1, 0), (0, 0, 1), 2)
    points = np.concatenate([floor, wall])
    triangles = np.concatenate([ft, wt + len(floor)])
    caster = NumpyRays(points, triangles)
    occluders = Occluders(triangles, points, 1.0, None, lambda: caster)
    at_foot = np.flatnonzero(np.all(np.isclose(floor, [0.0, 0.5, 0.0]), axis=1))[0]
    on_floor = len(floor) + np.flatnonzero(np.all(np.isclose(wall, [0.0, 0.5, 0.0]), axis=1))[0]
    receivers = Receivers(points[[at_foot, on_floor]], np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),
                          np.array([at_foot, on_floor]))
    return occluders, receivers


@pytest.mark.parametrize("receiver, towards, blocked", [
    (0, (-1.0, 0.0, 1.0), True),   # the floor's vertex, over the wall: the wall stands in the way
    (0, (1.0, 0.0, 1.0), False),   # away from the wall
    (1, (1.0, 0.0, -1.0), True),   # the wall's foot, down: the floor
    (1, (1.0, 0.0, 1.0), False),   # up and out
])
def test_a_ray_from_where_two_surfaces_meet_is_stopped_by_the_other_one_only_when_it_goes_into_it(receiver, towards, blocked):
    occluders, receivers = _floor_and_wall()
    start = ray_starts(receivers, occluders, np.full(2, 0.01), np.array([receiver]))
    towards = np.array([towards]) / np.linalg.norm(towards)
    assert occluders.rays().blocked(start, towards, None)[0] == blocked


def test_every_light_s_occluders_of_one_scene_share_its_inward_vectors():
    """Where rays start is made once per scene, not once per light's occluders."""
    from cubegi.cubegi_engine import gather
    from cubegi.cubegi_engine.scene import SceneArrays

    points, triangles = _patch((0, 0, 0), (1, 0, 0), (0, 1, 0), 2)
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    scene = SceneArrays(points, normals, np.full_like(points, 0.5), np.zeros_like(points), triangles)
    first, second = gather.scene_occluders(scene), gather.scene_occluders(scene)
    assert first is not second and first.inward() is second.inward()
    np.testing.assert_allclose(first.inward(), geometry.inward(triangles, points))


def test_a_triangle_with_no_extent_pulls_no_corner_anywhere():
    """Three corners in one place (a collapsed triangle, left by a modifier or a weld) add no
    direction of rounding to where a ray starts."""
    points, triangles = _patch((0, 0, 0), (1, 0, 0), (0, 1, 0), 2)
    alone = geometry.inward(triangles, points)
    points = np.concatenate([points, np.repeat([[0.5, 0.5, 0.0]], 3, axis=0) + [[0.0, 0.0, 0.0], [1e-12, 0.0, 0.0], [0.0, 1e-12, 0.0]]])
    collapsed = np.concatenate([triangles, [[len(points) - 3, len(points) - 2, len(points) - 1]]])
    into = geometry.inward(collapsed, points)
    np.testing.assert_allclose(into[: len(alone)], alone)
    assert np.all(into[len(alone):] == 0.0)


def test_the_sky_asks_a_receivers_other_directions_only_where_its_first_ones_disagree(monkeypatch):
    """Inside a closed box every first ray meets it, in the open every one leaves: those
    receivers take that answer for their other directions, with a quarter of the rays; one
    beside the box sees it along some first rays and not others, and asks every direction.
    Each gets the light it gets when every direction is asked at once."""
    from cubegi.cubegi_engine import sky
    from cubegi.cubegi_engine.scene import SceneArrays

    faces = [((0, 0, 0), (0, 1, 0), (1, 0, 0)), ((0, 0, 1), (1, 0, 0), (0, 1, 0)), ((0, 0, 0), (1, 0, 0), (0, 0, 1)),
             ((0, 1, 0), (0, 0, 1), (1, 0, 0)), ((0, 0, 0), (0, 0, 1), (0, 1, 0)), ((1, 0, 0), (0, 1, 0), (0, 0, 1))]
    parts = [_patch(o, u, v, 2) for o, u, v in faces]
    box = np.concatenate([p for p, _ in parts])
    points = np.concatenate([box, [[0.5, 0.5, 0.05], [9.0, 9.0, 0.0], [1.02, 0.5, 0.0]]])
    triangles = np.concatenate([t + 9 * k for k, (_, t) in enumerate(parts)])
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    scene = SceneArrays(points, normals, np.full_like(points, 0.5), np.zeros_like(points), triangles)
    which = np.arange(len(box), len(points))
    asked = []

    class Counted(NumpyRays):
        def blocked(self, origins, dirs, reach=None):
            asked.append(len(origins))
            return super().blocked(origins, dirs, reach)

    class Renderer:  # rays alone: a map drawn would fail the test
        rays = Counted

    light, first_every = {}, sky.SKY_FIRST_EVERY
    for every in (first_every, 1):
        monkeypatch.setattr(sky, "SKY_FIRST_EVERY", every)
        asked.clear()
        light[every] = sky.sky_direct(scene, Renderer(), which, rays_at_most=10**9)[:, 0]
        light[every, "rays"] = sum(asked)
    assert light[1][0] == 0.0 and light[1][1] == 1.0 and 0.2 < light[1][2] < 0.9  # shut in, open, beside the box
    np.testing.assert_array_equal(light[first_every], light[1])
    facing = int(np.count_nonzero(sky.sh.fibonacci_sphere(sky.SKY_DIRECTIONS)[:, 2] > 0))
    assert light[1, "rays"] == 3 * facing
    assert light[first_every, "rays"] < 2 * facing  # the box's first rays and all of the third's
