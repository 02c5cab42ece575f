"""Furnace: a closed box of uniform albedo rho lit by uniform emission on every surface.

Every point receives the emitted radiance L from all around, so the direct diffuse light is
L, bounce n carries rho^n L at every vertex, and all bounces together rho / (1 - rho) L."""

import json

import bpy
import numpy as np
import pytest
import scenes

# Uniform radiance is captured exactly by SH band 0. Measured: every vertex within 1e-5;
# 1e-4 allows float32 rounding of sums over 6n^2 texels per probe, and would still catch a
# per-bounce energy error of 0.01%.
FLOAT32_TOL = 1e-4


def furnace(rho):
    """The box, Lambertian: its Principled BSDF's specular layer off (Specular IOR Level 0),
    which would otherwise send on a few per cent more than rho (cubegi_engine.specular)."""
    box = scenes.closed_box(size=2.0, cells=6, albedo=rho, emission=(1.0, 1.0, 1.0), strength=1.0)
    bsdf = next(n for n in box.active_material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Specular IOR Level"].default_value = 0.0
    scenes.set_world((0.0, 0.0, 0.0))
    return box.data


def last_report():
    return json.loads(bpy.context.scene.cubegi.last_report)


@pytest.mark.parametrize("rho", [0.5, 0.9])
def test_bounce_n_carries_rho_to_the_n(empty_scene, cubegi, rho):
    attributes = cubegi.cubegi_addon.attributes
    mesh = furnace(rho)
    assert bpy.ops.cubegi.bake(bounces=5, grid=(2, 2, 2), add_tail=False) == {"FINISHED"}
    np.testing.assert_allclose(attributes.read(mesh, "CubeGI_direct"), 1.0, rtol=FLOAT32_TOL)
    for n in range(1, 6):
        b = attributes.read(mesh, f"CubeGI_bounce_{n}")
        np.testing.assert_allclose(b, rho**n, rtol=FLOAT32_TOL * n)
    total = attributes.read(mesh, "CubeGI")
    np.testing.assert_allclose(total, sum(rho**n for n in range(1, 6)), rtol=5 * FLOAT32_TOL)
    rep = last_report()
    # Ratio of each bounce to the one before is rho, and the estimate of what is missing is
    # the geometric series' exact rest: rho^6 / (1 - rho) over rho / (1 - rho) = rho^5.
    for rec in rep["bounces"]:
        assert rec["ratio_mean"] == pytest.approx(rho, rel=1e-3)
    assert rep["estimated_remaining_error"] == pytest.approx(rho**5, rel=1e-3)
    assert rep["tail"]["added"] is False


@pytest.mark.parametrize("rho", [0.5, 0.9, 0.95, 0.99])
def test_tail_completes_the_series(empty_scene, cubegi, rho):
    """Three bounces and the tail give all bounces: rho / (1 - rho), to 0.1% even at 0.99."""
    mesh = furnace(rho)
    assert bpy.ops.cubegi.bake(bounces=3, grid=(2, 2, 2)) == {"FINISHED"}
    total = cubegi.cubegi_addon.attributes.read(mesh, "CubeGI")
    np.testing.assert_allclose(total, rho / (1 - rho), rtol=1e-3)
    rep = last_report()
    assert rep["tail"]["added"] is True
    # The tail's share is the part of the series after bounce 3: rho^3.
    assert rep["tail"]["share_of_indirect"] == pytest.approx(rho**3, rel=1e-3)
    # Little missing: the geometric rest; much missing: solved for.
    assert rep["tail"]["method"] == ("geometric" if rho**3 <= 0.01 else "solved")


def test_tolerance_stops_early(empty_scene, cubegi):
    """rho = 0.5: after n bounces the rest is 0.5^n of the whole; below 1% from n = 7."""
    mesh = furnace(0.5)
    assert bpy.ops.cubegi.bake(bounces=50, grid=(2, 2, 2), tolerance=0.01) == {"FINISHED"}
    rep = last_report()
    assert len(rep["bounces"]) == 7
    assert rep["estimated_remaining_error"] == pytest.approx(0.5**7, rel=1e-3)
    assert "CubeGI_bounce_7" in mesh.attributes and "CubeGI_bounce_8" not in mesh.attributes
    np.testing.assert_allclose(cubegi.cubegi_addon.attributes.read(mesh, "CubeGI"), 1.0, rtol=1e-3)


def test_albedo_one_stops_at_the_cap_with_a_warning(empty_scene, cubegi):
    mesh = furnace(1.0)
    assert bpy.ops.cubegi.bake(bounces=4, grid=(2, 2, 2)) == {"FINISHED"}
    rep = last_report()
    assert len(rep["bounces"]) == 4
    assert rep["tail"]["added"] is False and "do not converge" in rep["warnings"][0]
    total = cubegi.cubegi_addon.attributes.read(mesh, "CubeGI")
    assert np.isfinite(total).all()
    np.testing.assert_allclose(total, 4.0, rtol=5 * FLOAT32_TOL)
