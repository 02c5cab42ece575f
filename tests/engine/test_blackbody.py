"""The black-body colour of a light's Temperature (cubegi_engine.blackbody), against closed
forms: its normalisation, the colour-matching fit's integrals, and the order of colours."""

import numpy as np
import pytest

from cubegi.cubegi_engine import blackbody


@pytest.mark.parametrize("kelvin", [800, 1800, 2700, 4000, 6500, 12000, 40000])
def test_the_colour_has_luminance_one_and_no_negative_channel(kelvin):
    rgb = blackbody.blackbody_rgb(kelvin)
    assert rgb.shape == (3,) and (rgb >= 0).all()
    assert blackbody.LUMINANCE @ rgb == pytest.approx(1.0, rel=1e-12)


def test_the_colour_matching_fit_integrates_as_the_cie_tables_do():
    # The CIE 1931 tables integrate to 106.86 (x), 106.86 (y), 106.88 (z) over 360-830 nm at
    # 1 nm; the fit's stated accuracy is about 1% of the peak, so 2% of the integral.
    sums = blackbody._CMF.sum(axis=0)
    np.testing.assert_allclose(sums, [106.86, 106.86, 106.88], rtol=0.02)


def test_hotter_is_bluer_and_6500_kelvin_is_near_white():
    kelvins = [1200, 1800, 2700, 4000, 5500, 6500, 8000, 12000]
    rgb = np.array([blackbody.blackbody_rgb(k) for k in kelvins])
    assert (np.diff(rgb[:, 0]) < 0).all() and (np.diff(rgb[:, 1:], axis=0) >= 0).all()  # less red, more green and blue
    assert rgb[0, 2] == 0.0 and (rgb[2:, 2] > 0).all()  # below about 2000 K no blue at all
    # D65, the Rec.709 white, is close to a 6504 K black body (about 0.003 off the Planckian
    # locus in uv): within 5% per channel.
    np.testing.assert_allclose(blackbody.blackbody_rgb(6504), [1.0, 1.0, 1.0], rtol=0.05)
    assert blackbody.blackbody_rgb(1.0).tolist() == [0.0, 0.0, 0.0]  # no light at all, not NaN
