"""The engine's mathematics against closed forms and brute force (pure numpy, no bpy)."""

from dataclasses import replace

import numpy as np
import pytest

from cubegi.cubegi_engine import cubemap, grid, lights, sh, visibility
from cubegi.cubegi_engine.geometry import all_three, in_box

N = 32
DIRS = cubemap.texel_directions(N).reshape(-1, 3)
SOLID = np.tile(cubemap.texel_solid_angles(N).ravel(), 6)
# Quadrature at texel centres of a 32x32 cube map integrates the order-2 basis to about
# 1e-4 of pi; 1e-3 leaves margin without hiding a wrong constant (those are off by >= 10%).
QUADRATURE_TOL = 1e-3


def test_texel_solid_angles_sum_to_4pi():
    for n in (1, 2, 7, 32, 128):
        total = 6 * cubemap.texel_solid_angles(n).sum()
        assert total == pytest.approx(4 * np.pi, rel=1e-12), n


def test_texel_solid_angle_matches_small_texel_estimate():
    # A texel's solid angle ~ its area x cos / r^2 at its centre, for small texels.
    n = 256
    u, v = cubemap.texel_uv(n)
    approx = (2.0 / n) ** 2 / (1 + u * u + v * v) ** 1.5
    np.testing.assert_allclose(cubemap.texel_solid_angles(n), approx, rtol=1e-4)


def test_texel_lookup_round_trip():
    face, row, col, _, _ = cubemap.direction_to_texel(cubemap.texel_directions(16), 16)
    f, r, c = np.meshgrid(np.arange(6), np.arange(16), np.arange(16), indexing="ij")
    assert (face == f).all() and (row == r).all() and (col == c).all()


def test_face_frames_are_right_handed_cameras():
    for f in range(6):
        view = cubemap.look_matrix(np.zeros(3), cubemap.FACE_FORWARD[f], cubemap.FACE_UP[f])
        np.testing.assert_allclose(view[:3, :3] @ cubemap.FACE_FORWARD[f], [0, 0, -1], atol=1e-12)
        np.testing.assert_allclose(view[:3, :3] @ cubemap.FACE_RIGHT[f], [1, 0, 0], atol=1e-12)
        assert np.linalg.det(view[:3, :3]) == pytest.approx(1.0)


