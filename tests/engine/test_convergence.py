"""Convergence estimates and error measures against hand-computed values (pure numpy)."""

import numpy as np
import pytest

from cubegi.cubegi_engine import convergence, metrics


def test_ratios_per_channel_and_zero_safe():
    r = convergence.ratios([2.0, 0.0, 4.0], [1.0, 0.0, 3.0])
    np.testing.assert_allclose(r, [0.5, 0.0, 0.75])


def test_remaining_share_of_a_geometric_series_is_exact():
    # Bounces a r^k, k = 1..n: computed sum a r (1 - r^n) / (1 - r), rest a r^(n+1) / (1 - r),
    # so the missing share of the whole (a r / (1 - r)) is r^n.
    a, n = 2.0, 4
    r = np.array([0.3, 0.6, 0.9])
    bounces = [a * r**k for k in range(1, n + 1)]
    share = convergence.remaining_share(np.sum(bounces, axis=0), bounces[-1], r)
    rest = a * r ** (n + 1) / (1 - r)
    whole = a * r / (1 - r)
    assert share == pytest.approx(rest.sum() / whole.sum(), rel=1e-12)
    tail = convergence.geometric_tail(np.tile(bounces[-1], (5, 1)), r)
    np.testing.assert_allclose(tail, np.tile(rest, (5, 1)), rtol=1e-12)


def test_divergent_series_reports_everything_missing_and_adds_nothing():
    r = np.array([0.5, 1.0, 1.2])
    assert not convergence.converges(r)
    assert convergence.remaining_share([1.0, 1.0, 1.0], [0.1, 0.1, 0.1], r) == 1.0
    tail = convergence.geometric_tail(np.ones((2, 3)), r)
    np.testing.assert_allclose(tail, [[1.0, 0.0, 0.0]] * 2)


def test_no_light_means_nothing_missing():
    assert convergence.remaining_share(np.zeros(3), np.zeros(3), np.zeros(3)) == 0.0


def test_gmres_solves_a_neumann_system():
    # (I - M) x = b with M of spectral radius 0.99: the sum of all powers of M applied to b.
    rng = np.random.default_rng(1)
    q, _ = np.linalg.qr(rng.normal(size=(40, 40)))
    m = q @ np.diag(np.linspace(0.99, -0.2, 40)) @ q.T
    b = rng.normal(size=40)
    x, iterations, residual = convergence.gmres(lambda v: v - m @ v, b, tol=1e-10, max_iter=40)
    np.testing.assert_allclose(x, np.linalg.solve(np.eye(40) - m, b), rtol=1e-7, atol=1e-9)
    assert residual <= 1e-10 and iterations <= 40
    assert convergence.gmres(lambda v: v, np.zeros(3))[0].tolist() == [0.0, 0.0, 0.0]


def test_error_measures_by_hand():
    # Grey values; areas 1, 1, 2. Reference mean (1 + 2 + 2*4) / 4 = 2.75.
    ref = np.array([1.0, 2.0, 4.0])
    est = np.array([2.0, 2.0, 3.0])
    areas = np.array([1.0, 1.0, 2.0])
    e = metrics.errors(est[:, None].repeat(3, 1), ref[:, None].repeat(3, 1), areas)
    assert e["reference_mean"] == pytest.approx(2.75)
    # Squared errors 1, 0, 1 weighted 1, 1, 2: 3 / 4.
    assert e["rel_rmse"] == pytest.approx(np.sqrt(0.75) / 2.75)
    # Estimate mean (2 + 2 + 6) / 4 = 2.5: bias -0.25 / 2.75.
    assert e["rel_bias"] == pytest.approx(-0.25 / 2.75)
    # |relative errors| 1.0, 0.0, 0.25 with weights 1, 1, 2 (sorted 0, 0.25, 1.0; cumulative
    # 1, 3, 4): the 95th percentile of weight 3.8 falls on 1.0.
    assert e["p95_rel"] == pytest.approx(1.0)
    # Channels are averaged first.
    rgb = metrics.errors(np.array([[1.0, 2.0, 3.0]]), np.array([[2.0, 2.0, 2.0]]), np.ones(1))
    assert rgb["rel_rmse"] == 0.0 and rgb["rel_bias"] == 0.0


