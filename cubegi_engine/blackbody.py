"""The colour of a black body at a temperature, as a light's Temperature tints it.

Pure numpy; must not import bpy.

Conventions: linear Rec.709 (Blender's default scene-linear space), normalised to luminance
1 (Rec.709 weights 0.2126, 0.7152, 0.0722): that is how Cycles multiplies a light's colour
by its Temperature (measured against Cycles 5.0: a 6500 K light gives (1.043, 0.984,
1.035)). Sources:

1. Planck's law, spectral radiance ``B(l, T) ~ l^-5 / (exp(c2 / (l T)) - 1)``, with the second
   radiation constant ``c2 = h c / k = 1.4387769e-2 m K`` (CODATA).
2. The CIE 1931 2-degree colour-matching functions in the multi-lobe Gaussian fit of Wyman,
   Sloan and Shirley, "Simple Analytic Approximations to the CIE XYZ Color Matching
   Functions", JCGT 2(2), 2013, table 1.
3. XYZ to linear sRGB / Rec.709 (D65), IEC 61966-2-1.

Against Cycles' light Temperature (the ratio of the light with and without it, per channel):
within 1.1% for 2700-12000 K, 2.8% at 1800 K; below about 1500 K the fitted green falls off
too slowly (1000 K: green 0.12 against Cycles' 0.04), see :data:`ACCURATE_FROM`.
"""

import numpy as np

__all__ = ["blackbody_rgb", "ACCURATE_FROM"]

SECOND_RADIATION_CONSTANT = 1.4387769e-2  # m K
# Wavelengths summed, nm: where the colour-matching functions are non-zero (CIE 1931 tables
# run 360-830 nm), at 1 nm.
WAVELENGTHS = np.arange(360.0, 831.0, 1.0)
# (weight, centre nm, sigma below, sigma above) per lobe (source 2).
_LOBES = {
    "x": ((1.056, 599.8, 37.9, 31.0), (0.362, 442.0, 16.0, 26.7), (-0.065, 501.1, 20.4, 26.2)),
    "y": ((0.821, 568.8, 46.9, 40.5), (0.286, 530.9, 16.3, 31.1)),
    "z": ((1.217, 437.0, 11.8, 36.0), (0.681, 459.0, 26.0, 13.8)),
}
XYZ_TO_REC709 = np.array([
    [3.2404542, -1.5371385, -0.4985314],
    [-0.9692660, 1.8760108, 0.0415560],
    [0.0556434, -0.2040259, 1.0572252],
])
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
# Below this temperature (K) the result drifts from Cycles' by more than a few per cent.
ACCURATE_FROM = 1500.0


def _matching(wavelengths):
    """``(n, 3)`` CIE 1931 x, y, z colour-matching values at ``wavelengths`` (nm)."""
    columns = []
    for lobes in _LOBES.values():
        total = np.zeros_like(wavelengths)
        for weight, centre, below, above in lobes:
            sigma = np.where(wavelengths < centre, below, above)
            total += weight * np.exp(-0.5 * ((wavelengths - centre) / sigma) ** 2)
        columns.append(total)
    return np.stack(columns, axis=1)


_CMF = _matching(WAVELENGTHS)


def blackbody_rgb(temperature):
    """``(3,)`` float64 linear Rec.709 colour of a black body at ``temperature`` kelvin,
    luminance 1; negative channels (deep red, out of gamut) are clamped to 0 first."""
    t = max(float(temperature), 1.0)
    metres = WAVELENGTHS * 1e-9
    # Scaled so the largest term is about 1: only ratios matter, and float64 stays exact.
    with np.errstate(over="ignore"):  # exp overflows to inf at a few kelvin: no radiance there
        radiance = (metres / metres[0]) ** -5 / np.expm1(SECOND_RADIATION_CONSTANT / (metres * t))
    radiance = radiance / max(float(radiance.max()), 1e-300)
    rgb = np.maximum(XYZ_TO_REC709 @ (radiance @ _CMF), 0.0)
    return rgb / max(float(LUMINANCE @ rgb), 1e-300)
