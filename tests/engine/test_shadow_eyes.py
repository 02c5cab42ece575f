"""How many points each soft light's shadows are drawn from (pure numpy, no bpy): by what its
size subtends from what it lights, and a scene's soft lights sharing one budget."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from cubegi.cubegi_engine.eyes import SHADOW_EYES, fewer_samples, shadow_eyes, soft_count
from cubegi.cubegi_engine.lights import Light, area_polygon, area_samples


def _panel(centre, size_x, size_y, side=8):
    """A rectangular area light facing down at ``centre``, its samples a side x side grid."""
    centre = np.asarray(centre, dtype=np.float64)
    flip = np.diag([1.0, -1.0, -1.0])  # local -Z (the light's direction) to world -Z
    polygon = area_polygon("RECTANGLE", size_x, size_y) @ flip.T + centre
    samples = area_samples("RECTANGLE", size_x, size_y, side) @ flip.T + centre
    return Light("AREA", colour=np.ones(3) * 100.0, position=centre, direction=np.array([0.0, 0.0, -1.0]), polygon=polygon,
                 area=size_x * size_y, samples=samples)


# A 20 x 8 m floor of points (the hall's), no triangles needed but their count.
FLOOR = SimpleNamespace(points=np.stack(np.meshgrid(np.linspace(-10, 10, 41), np.linspace(-4, 4, 17), [0.0]), -1).reshape(-1, 3),
                        triangles=np.zeros((50_000, 3), dtype=np.int64))


def test_fewer_samples_are_the_coarser_grids_stratified_points():
    fine = area_samples("RECTANGLE", 1.2, 0.5, 8)
    for count, side in ((64, 8), (16, 4), (15, 2), (9, 2), (4, 2), (3, 1), (1, 1)):
        fewer = fewer_samples(fine, count)
        assert len(fewer) == side * side, count
        np.testing.assert_allclose(np.sort(fewer, axis=0), np.sort(area_samples("RECTANGLE", 1.2, 0.5, side), axis=0), atol=1e-12)
    odd = np.random.default_rng(0).normal(size=(10, 3))  # not a square grid: kept
    assert fewer_samples(odd, 4) is odd


def test_fewer_samples_of_a_disk_keep_their_spread_over_it():
    """A disk's samples lie in rings and angles: its fewer eyes are spread as its own (a
    block's mean would draw them to the middle: 4 eyes at 0.42 of the radius, against 0.67
    for the whole disk), and one eye is its centre."""
    fine = area_samples("DISK", 1.0, 1.0, 8)
    spread = np.linalg.norm(fine, axis=1).mean()
    for count in (4, 16):
        fewer = fewer_samples(fine, count)
        assert len(fewer) == count and abs(np.linalg.norm(fewer, axis=1).mean() - spread) < 0.2 * spread, count
        assert np.all(np.linalg.norm(fewer, axis=1) <= 0.5)  # on the disk
    np.testing.assert_allclose(fewer_samples(fine, 1)[0], fine.mean(axis=0), atol=1e-12)


def test_a_light_gets_the_eyes_its_size_needs_from_what_it_lights():
    large = _panel((0.0, 0.0, 4.9), 1.2, 0.5)  # 1.3 m seen from 2.5 m: all 64
    small = _panel((0.0, 0.0, 4.9), 0.1, 0.1)  # 14 cm from 5 m: one
    middle = _panel((0.0, 0.0, 4.9), 0.4, 0.4)  # 57 cm from 5 m: a 4 x 4 grid
    sun = Light("SUN", colour=np.ones(3), position=np.zeros(3), direction=np.array([0.0, 0.0, -1.0]))
    eyes = shadow_eyes(FLOOR, [large, small, middle, sun], [2.5, 5.0, 5.0, 1.0])
    assert eyes == [64, 1, 16, None]


def test_many_soft_lights_share_one_budget_equally_and_none_gets_more_than_it_needs():
    lamps = [_panel((x, y, 4.9), 1.2, 0.5) for x in np.linspace(-8, 8, 6) for y in (-1.6, 1.6)] + [_panel((0.3, 3.1, 4.9), 1.2, 0.5)]
    eyes = shadow_eyes(FLOOR, lamps, [3.0] * len(lamps))
    assert sum(eyes) <= SHADOW_EYES < 64 * len(lamps)
    assert len(set(eyes)) == 1 and eyes[0] >= 4, eyes  # equal lamps, equal shares
    # Within the budget every light gets what it needs.
    assert shadow_eyes(FLOOR, lamps[:1] + [_panel((0.0, 0.0, 4.9), 0.1, 0.1)], [3.0, 5.0]) == [64, 1]
    # Power does not change the shares (an update after a power edit keeps every light's maps).
    brighter = [replace(lamp, colour=lamp.colour * (10.0 if k == 0 else 1.0)) for k, lamp in enumerate(lamps)]
    assert shadow_eyes(FLOOR, brighter, [3.0] * len(lamps)) == eyes


def test_soft_point_lights_share_the_budget_and_sharp_ones_keep_their_one_eye():
    bulbs = [Light("POINT", colour=np.ones(3), position=np.array([x, 0.0, 3.0]), direction=np.array([0.0, 0.0, -1.0]), radius=0.3)
             for x in np.linspace(-8, 8, 13)]
    sharp = Light("POINT", colour=np.ones(3), position=np.array([0.0, 0.0, 3.0]), direction=np.array([0.0, 0.0, -1.0]), radius=0.001)
    own = soft_count(FLOOR)
    assert shadow_eyes(FLOOR, bulbs[:1] + [sharp], [3.0, 3.0]) == [own, None]
    eyes = shadow_eyes(FLOOR, bulbs, [3.0] * len(bulbs))
    assert sum(eyes) <= SHADOW_EYES and all(1 <= n < own for n in eyes), eyes
