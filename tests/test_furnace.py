"""Furnace: a closed box of uniform albedo rho lit by uniform emission on every surface.

Every point receives the emitted radiance L from all around, so the direct diffuse light is
L and bounce n carries rho^n L, at every vertex."""

import bpy
import numpy as np
import pytest

import scenes


@pytest.mark.parametrize("rho", [0.5, 0.9])
def test_bounce_n_carries_rho_to_the_n(empty_scene, cubegi, rho):
    attributes = cubegi.cubegi_addon.attributes
    box = scenes.closed_box(size=2.0, cells=6, albedo=rho, emission=(1.0, 1.0, 1.0), strength=1.0)
    scenes.set_world((0.0, 0.0, 0.0))
    assert bpy.ops.cubegi.bake(bounces=5, grid=(2, 2, 2)) == {"FINISHED"}
    mesh = box.data
    direct = attributes.read(mesh, "CubeGI_direct")
    # Uniform radiance is captured exactly by SH band 0: the direct light is L = 1.
    # Measured: every vertex within 1e-5; 1e-4 allows float32 rounding of sums over 6n^2
    # texels per probe, and would still catch a per-bounce energy error of 0.01%.
    FLOAT32_TOL = 1e-4
    np.testing.assert_allclose(direct, 1.0, rtol=FLOAT32_TOL)
    for n in range(1, 6):
        b = attributes.read(mesh, f"CubeGI_bounce_{n}")
        np.testing.assert_allclose(b, rho**n, rtol=FLOAT32_TOL * n)
    total = attributes.read(mesh, "CubeGI")
    np.testing.assert_allclose(total, sum(rho**n for n in range(1, 6)), rtol=5 * FLOAT32_TOL)
