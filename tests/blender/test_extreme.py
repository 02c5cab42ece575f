"""Extreme scale and power: the same scene at 1 mm and 10 km, lights from 1 uW to 1 GW."""

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


@pytest.mark.parametrize("scale", [1e-3, 1e4])
def test_scene_scale_does_not_change_the_light(empty_scene, cubegi, scale):
    """The GPU draws in a unit frame and every bias and clip plane follows the scene's
    size, so only float32 rounding of the scaled mesh differs. A vertex exactly on a hard
    shadow edge may still flip (measured: 0 to 2 of 797 vertices); everything else agrees
    to 0.1% (measured: 3e-4 at most), and the area mean to 1e-4."""
    base = _bake_cornell(1.0)
    got = _bake_cornell(scale)
    for name in base:
        rel = np.abs(got[name] - base[name]).max(axis=1) / base[name].mean()
        assert np.isfinite(got[name]).all()
        assert (rel > 1e-3).sum() <= 3, (name, np.sort(rel)[-5:])
        assert rel.mean() < 1e-4, (name, rel.mean())


def test_light_is_linear_in_power_from_microwatts_to_gigawatts(empty_scene, cubegi):
    base = _bake_cornell(power=1.0)
    for power in (1e-6 / 60.0, 1e9 / 60.0):  # the point light at 1 uW and at 1 GW
        got = _bake_cornell(power=power)
        for name in base:
            assert np.isfinite(got[name]).all() and (got[name] >= 0).all()
            # float32 throughout the bounces: relative rounding of 1e-6 per operation.
            np.testing.assert_allclose(got[name] / power, base[name], rtol=1e-4, atol=1e-6 * base[name].max())
