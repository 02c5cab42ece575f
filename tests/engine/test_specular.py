"""What a Principled BSDF's specular layer sends on (cubegi_engine.specular): pure numpy."""

import numpy as np
import pytest

from cubegi.cubegi_engine import specular


def test_the_default_principled_bsdf_has_a_facing_reflectance_of_four_per_cent():
    assert specular.facing_reflectance(1.5, 0.5) == pytest.approx(0.04)
    assert specular.facing_reflectance(1.5, 0.0) == 0.0
    assert specular.facing_reflectance(1.5, 1.0) == pytest.approx(0.08)


def test_the_share_is_the_measured_one_at_four_per_cent_and_grows_with_the_reflectance():
    for roughness, share in zip(specular.ROUGHNESS, specular.SHARE_AT_F0):
        assert specular.specular_share(0.04, roughness) == pytest.approx(share)
    shares = [float(specular.specular_share(f0, 0.5)) for f0 in (0.0, 0.02, 0.04, 0.08, 0.5)]
    assert shares[0] == 0.0 and all(a < b for a, b in zip(shares, shares[1:])), shares
    assert np.all(specular.specular_share(np.array([0.0, 0.04, 1e9]), 2.0) <= 1.0)


def test_sent_on_keeps_white_and_raises_dark_colours_most():
    base = np.array([[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [0.05, 0.2, 0.8]])
    out = specular.sent_on(base, 0.02)
    assert np.allclose(out[0], 1.0) and np.allclose(out[1], 0.02)
    gain = out[2] / base[2]
    assert gain[0] > gain[1] > gain[2] > 1.0, gain
    assert np.allclose(out[2], base[2] + 0.02 * (1.0 - base[2]))
