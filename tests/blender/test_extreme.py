"""Extreme scale and power: the same scene at 1 mm and 10 km, lights from 1 uW to 1 GW."""

import json

import bpy
import numpy as np
import pytest
import scenes


def _bake_cornell(scale=1.0, power=1.0):
    """The Cornell box scaled by ``scale``, lit by a point and an area light whose powers are
    scaled by ``power x scale^2`` (the same irradiance at every scale)."""
    scenes.cornell(light=False)
    m = np.diag([scale, scale, scale, 1.0]).tolist()
    meshes = sorted((ob for ob in bpy.context.scene.objects if ob.type == "MESH"), key=lambda ob: ob.name)
    for ob in meshes:
        ob.data.transform(m)
    k = power * scale * scale
    scenes.add_light("POINT", (0.13 * scale, -0.27 * scale, 1.63 * scale), 60.0 * k, shadow_soft_size=0.01 * scale)
    scenes.add_light("AREA", (0.07 * scale, 0.11 * scale, 1.98 * scale), 80.0 * k, shape="SQUARE", size=0.6 * scale)
    assert bpy.ops.cubegi.bake(bounces=3, grid=(3, 3, 3), cube_size=16) == {"FINISHED"}
    read = __import__("cubegi").cubegi_addon.attributes.read
    return {n: np.concatenate([read(ob.data, n) for ob in meshes]) for n in ("CubeGI_direct", "CubeGI")}


@pytest.mark.parametrize("scale", [1e-3, 1e3, 1e4])
def test_scene_scale_does_not_change_the_light(empty_scene, cubegi, scale):
    """The GPU draws in a unit frame, clip planes follow the scene's and the eye's
    surroundings' size, and every decision's margin is relative (to a texel's footprint, a
    receiver's distance, the scene's size): the same scene at 1 mm, 1 m, 1 km and 10 km
    gives the same light to the float32 rounding of its scaled mesh. The one decision that
    may flip is one of the area light's 64 shadow samples where a receiver's lookup falls
    exactly on an occluder's edge in that sample's (turned) map: float32 rounding then
    decides. Measured: in the direct light one to three of the box's 797 vertices differ by
    0.3-2.1% of the mean (one sample's share), every other vertex of either layer by 0.1%
    at most; the mean difference is 2-6e-5 of the mean (5.4e-5 at 1 mm, where the box's
    sheets have twins: float32 rounding on twice the points)."""
    base = _bake_cornell(1.0)
    got = _bake_cornell(scale)
    for name in base:
        rel = np.abs(got[name] - base[name]).max(axis=1) / base[name].mean()
        assert np.isfinite(got[name]).all()
        flips = rel > 1e-3
        assert flips.sum() <= 5, (name, np.sort(rel)[-8:])  # a handful of single-sample flips at most
        assert rel.max() < 0.05, (name, np.sort(rel)[-5:])  # each no more than about one sample's share
        assert rel[~flips].max() < 1e-3 and rel.mean() < 1e-4, (name, rel.mean())



def test_light_is_linear_in_power_from_microwatts_to_gigawatts(empty_scene, cubegi):
    base = _bake_cornell(power=1.0)
    for power in (1e-6 / 60.0, 1e9 / 60.0):  # the point light at 1 uW and at 1 GW
        got = _bake_cornell(power=power)
        for name in base:
            assert np.isfinite(got[name]).all() and (got[name] >= 0).all()
            # float32 throughout the bounces: relative rounding of 1e-6 per operation.
            np.testing.assert_allclose(got[name] / power, base[name], rtol=1e-4, atol=1e-6 * base[name].max())


def _room_on_ground(ground=None, size=1.0, cup=False):
    """A closed 4 x 4 x 2.5 room (times ``size``) lit inside, on a ground plane of edge
    ``2 * ground`` (none: the room alone) a hundredth of the room's size below its floor;
    with ``cup``, a detailed box on its floor holding most of the scene's points."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    v, f = scenes.box_mesh((-2 * size, -2 * size, 0), (2 * size, 2 * size, 2.5 * size), (8, 8, 5), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    if cup:
        v, f = scenes.box_mesh((0.8 * size, 0.8 * size, 0), (1.0 * size, 1.0 * size, 0.2 * size), (20, 20, 20), inward=False)
        scenes.mesh_object("Cup", v, f, scenes.material("Clay", (0.6, 0.5, 0.4)))
    scenes.add_light("POINT", (0.3 * size, 0.2 * size, 1.5 * size), 100.0 * size * size)
    if ground:
        v, f = scenes.grid_patch((-ground, -ground, -0.01 * size), (2 * ground, 0, 0), (0, 2 * ground, 0), 4, 4)
        scenes.mesh_object("Ground", v, f, scenes.material("Grey", (0.5, 0.5, 0.5)))
    assert bpy.ops.cubegi.bake(bounces=3) == {"FINISHED"}
    read = __import__("cubegi").cubegi_addon.attributes.read
    return {n: read(bpy.data.objects["Room"].data, n) for n in ("CubeGI_direct", "CubeGI")}


def test_a_furnished_room_on_a_huge_ground_gets_its_own_grid(empty_scene, cubegi):
    """The room on a 2 km ground with a detailed box on its floor holding most of the points:
    the middle of the points is the box's, yet the finer grid covers the room round it (it
    covered the room's furniture alone, grown by a 250 m coarse cell: the room's indirect
    light was a tenth of what it is alone). Measured: the room's mean light within 1% of
    the room's alone (the room alone puts its finer grid round the box)."""
    alone = _room_on_ground(None, cup=True)
    together = _room_on_ground(1000.0, cup=True)
    grids = json.loads(bpy.context.scene.cubegi.last_report)["grid"]["grids"]
    assert len(grids) == 2 and np.allclose(grids[1]["lo"], [-2, -2, 0], atol=0.05) and np.allclose(grids[1]["hi"], [2, 2, 2.5], atol=0.05), grids
    for name in alone:
        assert together[name].mean() == pytest.approx(alone[name].mean(), rel=0.03), name


@pytest.mark.parametrize("ground,size", [(10.0, 1.0), (1000.0, 1.0), (5e4, 0.01)])
def test_a_small_closed_room_on_a_huge_ground_keeps_its_light(empty_scene, cubegi, ground, size):
    """A lit room on a 20 m or 2 km ground, a 4 cm one on a 100 km ground: the fitted grid
    puts a finer grid over the room (where most geometry is), clip planes follow each eye's
    surroundings, shadow margins each receiver's distance: the room's light is what it is
    alone (it was 41%, 9% and 0% of it). Measured: within 0.1%."""
    alone = _room_on_ground(None, size)
    together = _room_on_ground(ground, size)
    grid = json.loads(bpy.context.scene.cubegi.last_report)["grid"]
    assert len(grid["grids"]) == 2  # the coarse one over everything, the fine one over the room
    for name in alone:
        assert together[name].mean() == pytest.approx(alone[name].mean(), rel=5e-3), name