def test_compare_adds_direct_and_indirect_for_the_total():
    areas = np.ones(2)
    c = metrics.compare(np.array([1.0, 1.0]), np.array([1.0, 3.0]), np.array([1.0, 1.0]), np.array([1.0, 1.0]), areas)
    assert c["direct"]["rel_rmse"] == 0.0
    assert c["indirect"]["rel_bias"] == pytest.approx(1.0)  # (4 - 2) / 2
    assert c["total"]["rel_bias"] == pytest.approx(0.5)  # (6 - 4) / 4
    assert metrics.errors(np.ones(3), np.zeros(3), np.ones(3))["rel_rmse"] == 0.0


def test_energy_conservation_makes_received_power_equal_landed_power():
    from cubegi.cubegi_engine.series import conserve_energy

    rng = np.random.default_rng(3)
    areas = rng.random(50) + 0.1
    sent = rng.random((50, 3))
    landing = rng.random((50, 3))
    received = (sent * landing * areas[:, None])[::-1] / areas[:, None] * 1.25  # 25% too much, elsewhere
    fixed, factor = conserve_energy(received, sent, landing, areas)
    np.testing.assert_allclose((areas[:, None] * fixed).sum(0), (areas[:, None] * sent * landing).sum(0), rtol=1e-12)
    np.testing.assert_allclose(fixed, received * factor)  # one scale per channel: the shape is kept
    # A factor outside 0.5..2 means something else is wrong: the light is left as it is.
    _, factor = conserve_energy(received * 10.0, sent, landing, areas)
    np.testing.assert_array_equal(factor, 1.0)
    # No light sent or received: factor 1, nothing divided by zero.
    _, factor = conserve_energy(np.zeros((50, 3)), sent, landing, areas)
    np.testing.assert_array_equal(factor, 1.0)


def test_fixed_point_settles_a_contraction_and_stops_at_its_cap():
    a = np.array([[0.4, 0.3], [0.2, 0.5]])  # eigenvalues 0.7 and 0.2
    b = np.array([1.0, 2.0])
    x, steps = convergence.fixed_point(lambda x: a @ x + b, np.zeros(2))
    assert np.abs(x - np.linalg.solve(np.eye(2) - a, b)).max() <= 1e-5 * np.abs(x).max()
    assert steps < convergence.FIXED_POINT_STEPS
    _, capped = convergence.fixed_point(lambda x: 0.999 * x + 1.0, np.zeros(1), max_steps=2)
    assert capped == 2
    same, one = convergence.fixed_point(lambda x: x, np.ones(3))
    assert one == 1 and np.array_equal(same, np.ones(3))


def test_fixed_point_mixes_its_steps_where_plain_steps_would_crawl():
    """A loop that keeps 0.94 of its light a step (a white cavity): plain steps need about 250
    to settle to 1e-6; the Anderson mix settles it in a few dozen, to the same answer, and the
    clamp of a nonlinear step holds."""
    rng = np.random.default_rng(3)
    a = rng.uniform(0.0, 1.0, (200, 200))
    a *= 0.94 / a.sum(axis=1, keepdims=True)  # every row keeps 0.94: the max norm's gain
    b = rng.uniform(-0.2, 1.0, 200)
    exact = np.linalg.solve(np.eye(200) - a, b)
    x, steps = convergence.fixed_point(lambda x: a @ x + b, np.zeros(200), gain=0.94)
    assert steps <= 40
    assert np.abs(x - exact).max() <= 1e-5 * np.abs(exact).max()
    plain = np.zeros(200)
    for _ in range(steps):
        plain = a @ plain + b
    assert np.abs(plain - exact).max() > 100 * np.abs(x - exact).max()  # what as many plain steps reach
    clamped, _ = convergence.fixed_point(lambda x: np.maximum(a @ x + b - 0.5, 0.0), np.zeros(200), gain=0.94)
    assert clamped.min() >= 0.0
    np.testing.assert_allclose(clamped, np.maximum(a @ clamped + b - 0.5, 0.0), atol=1e-5 * clamped.max())


