"""Property-based tests (hypothesis) of the SH code: projection is linear, rotating the input
rotates the output, and deringing leaves no negative light from non-negative radiance."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from cubegi.cubegi_engine import cubemap, sh

N = 8
DIRS = cubemap.texel_directions(N).reshape(-1, 3)
SOLID = np.tile(cubemap.texel_solid_angles(N).ravel(), 6)
T = len(DIRS)
NORMALS = sh.fibonacci_sphere(3000)

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
radiance = arrays(np.float64, (T, 3), elements=finite)


@settings(max_examples=40, deadline=None)
@given(radiance, radiance, finite, finite)
def test_projection_is_linear(f, g, a, b):
    lhs = sh.project(a * f + b * g, DIRS, SOLID)
    rhs = a * sh.project(f, DIRS, SOLID) + b * sh.project(g, DIRS, SOLID)
    scale = 1.0 + np.abs(lhs).max() + np.abs(rhs).max()
    np.testing.assert_allclose(lhs, rhs, atol=1e-9 * scale)


def _rotation(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


quaternion = arrays(np.float64, 4, elements=st.floats(-1, 1)).filter(lambda q: np.linalg.norm(q) > 0.1)


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, 9, elements=st.floats(-1, 1)), quaternion)
def test_rotating_the_input_rotates_the_output(a, q):
    """Project f(R^T w) and evaluate at R n: the same as f projected and evaluated at n.

    f is an order-2 function, so its projection is exact up to the quadrature of a 32x32
    cube map (measured 1e-4 of the function's size; 2e-3 allowed)."""
    r = _rotation(q)
    dirs = cubemap.texel_directions(32).reshape(-1, 3)
    solid = np.tile(cubemap.texel_solid_angles(32).ravel(), 6)
    f = sh.basis(dirs) @ a
    f_rot = sh.basis(dirs @ r) @ a  # f(R^T w): rows are R^T w
    c = sh.project(f[:, None], dirs, solid)
    c_rot = sh.project(f_rot[:, None], dirs, solid)
    normals = NORMALS[::10]
    e = sh.irradiance_diffuse(c, normals)
    e_rot = sh.irradiance_diffuse(c_rot, normals @ r.T)
    np.testing.assert_allclose(e_rot, e, atol=2e-3 * (np.abs(a).sum() + 1e-3))


sparse_bright = st.tuples(
    st.lists(st.tuples(st.integers(0, T - 1), st.floats(0, 1e6)), min_size=1, max_size=6),
    st.floats(0, 1.0),
)


@settings(max_examples=60, deadline=None)
@given(sparse_bright)
def test_deringed_irradiance_of_non_negative_radiance_is_never_negative(spec):
    """A few very bright texels over a faint background: the worst case for ringing."""
    hot, background = spec
    rad = np.full((T, 3), background)
    for texel, value in hot:
        rad[texel] += value
    c = sh.project(rad, DIRS, SOLID)
    raw = sh.irradiance_diffuse(c, NORMALS)
    fixed, rings = sh.dering(c)
    e = sh.irradiance_diffuse(fixed, NORMALS)
    assert e.min() >= -1e-12 * max(e.max(), 1e-300)
    # Band 0 (the mean over all normals, the energy) is untouched; a probe that did not
    # ring is returned as it was.
    np.testing.assert_array_equal(fixed[0], c[0])
    np.testing.assert_allclose(e.mean(axis=0), raw.mean(axis=0), rtol=1e-3, atol=1e-12)
    np.testing.assert_array_equal(fixed[:, ~rings], c[:, ~rings])


def test_a_single_direction_rings_and_is_windowed_to_zero_at_worst():
    """The worst case, one direction: -3.7% of the peak before, >= 0 after (touching 0)."""
    c = sh.basis(np.array([[0.0, 0.0, 1.0]]))[0][:, None]
    dense = sh.fibonacci_sphere(40000)
    raw = sh.irradiance_diffuse(c, dense)[:, 0]
    assert raw.min() / raw.max() < -0.03
    fixed, rings = sh.dering(c)
    e = sh.irradiance_diffuse(fixed, dense)[:, 0]
    assert rings.all() and e.min() >= -1e-12 and e.min() < 1e-3 * e.max()
