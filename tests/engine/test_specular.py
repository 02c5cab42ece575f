"""What a Principled BSDF sends on (cubegi_engine.specular): pure numpy."""

import numpy as np
import pytest

from cubegi.cubegi_engine import specular


def test_the_default_principled_bsdf_has_a_facing_reflectance_of_four_per_cent():
    assert specular.facing_reflectance(1.5, 0.5) == pytest.approx(0.04)
    assert specular.facing_reflectance(1.5, 0.0) == 0.0
    assert specular.facing_reflectance(1.5, 1.0) == pytest.approx(0.08)
    assert specular.facing_reflectance(1.0 / 1.5, 0.5) == pytest.approx(0.04)  # an IOR below 1, as Cycles reads it


# Cycles' furnace (see the module docstring) at base colours the table was not fitted on:
# (base, roughness) -> the reflectance at Specular IOR Level 0.5, IOR 1.5.
FURNACE = {(0.2, 1.0): 0.2191, (0.2, 0.5): 0.2339, (0.2, 0.0): 0.2256, (0.5, 1.0): 0.5100, (0.5, 0.5): 0.5106,
           (0.5, 0.0): 0.4907, (0.8, 1.0): 0.8046, (0.8, 0.5): 0.7936, (0.8, 0.0): 0.7653}


@pytest.mark.parametrize("base,roughness", list(FURNACE))
def test_the_layer_gives_the_furnaces_reflectance_at_other_base_colours(base, roughness):
    loss, gain = specular.layer(0.04, roughness)
    assert float(specular.sent_on(np.array([base] * 3), loss, gain)[0]) == pytest.approx(FURNACE[base, roughness], abs=0.006)


def test_no_layer_changes_nothing_and_a_stronger_one_reflects_more():
    assert specular.layer(0.0, 0.3) == (0.0, 0.0)
    gains = [float(specular.layer(f0, 0.5)[1]) for f0 in (0.0, 0.01, 0.04, 0.08, 0.2)]
    assert all(a < b for a, b in zip(gains, gains[1:])), gains
    loss, gain = specular.layer(np.array([0.0, 0.04, 1e9]), 2.0)
    assert np.all((0.0 <= gain) & (gain <= loss) & (loss <= 1.0)), (loss, gain)


def test_a_rough_white_base_sends_on_all_and_a_smooth_one_less_and_dark_ones_more():
    base = np.array([[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [0.05, 0.2, 0.8]])
    rough = specular.sent_on(base, *specular.layer(0.04, 1.0))
    assert np.allclose(rough[0], 1.0, atol=1e-3) and np.all(rough[1] > 0.02)
    gain = rough[2] / base[2]
    assert gain[0] > gain[1] > gain[2] > 1.0, gain
    assert specular.sent_on(base, *specular.layer(0.04, 0.0))[0, 0] < 0.96