def test_squared_error_says_which_points_hold_the_error():
    # Three points; the large one off by 1, a small one off by 2: a (x - r)^2 = 10 and 4.
    est, ref, areas = np.array([2.0, 3.0, 1.0]), np.array([1.0, 1.0, 1.0]), np.array([10.0, 1.0, 1.0])
    share = metrics.squared_error(est, ref, areas)
    assert share == pytest.approx([10 / 14, 4 / 14, 0.0])
    assert metrics.error_holders(est, ref, areas) == {"points": 1, "area_share": pytest.approx(10 / 12)}
    assert metrics.error_holders(est, ref, areas, share=0.8)["points"] == 2  # 10/14 < 0.8
    assert metrics.error_holders(ref, ref, areas) == {"points": 0, "area_share": 0.0}
    assert not metrics.squared_error(ref, ref, areas).any()


def test_the_objects_furthest_off_are_named_with_their_share_and_mean_bias():
    """Three objects: a large ground right on, a room whose indirect light is 30% too bright,
    a glass case that Cycles gives no light: the case and the room hold the error, in that
    order, each with its mean direct and indirect bias (none where the reference has none, or
    a negligible share of the scene's light); the ground, under the least share, is not
    listed; ``most`` caps the list."""
    areas = np.array([100.0, 100.0, 1.0, 1.0, 1.0, 1.0, 0.5])
    light = {"direct": np.zeros((7, 3)), "indirect": np.zeros((7, 3))}
    reference = {"direct": np.zeros((7, 3)), "indirect": np.zeros((7, 3))}
    reference["indirect"][:6], light["indirect"][:2] = 1.0, 1.0  # the ground: 2 points, right
    light["indirect"][2:6] = 1.3  # the room: 4 points, +30%
    light["direct"][6] = 1.0  # the case: none in Cycles
    found = metrics.furthest_off(["Ground", "Room", "Case"], [2, 4, 1], light, reference, areas)
    assert [o["name"] for o in found] == ["Case", "Room"]
    case, room = found
    assert case["direct_bias"] is None and case["indirect_bias"] is None
    assert room["indirect_bias"] == pytest.approx(0.3) and room["direct_bias"] is None
    assert case["error_share"] + room["error_share"] == pytest.approx(1.0) and case["error_share"] > room["error_share"]
    assert [o["name"] for o in metrics.furthest_off(["Ground", "Room", "Case"], [2, 4, 1], light, reference, areas, most=1)] == ["Case"]
    # A light Cycles gives the case but under a thousandth of the scene's mean: no bias either.
    reference["direct"][6] = 1e-4
    (case, _) = metrics.furthest_off(["Ground", "Room", "Case"], [2, 4, 1], light, reference, areas)
    assert case["name"] == "Case" and case["direct_bias"] is None
    reference["direct"][6] = 0.5
    found = {o["name"]: o for o in metrics.furthest_off(["Ground", "Room", "Case"], [2, 4, 1], light, reference, areas)}
    assert found["Case"]["direct_bias"] == pytest.approx(1.0)


def test_the_anderson_mix_takes_the_same_products_a_step_at_a_time(monkeypatch):
    """fixed_point keeps the Gram matrix of its last changes and takes only the new change's
    products each step: the matrix it mixes with is the one made whole from its changes, bit
    for bit, through the window's sliding."""
    rng = np.random.default_rng(7)
    a = rng.normal(size=(40, 40)) * 0.12
    b = rng.normal(size=40)
    seen = []
    real = np.linalg.lstsq

    def lstsq(matrix, rhs, rcond=None):
        seen.append(np.array(matrix))
        return real(matrix, rhs, rcond=rcond)

    def whole(changes):
        return np.array([[x @ y for y in changes] for x in changes])

    made = []
    gram_with = convergence._gram_with

    def recording(gram, changes):
        out = gram_with(gram, changes)
        made.append((out, whole(changes)))
        return out

    monkeypatch.setattr(convergence.np.linalg, "lstsq", lstsq)
    monkeypatch.setattr(convergence, "_gram_with", recording)
    x, steps = convergence.fixed_point(lambda v: a @ v + b, np.zeros(40), tol=1e-12)
    assert steps > convergence.ANDERSON_MEMORY + 2  # the window slid
    assert len(made) >= convergence.ANDERSON_MEMORY + 1
    for kept, full in made:
        np.testing.assert_array_equal(kept, full)
    np.testing.assert_allclose(x, np.linalg.solve(np.eye(40) - a, b), rtol=1e-6, atol=1e-9)
    assert len(seen) == len(made)