def test_turned_cubes_draw_each_direction_where_the_lookup_finds_it():
    """A turned shadow cube: the face and texel the lookup picks for a world direction (in the
    cube's own frame) are where that face's view-projection draws the point."""
    turns = cubemap.turns(5, seed=3)
    np.testing.assert_allclose(np.einsum("kji,kjl->kil", turns, turns), np.broadcast_to(np.eye(3), (5, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(turns), 1.0)
    assert not np.allclose(turns[0], turns[1])
    eyes = np.random.default_rng(1).normal(size=(5, 3))
    vps = cubemap.cube_view_projections_many(eyes, 0.01, 100.0, turns).reshape(5, 6, 4, 4)
    dirs = np.random.default_rng(2).normal(size=(200, 3))
    n = 32
    for k in range(5):
        face, row, col, _, _ = cubemap.direction_to_texel(dirs @ turns[k], n)
        clip = np.einsum("sij,sj->si", vps[k, face], np.concatenate([eyes[k] + dirs, np.ones((200, 1))], axis=1))
        ndc = clip[:, :2] / clip[:, 3:]
        assert (clip[:, 3] > 0).all() and (np.abs(ndc) <= 1 + 1e-9).all()
        np.testing.assert_array_equal(np.clip(((ndc[:, 0] + 1) * 0.5 * n).astype(int), 0, n - 1), col)
        np.testing.assert_array_equal(np.clip(((ndc[:, 1] + 1) * 0.5 * n).astype(int), 0, n - 1), row)


def test_constant_radiance_gives_its_value():
    c = np.array([0.3, 1.0, 2.5])
    coeffs = sh.project(np.tile(c, (len(DIRS), 1)), DIRS, SOLID)
    got = sh.irradiance_diffuse(coeffs, sh.fibonacci_sphere(50))
    np.testing.assert_allclose(got, np.tile(c, (50, 1)), rtol=1e-9)


def test_linear_radiance_gives_exact_irradiance():
    # L(w) = a + b.w  ->  E(n) = pi a + 2 pi / 3 b.n  (bands 0 and 1 are exact).
    a, b = 0.7, np.array([0.2, -0.3, 0.4])
    coeffs = sh.project((a + DIRS @ b)[:, None], DIRS, SOLID)
    n = sh.fibonacci_sphere(200)
    want = a + (2.0 / 3.0) * (n @ b)
    np.testing.assert_allclose(sh.irradiance_diffuse(coeffs, n)[:, 0], want, atol=QUADRATURE_TOL)


def test_clamped_cosine_lobe_coefficients_and_irradiance():
    # L(w) = max(0, w.z): analytic coefficients L00 = sqrt(pi)/2, L10 = sqrt(pi/3),
    # L20 = sqrt(5 pi)/8, others 0 (R&H 2001, eq. 10 with A_l / sqrt(4 pi / (2l+1))).
    radiance = np.maximum(DIRS[:, 2], 0.0)[:, None]
    coeffs = sh.project(radiance, DIRS, SOLID)[:, 0]
    want = np.zeros(9)
    want[0], want[2], want[6] = np.sqrt(np.pi) / 2, np.sqrt(np.pi / 3), np.sqrt(5 * np.pi) / 8
    np.testing.assert_allclose(coeffs, want, atol=QUADRATURE_TOL)
    # Irradiance of that lobe at normal n, by brute force over a fine cube map.
    fine = cubemap.texel_directions(128).reshape(-1, 3)
    fine_w = np.tile(cubemap.texel_solid_angles(128).ravel(), 6)
    n = sh.fibonacci_sphere(64)
    brute = (np.maximum(fine[:, 2], 0)[None] * np.maximum(n @ fine.T, 0) * fine_w).sum(1) / np.pi
    got = sh.irradiance_diffuse(coeffs[:, None], n)[:, 0]
    # Order-2 truncation: R&H report under 3% average error for irradiance; the worst case
    # for this lobe is 0.03 of the peak value 2/3 near the lobe's terminator.
    assert np.abs(got - brute).max() < 0.03 * (2 / 3)
    assert np.abs(got - brute).mean() < 0.01 * (2 / 3)


def test_projection_is_linear_and_rotates_with_input():
    rng = np.random.default_rng(1)
    a, b = rng.random((len(DIRS), 3)), rng.random((len(DIRS), 3))
    np.testing.assert_allclose(
        sh.project(2 * a + 3 * b, DIRS, SOLID), 2 * sh.project(a, DIRS, SOLID) + 3 * sh.project(b, DIRS, SOLID), rtol=1e-10
    )
    # A lobe about +x gives, at +x, what a lobe about +z gives at +z.
    lobe_x = sh.project(np.maximum(DIRS[:, 0], 0)[:, None], DIRS, SOLID)
    lobe_z = sh.project(np.maximum(DIRS[:, 2], 0)[:, None], DIRS, SOLID)
    assert sh.irradiance_diffuse(lobe_x, np.array([1.0, 0, 0]))[0] == pytest.approx(
        sh.irradiance_diffuse(lobe_z, np.array([0, 0, 1.0]))[0], rel=1e-6
    )


def test_grid_positions_and_trilinear_weights():
    g = grid.ProbeGrid((0, 0, 0), (3, 2, 7), (3, 2, 7))
    pos = g.positions()
    assert pos.shape == (42, 3)
    np.testing.assert_allclose(pos[0], [0.5, 0.5, 0.5])
    np.testing.assert_allclose(pos[1], [1.5, 0.5, 0.5])  # x fastest
    rng = np.random.default_rng(0)
    pts = rng.uniform([0.5, 0.5, 0.5], [2.5, 1.5, 6.5], (500, 3))
    idx, w = g.trilinear(pts)
    np.testing.assert_allclose(w.sum(1), 1.0)
    assert (w >= 0).all()
    # Trilinear interpolation reproduces any linear function inside the probe hull.
    f = pos @ np.array([1.0, -2.0, 0.5]) + 3.0
    np.testing.assert_allclose((w * f[idx]).sum(1), pts @ np.array([1.0, -2.0, 0.5]) + 3.0, atol=1e-12)
    # Outside the hull weights clamp to the nearest probes and still sum to 1.
    idx, w = g.trilinear(np.array([[-5.0, -5.0, -5.0], [10, 10, 10]]))
    np.testing.assert_allclose(w.sum(1), 1.0)
    assert idx[0, np.argmax(w[0])] == 0 and idx[1, np.argmax(w[1])] == 41


def test_probes_behind_a_points_plane_light_it_only_where_no_probe_in_front_can():
    """A 2x2x2 grid of unit cells; nothing drawn (every probe sees every point). A point
    facing up between the layers takes only the upper probes; a point facing up above all
    of them (a block's top) takes the ones it stands over only in the second weights of ``both``, else
    none; a point facing sideways keeps the probes on its side."""
    g = grid.ProbeGrid((0, 0, 0), (2, 2, 2), (2, 2, 2))  # probes at 0.5 and 1.5
    pos = g.positions()
    pts = np.array([[1.0, 1.0, 0.8], [1.0, 1.0, 1.9], [1.0, 1.0, 1.0]])
    nrm = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    index, weight = g.trilinear(pts)
    dist = np.full((8, 6, 4, 4), np.inf)
    valid = np.ones(8, dtype=bool)
    probes, at = visibility.Probes(pos, dist, valid), visibility.PointProbes(pts, nrm, index, weight)
    w = visibility.visibility_weights(g, probes, at).weights
    above = pos[index][..., 2] > 1.0
    right = pos[index][..., 0] > 1.0
    np.testing.assert_allclose(w[0], np.where(above[0], 0.25, 0.0))
    assert not w[1].any()  # all eight stand more than a tenth of a cell below its plane
    np.testing.assert_allclose(w[2], np.where(right[2], 0.25, 0.0))
    both = visibility.visibility_weights(g, probes, at, both=True)
    strict, kept = both.weights, both.behind
    np.testing.assert_array_equal(strict, w)
    np.testing.assert_allclose(kept[1], weight[1])
    np.testing.assert_allclose(kept[[0, 2]], w[[0, 2]])


def test_single_probe_grid_and_bad_grids():
    g = grid.ProbeGrid((0, 0, 0), (1, 1, 1), (1, 1, 1))
    idx, w = g.trilinear(np.random.default_rng(0).random((10, 3)))
    assert (idx == 0).all() and np.allclose(w.sum(1), 1)
    for res in [(0, 1, 1), (-1, 2, 2), (1, 1)]:
        with pytest.raises(ValueError):
            grid.ProbeGrid((0, 0, 0), (1, 1, 1), res)
    with pytest.raises(ValueError):
        grid.ProbeGrid((0, 0, 0), (0, 1, 1), (1, 1, 1))


def test_grid_set_uses_the_finest_containing_grid_then_the_nearest():
    coarse = grid.ProbeGrid((0, 0, 0), (4, 4, 4), (2, 2, 2))
    fine = grid.ProbeGrid((1, 1, 1), (2, 2, 2), (4, 4, 4))
    beside = grid.ProbeGrid((10, 0, 0), (11, 1, 1), (1, 1, 1))
    gs = grid.GridSet([coarse, fine, beside])
    pts = np.array([[0.5, 0.5, 0.5], [1.5, 1.5, 1.5], [2.0, 2.0, 2.0], [10.5, 0.5, 0.5], [6.0, 0.5, 0.5], [9.5, 0.5, 0.5]])
    np.testing.assert_array_equal(gs.assign(pts), [0, 1, 1, 2, 0, 2])
    idx, w = gs.trilinear(pts)
    # The coarse probe at (1, 1, 1) lies in the fine grid's box: the coarse grid's points
    # leave it out. The first point's only probe (clamped) is that one: no probe light.
    np.testing.assert_allclose(w.sum(1), [0.0, 1.0, 1.0, 1.0, 1.0, 1.0])
    assert w[0].sum() == 0.0 and (w[4] > 0).any() and not np.isin(idx[4][w[4] > 0], [0]).any()
    # Indices fall in each grid's own range, and match that grid's own weights.
    assert (idx[0] < 8).all() and ((idx[1] >= 8) & (idx[1] < 72)).all() and (idx[3] == 72).all()
    i1, w1 = fine.trilinear(pts[1:2])
    np.testing.assert_array_equal(idx[1], i1[0] + 8)
    np.testing.assert_allclose(w[1], w1[0])
    np.testing.assert_allclose(gs.positions()[8:72], fine.positions())
    np.testing.assert_allclose(gs.point_cell_edge(pts[:2]), [2.0, 0.25])
    # On a tie (same cells, both contain the point) the first grid wins.
    twin = grid.GridSet([coarse, grid.ProbeGrid((0, 0, 0), (4, 4, 4), (2, 2, 2))])
    assert (twin.assign(pts[:3]) == 0).all()
    with pytest.raises(ValueError):
        grid.GridSet([])


def brute_form_factor(point, normal, polygon, n=512):
    # Integrate cos / pi over the directions that hit the polygon (fine cube-map quadrature).
    d = cubemap.texel_directions(n).reshape(-1, 3)
    w = np.tile(cubemap.texel_solid_angles(n).ravel(), 6)
    p0, e1, e2 = polygon[0], polygon[1] - polygon[0], polygon[3] - polygon[0]
    nrm = np.cross(e1, e2)
    t = ((p0 - point) @ nrm) / (d @ nrm)
    hit = point + t[:, None] * d - p0
    a = hit @ e1 / (e1 @ e1)
    b = hit @ e2 / (e2 @ e2)
    inside = (t > 0) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
    return (w * inside * np.maximum(d @ normal, 0)).sum() / np.pi


@pytest.mark.parametrize(
    "point,normal",
    [
        ((0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
        ((0.3, -0.2, 0.0), (0.0, 0.6, 0.8)),
        ((0.0, 0.0, 0.5), (1.0, 0.0, 0.0)),  # polygon straddles the horizon: clipped
        ((2.0, 0.0, 0.9), (-1.0, 0.0, 0.0)),
    ],
)
def test_polygon_form_factor_matches_brute_force(point, normal):
    poly = lights.area_polygon("SQUARE", 1.0, 1.0) + np.array([0.0, 0.0, 1.0])
    got = lights.polygon_form_factor(np.array([point]), np.array([normal]), poly)[0]
    assert got == pytest.approx(brute_form_factor(np.array(point), np.array(normal), poly), abs=2e-3)


def test_disk_polygon_has_exact_area_and_spot_cone():
    poly = lights.area_polygon("DISK", 2.0, 2.0)
    x, y = poly[:, 0], poly[:, 1]
    assert 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) == pytest.approx(np.pi)
    spot = lights.Light("SPOT", np.ones(3), np.zeros(3), np.array([0, 0, -1.0]), spot_size=np.radians(60), spot_blend=0.5)
    a = lights.spot_attenuation(spot, np.array([[0, 0, -1.0], [np.sin(0.45), 0, -np.cos(0.45)], [1.0, 0, 0]]))
    assert a[0] == 1.0 and 0 < a[1] < 1 and a[2] == 0


def test_a_probe_subset_keeps_the_weights_of_the_probes_points_use():
    g = grid.ProbeGrid((0, 0, 0), (4, 4, 4), (4, 4, 4))
    rng = np.random.default_rng(2)
    pts = rng.uniform([0.6, 0.6, 0.6], [1.4, 1.4, 3.4], (200, 3))  # a column of cells
    used = grid.probes_used(g, pts)
    assert 0 < used.sum() < g.count
    sub = grid.ProbeSubset(g, used)
    assert sub.count == used.sum() and sub.left_out == g.count - used.sum()
    np.testing.assert_array_equal(sub.positions(), g.positions()[used])
    i0, w0 = g.trilinear(pts)
    i1, w1 = sub.trilinear(pts)
    np.testing.assert_array_equal(sub.keep[i1][w1 > 0], i0[w1 > 0])
    np.testing.assert_allclose(w1, w0)  # every probe a point weighs is kept
    # A point elsewhere has no kept probe: no weight at all.
    _, w = sub.trilinear(np.array([[3.5, 3.5, 0.5]]))
    assert not w.any()
    values = np.arange(sub.count, dtype=float)
    full = sub.expand(values, fill=-1.0)
    assert full.shape == (g.count,) and (full[~used] == -1).all() and np.array_equal(full[used], values)


def test_edge_neighbours_pair_the_triangles_across_each_edge():
    from cubegi.cubegi_engine.geometry import edge_neighbours

    # Two quads side by side: 0-1-4-3 and 1-2-5-4, two triangles each.
    tris = np.array([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])
    nb = edge_neighbours(tris)
    assert nb[0].tolist() == [-1, 3, 1]  # edge 1-4 borders triangle 3, edge 4-0 triangle 1
    assert nb[1].tolist() == [0, -1, -1] and nb[3].tolist() == [2, -1, 0]
    assert (edge_neighbours(np.zeros((0, 3), dtype=np.int64)) == -1).all()


def test_a_ray_cuts_a_triangle_where_the_textbook_test_says():
    """cut_planes (precomputed planes), cut_triangles and cuts_ahead agree with
    Moller-Trumbore on random rays and triangles, degenerate and grazing ones included."""
    from cubegi.cubegi_engine.geometry import cut_planes, cut_triangles, cuts_ahead, triangle_planes

    rng = np.random.default_rng(3)
    vertices = rng.normal(size=(300, 3))
    triangles = rng.integers(0, 300, size=(100, 3))
    triangles[0] = (4, 4, 7)  # no area
    origins = rng.normal(size=(2000, 3)) * 3
    tid = rng.integers(-1, 100, size=2000)
    aim = vertices[triangles[np.maximum(tid, 0)]].mean(axis=1) + rng.normal(size=(2000, 3)) * 0.3
    u = (aim - origins) / np.linalg.norm(aim - origins, axis=1, keepdims=True)
    t, inside = cut_planes(origins, u, tid, triangle_planes(triangles, vertices))
    t2, inside2 = cut_triangles(origins, u, tid, triangles, vertices)
    np.testing.assert_array_equal(inside, inside2)
    np.testing.assert_allclose(t, t2, rtol=1e-12, equal_nan=True)
    a, b, c = (vertices[triangles[np.maximum(tid, 0)]][:, k] for k in range(3))
    e1, e2 = b - a, c - a
    p = np.cross(u, e2)
    det = np.einsum("ic,ic->i", e1, p)
    n = np.cross(e1, e2)
    ok = (tid >= 0) & (np.abs(np.einsum("ic,ic->i", u, n)) > 1e-3 * np.linalg.norm(n, axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        s = origins - a
        bu = np.einsum("ic,ic->i", s, p) / det
        q = np.cross(s, e1)
        bv = np.einsum("ic,ic->i", u, q) / det
        tt = np.einsum("ic,ic->i", e2, q) / det
    far = ok & (np.minimum(np.minimum(bu, bv), 1 - bu - bv) > 1e-9) | (np.minimum(np.minimum(bu, bv), 1 - bu - bv) < -1e-9)
    assert ok.sum() > 1000 and (inside & ok).sum() > 100 and not inside[~ok].any()
    np.testing.assert_array_equal(inside[far & ok], ((bu >= 0) & (bv >= 0) & (bu + bv <= 1))[far & ok])
    np.testing.assert_allclose(t[ok], tt[ok], rtol=1e-9, atol=1e-9)
    assert np.isnan(t[~ok]).all()
    # The cover test's cut: the same cuts, asked only up to a depth along each ray.
    depth = rng.random(2000) * 6.0
    ahead, inside3 = cuts_ahead(origins, u, tid, triangle_planes(triangles, vertices), depth)
    want = (t > 0) & (t < depth)
    assert 100 < want.sum() < ok.sum() and (want & inside).sum() > 50
    np.testing.assert_array_equal(ahead, want)
    np.testing.assert_array_equal(inside3, inside & want)


def test_the_cover_ring_search_finds_the_crossed_triangle_up_to_two_edges_away():
    """A strip of triangles along x, one object; the ray crosses triangle 6. From triangle
    4 (two edges away) it is found; from triangle 2 (four away) it is not; nor across
    an object border."""
    from cubegi.cubegi_engine.geometry import edge_neighbours, triangle_planes
    from cubegi.cubegi_engine.visibility import Cover, _ring_search

    xs = np.arange(7.0)
    vertices = np.concatenate([np.stack([xs, np.zeros(7), np.zeros(7)], 1), np.stack([xs, np.ones(7), np.zeros(7)], 1)])
    triangles = []
    for i in range(6):
        triangles += [(i, i + 1, 7 + i), (i + 1, 8 + i, 7 + i)]
    triangles = np.array(triangles)
    eye = np.array([[3.6, 0.2, 5.0]] * 4)  # down onto triangle 6 (x in [3, 4], below the diagonal)
    u = np.array([[0.0, 0.0, -1.0]] * 4)
    depth = np.array([10.0, 10.0, 10.0, 4.0])  # the last stops above the strip
    ray_of, seen = np.array([0, 1, 2, 3]), np.array([4, 2, 4, 4])  # each ray's seen triangle
    one = Cover(None, np.zeros(12, int), triangle_planes(triangles, vertices), edge_neighbours(triangles), None)
    assert _ring_search(one, ray_of, seen, eye, u, depth).tolist() == [True, False, True, False]
    split = Cover(None, (np.arange(12) >= 5).astype(int), one.planes, one.neighbours, None)
    assert _ring_search(split, ray_of, seen, eye, u, depth).tolist() == [False, False, False, False]



def _two_strips():
    """Two strips of 12 triangles along x, one at z = 0 and one at z = 1, both facing +z."""
    xs = np.arange(7.0)
    row = np.concatenate([np.stack([xs, np.zeros(7), np.zeros(7)], 1), np.stack([xs, np.ones(7), np.zeros(7)], 1)])
    strip = np.array([t for i in range(6) for t in ((i, i + 1, 7 + i), (i + 1, 8 + i, 7 + i))])
    return np.concatenate([row, row + [0.0, 0.0, 1.0]]), np.concatenate([strip, strip + 14])


def test_the_cast_cover_meets_the_first_covering_triangle_past_its_own_objects_folds(monkeypatch):
    """The cast cover test (visibility.CastCover, over a NumpyRays): a ray to a point below
    two strips is covered by the first triangle it meets of another object, or of its own
    object facing away from the point; its own object's triangles facing the point are
    passed (COVER_ROUNDS times at most); a sheet met from behind faces the other way; a ray
    that stops short of the strips, or meets nothing, is not covered."""
    from cubegi.cubegi_engine import visibility
    from cubegi.cubegi_engine.rays import NumpyRays
    from cubegi.cubegi_engine.visibility import CastCover, _cast_covered

    vertices, triangles = _two_strips()
    upper = np.arange(24) >= 12

    def covered(objects, normal, down=True, sheet=False, depth=7.0, owner=0):
        cover = CastCover.of(NumpyRays(vertices, triangles), triangles, vertices, np.asarray(objects), np.full(24, sheet),
                             np.zeros(1, int), 10.0)
        eye = np.array([[4.6, 0.3, 5.0 if down else -5.0]])
        u = np.array([[0.0, 0.0, -1.0 if down else 1.0]])
        return bool(_cast_covered(cover, eye, u, np.array([depth]), np.array([owner]), np.array([normal], dtype=float))[0])

    up, down = [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]
    assert covered(np.where(upper, 2, 1), up)  # another object's strip above
    assert not covered(np.zeros(24, int), up)  # its own folds, facing it: passed
    assert covered(np.where(upper, 0, 1), up)  # past its own upper strip, onto another object's
    assert covered(np.zeros(24, int), down)  # its own surface facing away: a thin wall's far side
    assert not covered(np.where(upper, 2, 1), up, depth=3.5)  # stops above the strips
    # From below, both strips are met from behind: a one-sided strip faces away from a point
    # above it facing down; a sheet's twin faces it.
    assert covered(np.zeros(24, int), down, down=False)
    assert not covered(np.zeros(24, int), down, down=False, sheet=True)
    assert not covered(np.zeros(24, int), up, down=False, depth=0.5)
    monkeypatch.setattr(visibility, "COVER_ROUNDS", 0)  # no fold passed: the lower strip is never met
    assert not covered(np.where(upper, 0, 1), up)
    # Nothing asked: nothing cast.
    cover = CastCover.of(NumpyRays(vertices, triangles), triangles, vertices, np.zeros(24, int), np.zeros(24, bool), np.zeros(1, int), 10.0)
    assert _cast_covered(cover, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, int), np.zeros((0, 3))).shape == (0,)


def _random_cover(rng, s=40, p=3, n=4, objects=3):
    """A cover test's inputs over random triangles of a few objects (seen by random texels):
    the cover, and the same with the exact rays cast (a NumpyRays over the triangles)."""
    from cubegi.cubegi_engine.geometry import edge_neighbours, triangle_planes
    from cubegi.cubegi_engine.rays import NumpyRays
    from cubegi.cubegi_engine.visibility import CastCover, Cover, PointProbes, _Texels

    vertices, triangles = rng.uniform(0, 1, (40, 3)), rng.integers(0, 40, (60, 3))
    cover = Cover(rng.integers(-1, 60, (p, 6, n, n)).astype(np.int32), rng.integers(0, objects, 60),
                  triangle_planes(triangles, vertices), edge_neighbours(triangles), rng.integers(0, objects, s))
    normals = rng.normal(size=(s, 3))
    index = rng.integers(0, p, (s, 8))
    at = PointProbes(rng.uniform(0, 1, (s, 3)), normals / np.linalg.norm(normals, axis=1)[:, None], index, rng.uniform(0, 1, (s, 8)))
    texels = _Texels(rng.integers(0, 6, (s, 8)), rng.integers(0, n, (s, 8)), rng.integers(0, n, (s, 8)), n)
    cast = CastCover.of(NumpyRays(vertices, triangles), triangles, vertices, cover.triangle_object, np.zeros(60, bool), cover.point_object, 1.0)
    return (cover, replace(cover, cast=cast), at, rng.uniform(-1, 2, (p, 3))[index], texels, rng.uniform(0.01, 0.1, (s, 1)),
            rng.uniform(size=(s, 8)) < 0.5)


def test_the_cover_test_is_each_pairs_own_and_cut_into_chunks_alike(monkeypatch):
    """Each (point, probe) pair's cover is found from its own ray and texels: asked pair by
    pair (each texel's triangle cut with the ray, then the rings around the ones it missed)
    the answers are the same as asked all at once, whatever the ring search's chunks; and
    asking a point's probes one at a time until one is covered says the same as asking all."""
    from cubegi.cubegi_engine import visibility
    from cubegi.cubegi_engine.geometry import cut_planes

    rng = np.random.default_rng(5)
    found = rings = cast_decided = 0
    monkeypatch.setattr(visibility, "COVER_ROUNDS", 100)  # every fold passed: the first blocking triangle decides
    chunk = visibility.RING_CHUNK
    for _ in range(20):
        cover, cast, at, eyes, texels, cell, ask = _random_cover(rng)
        whole = visibility._covered(cover, at, eyes, texels, cell, ask)
        by_cast = np.zeros(ask.shape, dtype=bool)
        monkeypatch.setattr(visibility, "RING_CHUNK", int(rng.integers(1, 4)))
        assert np.array_equal(visibility._covered(cover, at, eyes, texels, cell, ask), whole)
        monkeypatch.setattr(visibility, "RING_CHUNK", chunk)
        n = texels.n
        for i, k in zip(*np.nonzero(ask)):  # pair by pair
            q = at.points[i] + 1e-3 * cell[i, 0] * at.normals[i]
            u = (q - eyes[i, k]) / np.linalg.norm(q - eyes[i, k])
            depth = np.linalg.norm(q - eyes[i, k]) - 1e-4 * cell[i, 0]
            tids = {int(cover.probe_tid[at.index[i, k], texels.face[i, k], min(max(texels.row[i, k] + dr, 0), n - 1),
                                        min(max(texels.col[i, k] + dc, 0), n - 1)]) for dr in (-1, 0, 1) for dc in (-1, 0, 1)}
            tids = np.array(sorted(t for t in tids if t >= 0), dtype=np.int64)
            tids = tids[visibility._blocks(cover, tids, np.full(len(tids), cover.point_object[i]), np.tile(at.normals[i], (len(tids), 1)))]
            t, inside = cut_planes(np.tile(eyes[i, k], (len(tids), 1)), np.tile(u, (len(tids), 1)), tids, cover.planes)
            ahead = (t > 0) & (t < depth)
            one = bool((inside & ahead).any())
            missed = tids[ahead & ~inside & (cover.triangle_object[tids] != cover.point_object[i])]
            if not one and len(missed):
                one = bool(visibility._ring_search(cover, np.zeros(len(missed), dtype=np.int64), missed, eyes[i, k][None], u[None],
                                                   np.array([depth]))[0])
                rings += one
                # With a caster: whether the exact ray crosses any triangle of another object,
                # or of its own facing away (its own facing the point are passed).
                t_all, in_all = cut_planes(np.tile(eyes[i, k], (60, 1)), np.tile(u, (60, 1)), np.arange(60), cover.planes)
                crossed = np.flatnonzero(in_all & (t_all > 0) & (t_all < depth))
                by_cast[i, k] = visibility._blocks(cover, crossed, np.full(len(crossed), cover.point_object[i]),
                                                   np.tile(at.normals[i], (len(crossed), 1))).any()
                cast_decided += by_cast[i, k] != one
            else:
                by_cast[i, k] = one
            assert whole[i, k] == one
            found += one
        assert not whole[~ask].any()
        assert np.array_equal(visibility._covered(cast, at, eyes, texels, cell, ask), by_cast)
        rows = np.flatnonzero(rng.uniform(size=len(ask)) < 0.5)
        for one_cover in (cover, cast):
            sub = visibility._covered(one_cover.rows(rows), at[rows], eyes[rows], texels[rows], cell[rows], ~ask[rows])
            assert np.array_equal(visibility._any_covered(one_cover.rows(rows), at[rows], eyes[rows], texels[rows], cell[rows], ~ask[rows]),
                                  sub.any(axis=1))
    assert found > 50 and rings > 0 and cast_decided > 0  # both ways of being covered were met, and the rays differ from the rings


def test_a_triangles_box_is_its_corners_least_and_greatest():
    """geometry.corner_box gives numpy's own reduction over the corners, NaN and dtype kept."""
    from cubegi.cubegi_engine.geometry import corner_box

    corners = np.random.default_rng(2).normal(size=(500, 3, 3))
    corners[7, 1, 2] = np.nan
    for c in (corners, corners.astype(np.float32)):
        lo, hi = corner_box(c)
        assert lo.dtype == c.dtype and np.array_equal(lo, c.min(axis=1), equal_nan=True)
        assert np.array_equal(hi, c.max(axis=1), equal_nan=True) and np.isnan(lo[7, 2]) and (hi[:7] > lo[:7]).all()

def test_sorted_unique_and_membership():
    from cubegi.cubegi_engine.geometry import listed_ranks, sorted_unique
    from cubegi.cubegi_engine.visibility import _in_sorted

    keys = np.array([9, 3, 3, 7, 9, 1], dtype=np.int64)
    assert sorted_unique(keys).tolist() == [1, 3, 7, 9]
    assert sorted_unique(keys[:0]).tolist() == []
    runs = np.random.default_rng(3).integers(0, 50, 2000) + 100 * np.repeat(np.arange(40), 50)  # sorted runs, as pairs come
    assert np.array_equal(sorted_unique(runs), np.unique(runs))
    assert _in_sorted(np.array([0, 3, 8, 9, 10]), np.array([1, 3, 7, 9])).tolist() == [False, True, False, True, False]
    assert _in_sorted(np.array([2]), np.array([], dtype=np.int64)).tolist() == [False]
    # By flags: which keys occur, and each one's place among them (np.unique's inverse).
    listed, rank = listed_ranks(runs, 4000)
    assert np.array_equal(np.flatnonzero(listed), np.unique(runs))
    assert np.array_equal(rank[runs], np.unique(runs, return_inverse=True)[1].ravel())
    grid = keys.reshape(2, 3)
    assert np.array_equal(listed_ranks(grid, 10)[1][grid], [[3, 1, 1], [2, 3, 0]])


def test_cutting_many_rays_makes_each_triangles_plane_once_with_the_same_answer():
    from cubegi.cubegi_engine import geometry

    rng = np.random.default_rng(5)
    vertices = rng.random((50, 3))
    triangles = rng.integers(0, 50, (40, 3))
    origins, u = rng.random((30, 1, 3)), rng.normal(size=(30, 1, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    for tid in (rng.integers(-1, 40, (30, 9)), rng.integers(-1, 40, (3, 1))):  # many rays (shared planes), and few
        n = len(tid)
        t, inside = geometry.cut_triangles(origins[:n], u[:n], tid, triangles, vertices)
        want_t, want_inside = geometry.cut_planes(origins[:n], u[:n], tid, geometry.triangle_planes(triangles, vertices))
        assert np.array_equal(np.isnan(t), np.isnan(want_t)) and np.allclose(np.nan_to_num(t), np.nan_to_num(want_t), rtol=1e-12)
        assert np.array_equal(inside, want_inside) and np.isnan(t[tid < 0]).all()


def test_an_emitter_with_few_triangles_spreads_its_shadow_points_inside_them():
    from cubegi.cubegi_engine import emitters

    quad = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]], dtype=float)
    radiance = np.array([[1.0, 1.0, 1.0], [3.0, 3.0, 3.0]])  # the second sends 3x the power
    pts, nrm, tri = emitters._samples(quad, radiance, 16)
    assert len(pts) == 16 and len(np.unique(np.round(pts, 9), axis=0)) == 16
    np.testing.assert_allclose(nrm, np.broadcast_to([0, 0, 1], (16, 3)))
    first = pts[:, 0] >= pts[:, 1]  # the first triangle is x >= y
    assert first.sum() == 4 and (~first).sum() == 12
    np.testing.assert_array_equal(tri, np.where(first, 0, 1))  # each point's own triangle
    assert (pts[:, :2] >= 0).all() and (pts[:, :2] <= 1).all()


def test_a_subdivided_emitter_sends_what_its_triangles_send_one_by_one():
    """The flat-group form factor (the outline's edges where a receiver's plane does not cut
    the group) equals the sum over its triangles, for receivers in front of, behind, beside
    and cut by the panel; a tilted panel and a lone triangle form groups of their own."""
    from cubegi.cubegi_engine import emitters

    n = 6
    xs = np.linspace(-0.5, 0.5, n + 1)
    grid = np.stack(np.meshgrid(xs, xs, indexing="ij"), -1).reshape(-1, 2)
    verts = np.concatenate([grid, np.full((len(grid), 1), 1.0)], axis=1)
    ids = np.arange(len(grid)).reshape(n + 1, n + 1)
    tris = []
    for i in range(n):
        for j in range(n):
            tris += [(ids[i, j], ids[i + 1, j], ids[i + 1, j + 1]), (ids[i, j], ids[i + 1, j + 1], ids[i, j + 1])]
    tris = np.array(tris)
    rng = np.random.default_rng(5)
    points = rng.uniform(-1.5, 1.5, size=(400, 3))
    points[:, 2] = rng.uniform(-0.5, 2.5, size=400)
    normals = rng.normal(size=(400, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    normals[:100] = (0, 0, 1)  # facing it from below (and its back from above)
    tri_verts = verts[tris]
    want = sum(emitters._two_sided_ff(points, normals, t) for t in tri_verts)
    got = emitters._group_ff(points, normals, tris, tri_verts)
    heights = normals @ verts.T - np.einsum("sc,sc->s", normals, points)[:, None]
    cut = (heights.min(axis=1) < 0) & (heights.max(axis=1) > 0)
    assert cut.sum() > 50 and (~cut).sum() > 50 and (want > 0.01).sum() > 100
    np.testing.assert_allclose(got, np.minimum(want, 1.0), atol=1e-9)
    tilted = tri_verts[:1].copy()
    tilted[0, 0, 2] += 0.3
    both = np.concatenate([tri_verts, tilted])
    groups = emitters._flat_groups(both, np.ones((len(both), 3)), np.zeros(len(both), int), 2.0)
    assert sorted(len(g) for g in groups) == [1, len(tri_verts)]
    other = emitters._flat_groups(tri_verts, np.ones((len(tri_verts), 3)) * (np.arange(len(tri_verts)) % 2)[:, None] + 1,
                                  np.zeros(len(tri_verts), int), 2.0)
    assert sorted(len(g) for g in other) == [n * n, n * n]  # two radiances: two groups


def test_the_one_ray_kernel_cuts_as_moller_trumbore_and_leaves_grazing_rays_to_its_caller():
    """geometry.ray_cut against an independent Moller-Trumbore: the same distance and
    barycentrics wherever the ray is not within GRAZING of the plane, the front told from
    the back, and a triangle of no area never cut."""
    from cubegi.cubegi_engine.geometry import GRAZING, planes_of, ray_cut

    rng = np.random.default_rng(7)
    m = 2000
    a, b, c = (rng.normal(size=(m, 3)) for _ in range(3))
    o = rng.normal(size=(m, 3)) * 3.0
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, u, v, ok, front = ray_cut(o, d, planes_of(a, b, c))
    e1, e2 = b - a, c - a
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    s = o - a
    q = np.cross(s, e1)
    mt_u, mt_v, mt_t = np.einsum("ij,ij->i", s, p) / det, np.einsum("ij,ij->i", d, q) / det, np.einsum("ij,ij->i", e2, q) / det
    cos = np.abs(det) / np.linalg.norm(np.cross(e1, e2), axis=1)
    assert np.array_equal(ok, cos > GRAZING) and ok.sum() > 0.99 * m
    np.testing.assert_allclose(t[ok], mt_t[ok], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(np.stack([u, v])[:, ok], np.stack([mt_u, mt_v])[:, ok], rtol=1e-8, atol=1e-8)
    assert np.array_equal(front[ok], (det > 0)[ok]) and np.isnan(t[~ok]).all()  # det = -d . (e1 x e2)
    # A ray along the plane is left to the caller's tolerance; a degenerate triangle is never cut.
    flat = planes_of(np.zeros((1, 3)), np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    along = np.array([[1.0, np.sqrt(1 - 1e-8), 1e-4]]) / np.linalg.norm([1.0, np.sqrt(1 - 1e-8), 1e-4])
    assert not ray_cut(np.array([[0.2, 0.2, -1e-5]]), along, flat)[3][0]
    assert ray_cut(np.array([[0.2, 0.2, -1e-5]]), along, flat, grazing=0.0)[3][0]
    line = planes_of(np.zeros((1, 3)), np.array([[1.0, 0, 0]]), np.array([[2.0, 0, 0]]))
    assert not ray_cut(np.array([[0.5, 0, -1.0]]), np.array([[0.0, 0, 1.0]]), line, grazing=0.0)[3][0]


def test_points_interpolated_cell_by_cell_equal_point_by_point():
    """The probe light at points grouped by their 8 probes (one matrix product per cell,
    cubegi_engine.grid.points_by_cell) equals the per-point products; the weights read back
    in the points' order are the ones given; rows sharing their first and last probes but
    not the others are groups of their own; scattered probes are left ungrouped."""
    from cubegi.cubegi_engine.grid import CELL_POINTS, points_by_cell
    from cubegi.cubegi_engine.transport import Transport

    rng = np.random.default_rng(11)
    s, p = 6000, 60
    rows = np.stack([rng.choice(p, 8, replace=False) for _ in range(12)])
    rows[1, [0, -1]] = rows[0, [0, -1]]  # the same first and last probes as row 0
    index = rows[rng.integers(0, len(rows), s)]
    weight = rng.uniform(-0.1, 1.0, (s, 8)).astype(np.float32)
    basis = rng.uniform(-1.0, 1.0, (s, 9)).astype(np.float32)
    coeffs = rng.uniform(-0.2, 1.0, (p, 9, 3))
    plain = Transport.__new__(Transport)
    plain.index, plain._weight, plain._basis, plain._cells = index, weight.copy(), basis.copy(), None
    cells = points_by_cell(index)
    assert cells is not None and len(cells.probes) == len(rows) and cells.bounds[-1] == s
    for k in range(len(cells.probes)):
        assert (index[cells.order[cells.bounds[k]:cells.bounds[k + 1]]] == cells.probes[k]).all()
    grouped = Transport.__new__(Transport)
    grouped.index, grouped._weight, grouped._basis, grouped._cells = index, weight[cells.order], basis[cells.order], cells
    # Each point's light: its 8 probes' weights x its basis x their coefficients (float64).
    light = np.einsum("sp,sj,spjc->sc", weight.astype(np.float64), basis.astype(np.float64), coeffs[index])
    np.testing.assert_allclose(plain.interpolate(coeffs, clamp=False), light, rtol=1e-5, atol=1e-5)
    for clamp in (False, True):
        np.testing.assert_allclose(grouped.interpolate(coeffs, clamp), plain.interpolate(coeffs, clamp), rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(grouped.point_weights, (weight[:, :, None] * basis[:, None, :]).reshape(s, 72))
    some = rng.integers(0, s, 50)
    np.testing.assert_array_equal(grouped.probe_weights(some), plain.probe_weights(some))
    scattered = np.stack([rng.choice(p, 8, replace=False) for _ in range(s)])
    assert points_by_cell(scattered) is None and points_by_cell(index[: CELL_POINTS - 1]) is None


def test_the_points_no_probe_reaches_are_found_before_their_weights_are_made():
    """The covered points are found from the trilinear weights and the bases alone (so that
    the weights' (s, 72) array is made after the near field, the tables' high-water mark of
    memory): the same points as the made weights give, at the 1e-6 edge too."""
    from cubegi.cubegi_engine.transport import Transport, _no_weight

    rng = np.random.default_rng(13)
    s = 20000
    weight = rng.uniform(0.0, 1.0, (s, 8)) * (rng.uniform(0.0, 1.0, (s, 1)) < 0.5)
    edge = rng.integers(0, s, 4000)  # a largest product within a few roundings of 1e-6
    basis = rng.uniform(-1.0, 1.0, (s, 9))
    weight[edge] = 0.0
    weight[edge, 3] = 1e-6 / np.abs(basis[edge]).max(axis=1) * (1.0 + rng.uniform(-3e-7, 3e-7, len(edge)))
    transport = Transport.__new__(Transport)
    transport._cells, transport._weight, transport._basis = None, np.empty((s, 8), dtype=np.float32), np.empty((s, 9), dtype=np.float32)
    transport._put_weights(np.arange(s), weight, basis)
    made = transport._weightless()
    np.testing.assert_array_equal(_no_weight(weight, basis), made)
    assert 0 < made[edge].sum() < len(edge) and 0 < made.sum() < s  # both sides of the edge are met


def test_the_tail_step_through_a_simplified_capture_equals_the_gather_of_the_light_at_the_points():
    """The tail solve's step (Transport.linear_gather) with a simplified capture and the
    weights kept cell by cell (the light kept in the cells' order, sent to the clusters at
    once) equals the gather of the sent light interpolated at the points, per channel."""
    from cubegi.cubegi_engine.grid import points_by_cell
    from cubegi.cubegi_engine.proxy import CaptureProxy
    from cubegi.cubegi_engine.transport import DENSE_GATHER_ELEMENTS, Transport

    rng = np.random.default_rng(12)
    s, p, c, texels = 40000, 40, 300, 24
    rows = np.stack([rng.choice(p, 8, replace=False) for _ in range(9)])
    index = rows[rng.integers(0, len(rows), s)]
    weight = rng.uniform(-0.1, 1.0, (s, 8)).astype(np.float32)
    basis = rng.uniform(-1.0, 1.0, (s, 9)).astype(np.float32)
    coeffs = rng.uniform(-0.2, 1.0, (p, 9, 3))
    sent = rng.uniform(0.0, 0.9, (s, 3))
    cluster = rng.integers(0, c, s)
    share = rng.uniform(0.1, 1.0, s)
    share /= np.bincount(cluster, share, minlength=c)[cluster]
    cells = points_by_cell(index)
    assert cells is not None
    transport = Transport.__new__(Transport)
    transport.index, transport._weight, transport._basis, transport._cells = index, weight[cells.order], basis[cells.order], cells
    transport.proxy = CaptureProxy(np.zeros((c, 3)), np.zeros((0, 3), dtype=np.int64), cluster, share, None, np.zeros(1), 0)
    transport.corners = rng.integers(0, c, (p, texels, 3))
    transport.bary = rng.dirichlet(np.ones(3), (p, texels)).astype(np.float32)
    transport.sh_weights = rng.uniform(-1.0, 1.0, (texels, 9)).astype(np.float32)
    transport.probe_count, transport._dense = p, None
    assert 9 * transport.probe_count * s > DENSE_GATHER_ELEMENTS  # the texels' way, not the dense matrix
    want = transport.gather_project(sent * transport.interpolate(coeffs, clamp=False))
    got = transport.linear_gather(sent)(coeffs)
    assert got.shape == (p, 9, 3)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-4 * np.abs(want).max())
    assert np.ptp(want[..., 0] - want[..., 2]) > 0.1  # the channels differ


def test_a_curved_emitters_lone_triangles_give_lamberts_light_near_and_far():
    """A glowing ball's triangles are each a flat group of one: their light, summed at once
    (far ones as small patches, near ones by Lambert's formula, the ones wholly behind a
    point's tangent plane left out), is the per-triangle exact sum within the far patches'
    error (FAR_RADII), and exactly it where every triangle is near."""
    from cubegi.cubegi_engine import emitters

    rng = np.random.default_rng(11)
    # An icosphere-like ball: random points on a sphere of radius 0.2, triangulated as a fan strip.
    theta = np.linspace(0.2, np.pi - 0.2, 9)
    phi = np.linspace(0, 2 * np.pi, 13)[:-1]
    ring = np.stack([np.sin(theta)[:, None] * np.cos(phi), np.sin(theta)[:, None] * np.sin(phi),
                     np.cos(theta)[:, None] * np.ones_like(phi)], axis=-1) * 0.2
    tris = []
    for i in range(len(theta) - 1):
        for j in range(len(phi)):
            a, b, c, d = ring[i, j], ring[i, (j + 1) % len(phi)], ring[i + 1, j], ring[i + 1, (j + 1) % len(phi)]
            tris += [(a, c, b), (b, c, d)]
    verts = np.array(tris)
    radiance = rng.uniform(0.5, 2.0, (len(verts), 3))
    # Receivers: a floor and walls at 0.25-3 m, facing the ball, and points on the ball itself.
    far = rng.uniform(-3, 3, (300, 3))
    far *= np.clip(np.linalg.norm(far, axis=1, keepdims=True), 0.25, None) / np.linalg.norm(far, axis=1, keepdims=True)
    normals = -far / np.linalg.norm(far, axis=1, keepdims=True) + rng.normal(scale=0.4, size=far.shape)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    on = ring[2:6, :4].reshape(-1, 3) * 1.0001
    points = np.concatenate([far, on])
    normals = np.concatenate([normals, on / np.linalg.norm(on, axis=1, keepdims=True)])
    exact = sum(emitters._two_sided_ff(points, normals, tri)[:, None] * r for tri, r in zip(verts, radiance))
    fast = emitters._lone_ff(points, normals, verts, radiance)
    assert exact[:300].max() > 1e-3 and np.all(np.isfinite(fast))
    np.testing.assert_allclose(fast, exact, rtol=0.01, atol=1e-6 * exact.max())
    np.testing.assert_allclose(fast[300:], exact[300:], atol=1e-12)  # a convex ball's own points: none of its light
    # Every triangle near (a far threshold past the room): Lambert's formula throughout, the same sums.
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(emitters, "FAR_RADII", 1e6)
        np.testing.assert_allclose(emitters._lone_ff(points, normals, verts, radiance), exact, rtol=1e-12, atol=1e-15)


def test_a_sheets_twin_is_the_triangle_over_the_same_positions_wound_the_other_way():
    """Twins found by hashed positions are those a brute-force search finds: over the same
    three positions (copies, not shared vertices), wound the other way; not a copy wound the
    same way, not one of three over the same positions, not a triangle outside the sheets.
    Alike whether each position or each corner is hashed (few or many points per sheet)."""
    from cubegi.cubegi_engine.geometry import twin_triangles

    rng = np.random.default_rng(11)
    grid = rng.integers(0, 4, (30, 3)).astype(np.float32)  # few distinct positions: many near misses
    base = np.array([c for c in rng.integers(0, 30, (200, 3)) if len(set(c)) == 3][:60])
    turned = base[:, [0, 2, 1]]  # wound the other way
    same = base[:10]  # wound the same way: not a twin
    rolled = np.roll(base[10:20, ::-1], 1, axis=1)  # the other way, starting elsewhere: a twin
    tri = np.concatenate([base, turned[:40], same, rolled, turned[45:50], turned[45:50]])  # 45-49: three over one place
    points = np.concatenate([grid, grid[tri.ravel()]])  # each corner a copy of its position
    tri = (30 + np.arange(tri.size)).reshape(-1, 3)
    sheet = rng.uniform(size=len(tri)) < 0.9

    def brute(points):
        out = np.full(len(tri), -1)
        key = [tuple(map(tuple, points[t])) for t in tri]
        for i in np.flatnonzero(sheet):
            found = [j for j in np.flatnonzero(sheet) if j != i and sorted(key[j]) == sorted(key[i])]
            turn = [j for j in found if any(key[j] == (key[i][(k + 2) % 3], key[i][(k + 1) % 3], key[i][k]) for k in range(3))]
            if len(found) == 1 and len(turn) == 1:
                out[i] = turn[0]
        return out

    expected = brute(points)
    assert (expected >= 0).sum() >= 40 and (expected[:40] < 0).any()
    assert np.array_equal(twin_triangles(points, tri, sheet), expected)  # each corner hashed (points > 3 x sheets)
    compact = grid  # each position once, shared by the corners: each position hashed
    shared = np.concatenate([base, turned[:40], same, rolled, turned[45:50], turned[45:50]])
    assert np.array_equal(twin_triangles(compact, shared, sheet), expected)


def test_box_tests_a_coordinate_at_a_time_agree_with_numpys_all():
    """geometry.in_box and all_three give what np.all over the last axis gives: points (NaN
    among them) in boxes, bounds included, broadcast pairwise, and integer lattices."""
    rng = np.random.default_rng(7)
    x = rng.random((500, 3))
    x[::50, 1] = np.nan
    x[1] = (0.2, 0.5, 0.8)  # on the bounds
    lo, hi = np.array([0.2, 0.1, 0.3]), np.array([0.9, 0.5, 0.8])
    want = np.all((x >= lo) & (x <= hi), axis=1)
    assert want.any() and not want.all() and want[1]
    np.testing.assert_array_equal(in_box(x, lo, hi), want)
    blo = rng.random((40, 3)) * 0.8
    bhi = blo + 0.3
    pairs = np.all((x[:, None, :] >= blo[None]) & (x[:, None, :] <= bhi[None]), axis=2)
    np.testing.assert_array_equal(in_box(x[:, None, :], blo[None], bhi[None]), pairs)
    ijk = rng.integers(-2, 6, size=(300, 3))
    shape = np.array([4, 5, 3])
    np.testing.assert_array_equal(in_box(ijk, np.zeros(3, dtype=np.int64), shape - 1), np.all((ijk >= 0) & (ijk < shape), axis=1))
    np.testing.assert_array_equal(all_three(ijk >= 0), np.all(ijk >= 0, axis=-1))
