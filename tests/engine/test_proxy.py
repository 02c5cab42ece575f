"""The probes' simplified copy of the scene (pure numpy): the budget, the bound on how far
surfaces move, thin parts kept apart, nothing turned over, radiance averaged by area."""

from dataclasses import replace

import numpy as np
import pytest

from cubegi.cubegi_engine import crossing, cubemap
from cubegi.cubegi_engine.capture import RayCubes
from cubegi.cubegi_engine.proxy import CONTACT_LEVELS, KEEP_WHOLE, CaptureProxy, simplify
from cubegi.cubegi_engine.rays import NumpyRays
from cubegi.cubegi_engine.scene import SceneArrays


def _plane(origin, u, v, n, flip=False):
    """A grid of (n+1)^2 points and 2 n^2 triangles over origin + a u + b v."""
    a, b = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    pts = np.asarray(origin) + a.reshape(-1, 1) * np.asarray(u) + b.reshape(-1, 1) * np.asarray(v)
    k = np.arange(n + 1)
    i, j = np.meshgrid(k[:-1], k[:-1], indexing="ij")
    c = (i * (n + 1) + j).ravel()
    tris = np.concatenate([np.stack([c, c + n + 1, c + n + 2], 1), np.stack([c, c + n + 2, c + 1], 1)])
    if flip:
        tris = tris[:, ::-1]
    normal = np.cross(u, v)
    normal = normal / np.linalg.norm(normal) * (-1 if flip else 1)
    return pts, tris, np.tile(normal, (len(pts), 1))


def _scene(parts):
    """SceneArrays of [(object index, (points, triangles, normals)), ...]."""
    pts, tris, nrm, owner, off = [], [], [], [], 0
    for obj, (p, t, n) in parts:
        pts.append(p)
        tris.append(t + off)
        nrm.append(n)
        owner.append(np.full(len(p), obj))
        off += len(p)
    count = max(o for o, _ in parts) + 1
    s = off
    return SceneArrays(np.concatenate(pts), np.concatenate(nrm), np.full((s, 3), 0.5), np.zeros((s, 3)), np.concatenate(tris),
                       point_object=np.concatenate(owner), object_names=[f"o{k}" for k in range(count)])


def _thin_wall_and_floor(n=60):
    """Object 0: a 2 m wall of two faces 1 cm apart facing away from each other, finely
    tessellated; object 1: a floor of two triangles (kept whole)."""
    front = _plane((0.0, 0.0, 0.0), (0, 2.0, 0), (0, 0, 2.0), n)  # normal +X
    back = _plane((-0.01, 0.0, 0.0), (0, 2.0, 0), (0, 0, 2.0), n, flip=True)  # normal -X
    floor = _plane((-2.0, 0.0, 0.0), (4.0, 0, 0), (0, 2.0, 0), 1)
    return _scene([(0, front), (0, back), (1, floor)])


def _normals(v, t):
    x = v[t]
    return np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])


def test_no_proxy_at_or_below_the_budget():
    scene = _thin_wall_and_floor(n=10)
    assert simplify(scene, len(scene.triangles)) is None
    assert simplify(scene, None) is None


@pytest.mark.parametrize("budget", [4000, 8000])
def test_the_budget_and_the_bound_hold_and_the_wall_keeps_two_faces(budget):
    scene = _thin_wall_and_floor()
    proxy = simplify(scene, budget)
    assert proxy is not None and len(proxy.triangles) <= 1.1 * budget < len(scene.triangles)
    # Every point lies within the stated bound of its cluster's centre.
    offset = np.linalg.norm(scene.points - proxy.points[proxy.cluster], axis=1)
    assert offset.max() <= proxy.max_offset() + 1e-12
    # The floor (two triangles) is kept whole: its points are their own clusters.
    floor = scene.point_object == 1
    assert len(np.unique(proxy.cluster[floor])) == floor.sum() and proxy.cell[1] == 0
    assert (proxy.triangle_object == 1).sum() == 2
    # The wall's two faces stay apart: no cluster mixes them, and every proxy triangle of
    # each face still faces that face's way (nothing turned over, no slab collapsed).
    wall = proxy.triangle_object == 0
    front = scene.normals[:, 0] > 0.5
    assert not np.intersect1d(proxy.cluster[front & ~floor], proxy.cluster[~front & ~floor]).size
    nx = _normals(proxy.points, proxy.triangles[wall])[:, 0]
    side = proxy.points[proxy.triangles[wall]][:, :, 0].mean(axis=1) > -0.005
    assert np.all(nx[side] > 0) and np.all(nx[~side] < 0) and side.any() and (~side).any()


def test_each_object_keeps_the_same_share_of_its_triangles():
    big = _plane((0, 0, 0), (4.0, 0, 0), (0, 4.0, 0), 80)  # 12,800 triangles
    small = _plane((0, 0, 1.0), (1.0, 0, 0), (0, 1.0, 0), 20)  # 800 triangles
    scene = _scene([(0, big), (1, small)])
    proxy = simplify(scene, 2000)
    share = [(proxy.triangle_object == k).sum() / (scene.point_object[scene.triangles[:, 0]] == k).sum() for k in (0, 1)]
    assert 0.5 < share[0] / share[1] < 2.0, share
    assert KEEP_WHOLE < 800  # the small one was simplified too


def test_radiance_is_the_area_weighted_mean_and_the_matrix_agrees():
    scene = _thin_wall_and_floor(n=40)
    proxy = simplify(scene, 800)
    rng = np.random.default_rng(0)
    # A constant radiance stays that constant on every cluster.
    np.testing.assert_allclose(proxy.radiance(np.full((len(scene.points), 3), 0.7)), 0.7, rtol=1e-6)
    r = rng.uniform(0, 1, (len(scene.points), 3))
    per_cluster = proxy.radiance(r)
    areas = scene.point_areas()
    k = proxy.cluster[0]
    members = proxy.cluster == k
    np.testing.assert_allclose(per_cluster[k], (areas[members, None] * r[members]).sum(0) / areas[members].sum(), rtol=1e-5)
    # A matrix over clusters, expanded to points, gives the same product.
    m = rng.normal(size=(5, proxy.count))
    np.testing.assert_allclose(proxy.expand_columns(m) @ r, m @ per_cluster.astype(np.float64), rtol=1e-5, atol=1e-6)


def test_a_dense_floor_under_a_thin_wall_is_not_averaged_across_it():
    """A dense floor runs under a 2 cm wall (another object): no floor cluster takes in
    points from both sides of the wall (light from a lit room would reach a dark one), and
    the wall's faces still reach down to the floor."""
    front = _plane((0.0, 0.0, 0.0), (0, 2.0, 0), (0, 0, 2.0), 40)
    back = _plane((-0.02, 0.0, 0.0), (0, 2.0, 0), (0, 0, 2.0), 40, flip=True)
    floor = _plane((-2.0, 0.0, 0.0), (4.0, 0, 0), (0, 2.0, 0), 80)  # 12,800 triangles
    scene = _scene([(0, front), (0, back), (1, floor)])
    proxy = simplify(scene, 3000)
    assert proxy is not None and proxy.cell[1] > 0.05  # cells far wider than the wall
    on_floor = scene.point_object == 1
    left = on_floor & (scene.points[:, 0] < -0.02)
    right = on_floor & (scene.points[:, 0] > 0.0)
    assert not np.intersect1d(proxy.cluster[left], proxy.cluster[right]).size
    wall = proxy.points[proxy.triangles[proxy.triangle_object == 0]].reshape(-1, 3)
    assert wall[:, 2].min() == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("thickness, pegs", [(0.02, False), (0.005, False), (0.005, True)])
def test_the_finest_cells_a_wall_crosses_are_clustered_on_each_side_of_it(thickness, pegs):
    """A cell of the floor that the wall crosses is halved CONTACT_LEVELS times, and its
    finest halves are clustered on each side of the wall apart, even where they are wider
    than the wall, and where other objects cross them too (small pegs at the wall's foot,
    facing along it, listed first: split by the first crossing point's plane alone, 41 floor
    clusters took in both sides): the budget holds (the floor's points kept as they were
    took 150 triangles to 2,694), no floor cluster takes in points from both sides of the
    wall, the floor's clusters under the wall are of halved cells, and the floor still
    reaches the wall on both sides (no slit under it)."""
    parts = []
    for k, y in enumerate(np.arange(0.0, 1.0, 0.02) if pegs else ()):
        corners = np.array([[-0.002, y, -0.002], [0.002, y, -0.002], [0.0, y, 0.002]])
        parts.append((2 + k, (corners, np.array([[0, 1, 2]]), np.tile([0.0, 1.0, 0.0], (3, 1)))))
    front = _plane((0.0, 0.0, 0.0), (0, 1.0, 0), (0, 0, 1.0), 20)
    back = _plane((-thickness, 0.0, 0.0), (0, 1.0, 0), (0, 0, 1.0), 20, flip=True)
    floor = _plane((-1.0, 0.0, 0.0), (2.0, 0, 0), (0, 1.0, 0), 200)  # 1 cm apart: 80,000 triangles
    scene = _scene(parts + [(0, front), (0, back), (1, floor)])
    budget = 150 + len(parts)  # (the pegs are kept whole)
    proxy = simplify(scene, budget)
    # (Each peg splits the floor's cells it crosses: 270 triangles drawn for 200 there.)
    assert len(proxy.triangles) <= (1.5 if pegs else 1.1) * budget
    finest = proxy.cell[1] / 2**CONTACT_LEVELS
    assert finest > 2.0 * thickness  # the finest cells are wider than the wall
    on_floor = scene.point_object == 1
    x = scene.points[:, 0]
    left, right = on_floor & (x < -thickness), on_floor & (x > 0.0)
    assert not np.intersect1d(proxy.cluster[left], proxy.cluster[right]).size
    at_wall = np.unique(proxy.cluster[on_floor & (x >= -thickness) & (x <= 0.0)])
    spread = np.array([np.ptp(x[proxy.cluster == k]) for k in at_wall])
    assert len(at_wall) and spread.max() <= 0.5 * proxy.cell[1]  # halved at least once
    floor_points = proxy.points[np.unique(proxy.triangles[proxy.triangle_object == 1])]
    assert np.any((floor_points[:, 0] < -thickness) & (floor_points[:, 0] > -thickness - finest))
    assert np.any((floor_points[:, 0] > 0.0) & (floor_points[:, 0] < finest))


# Three small upright triangles through the floor near the wall (each smaller than a floor
# cell: one that crosses a cell with no corner in it has its corners in the cells around).
PEGS = [[[-0.09, 0.531, 0.017], [-0.023, 0.483, 0.017], [-0.056, 0.507, 0.096]],
        [[-0.261, 0.165, -0.078], [-0.168, 0.283, -0.078], [-0.215, 0.224, 0.042]],
        [[-0.246, 0.319, -0.014], [-0.129, 0.465, -0.014], [-0.187, 0.392, 0.128]]]


@pytest.mark.parametrize("leaning", ["board", "pegs"])
def test_finer_cells_ask_only_what_crossed_the_coarser_ones(monkeypatch, leaning):
    """The halves of a crossed cell are tested against only the points and triangles that
    could cross them (those of the crossed cells and the cells around them, and the
    triangles larger than a half): the same clusters as testing every other object again."""

    front = _plane((0.0, 0.0, 0.0), (0, 1.0, 0), (0, 0, 1.0), 20)
    back = _plane((-0.02, 0.0, 0.0), (0, 1.0, 0), (0, 0, 1.0), 20, flip=True)
    floor = _plane((-1.0, 0.0, 0.0), (2.0, 0, 0), (0, 1.0, 0), 120)
    parts = [(0, front), (0, back), (1, floor)]
    if leaning == "board":  # a tilted board leaning on the wall, across the floor's cells
        parts.append((2, _plane((0.3, 0.0, 0.0), (-0.25, 0, 0.6), (0, 0.8, 0), 6)))
    else:
        for k, corners in enumerate(np.array(PEGS)):
            normal = np.cross(corners[1] - corners[0], corners[2] - corners[0])
            parts.append((2 + k, (corners, np.array([[0, 1, 2]]), np.tile(normal / np.linalg.norm(normal), (3, 1)))))
    scene = _scene(parts)
    pruned = simplify(scene, 150)
    contact = crossing.contact
    monkeypatch.setattr(crossing, "contact", lambda prep, cell, ijk, which=None, within=None, **kw: contact(prep, cell, ijk, which, **kw))
    every = simplify(scene, 150)
    assert np.array_equal(pruned.cluster, every.cluster) and np.array_equal(pruned.triangles, every.triangles)
    assert len(np.unique(pruned.cluster[scene.point_object == 1])) < (scene.point_object == 1).sum() / 4


def test_a_triangle_past_an_objects_last_points_is_asked_by_the_finer_cells(monkeypatch):
    """A cell at the edge of a floor, crossed (by a pin), and an upright triangle no larger
    than a cell whose corners all lie past the floor's last points: it crosses a half of that
    cell, and the halves' pruned candidates include it (the same clusters as asking every
    other object)."""
    from cubegi.cubegi_engine import proxy as proxy_mod

    floor = _plane((0.0, 0.0, 0.0), (1.0, 0, 0), (0, 1.0, 0), 100)
    pin = np.array([[0.999, 0.5, 0.0005], [0.999, 0.501, 0.0005], [0.999, 0.5, 0.0015]])
    h = 0.08
    upright = np.array([[1.0 + 1.01 * h, 0.51, 0.01 * h], [1.0 + 0.02 * h, 0.51, 1.01 * h], [1.0 + 1.01 * h, 0.51 + 0.5 * h, 1.01 * h]])
    parts = [(0, floor), (1, (pin, np.array([[0, 1, 2]]), np.tile([1.0, 0, 0], (3, 1))))]
    normal = np.cross(upright[1] - upright[0], upright[2] - upright[0])
    parts.append((2, (upright, np.array([[0, 1, 2]]), np.tile(normal / np.linalg.norm(normal), (3, 1)))))
    scene = _scene(parts)
    prep = crossing.Prepared(scene.points, scene.normals, scene.triangles, scene.point_object, 3, np.ones(len(scene.points)))
    assert prep.tri_extent[-1] <= h and np.all(upright[:, 0] > scene.points[scene.point_object == 0, 0].max())
    cell = np.array([h, 0.0, 0.0])  # the floor clustered 8 cm wide, the others kept whole
    pruned = proxy_mod._cluster(prep, cell)
    contact = crossing.contact
    monkeypatch.setattr(crossing, "contact", lambda prep, cell, ijk, which=None, within=None, **kw: contact(prep, cell, ijk, which, **kw))
    every = proxy_mod._cluster(prep, cell)
    assert np.array_equal(pruned.cluster, every.cluster)


def test_near_any_triangle_is_conservative():
    from cubegi.cubegi_engine.geometry import near_any_triangle

    rng = np.random.default_rng(5)
    # Equilateral triangles (edge 1), turned at random: the test is conservative, and near a
    # sharp corner it takes in more than the true distance, so the bound below is for
    # well-shaped ones.
    q, _ = np.linalg.qr(rng.normal(size=(20, 3, 3)))
    shape = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, np.sqrt(0.75), 0.0]])
    corners = rng.uniform(-1, 1, (20, 1, 3)) + np.einsum("tij,kj->tki", q, shape)
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    pts = rng.uniform(-1.5, 1.5, (1500, 3))
    r = 0.15
    got = near_any_triangle(pts, r, a, b, c, tiles=5)
    assert np.array_equal(got, near_any_triangle(pts, r, a, b, c, tiles=1))  # each tile gets every triangle near it
    # Asked for it, the least index of a triangle near each point (-1: none), as one by one.
    alone = np.stack([near_any_triangle(pts, r, a[k:k + 1], b[k:k + 1], c[k:k + 1]) for k in range(len(a))], axis=1)
    _, least = near_any_triangle(pts, r, a, b, c, tiles=5, least=True)
    assert np.array_equal(least, np.where(alone.any(axis=1), np.argmax(alone, axis=1), -1))
    # Distances by dense sampling of each triangle (an upper bound on the true distance).
    u, v = np.meshgrid(np.linspace(0, 1, 41), np.linspace(0, 1, 41))
    inside = (u + v) <= 1
    w = np.stack([1 - u[inside] - v[inside], u[inside], v[inside]], axis=1)  # (q, 3)
    samples = (w[None, :, 0, None] * a[:, None] + w[None, :, 1, None] * b[:, None] + w[None, :, 2, None] * c[:, None]).reshape(-1, 3)
    d = np.min(np.linalg.norm(pts[:, None, :] - samples[None, :, :], axis=2), axis=1)
    step = 1.0 / 40  # sampling spacing on edges of length 1
    assert got[d <= r - step].all()  # everything truly near is found
    assert not got[d > 3 * r + step].any()  # nothing far is
    assert got.any() and not got.all()


def test_triangles_a_cut_added_neither_shrink_the_budget_nor_unkeep_a_whole_object():
    """A floor of two triangles cut into 800 for the bake (its light sampled finely) is still
    kept whole, and the rest of the scene is simplified as much as it was before the cut."""
    dense = _plane((0, 0, 1.0), (1.0, 0, 0), (0, 1.0, 0), 40)  # 3,200 triangles
    as_modelled = _scene([(0, dense), (1, _plane((-2.0, -2.0, 0), (4.0, 0, 0), (0, 4.0, 0), 1))])
    cut = _scene([(0, dense), (1, _plane((-2.0, -2.0, 0), (4.0, 0, 0), (0, 4.0, 0), 20))])  # the floor cut 20 x 20
    before = simplify(as_modelled, 1000)
    assert before is not None and before.cell[1] == 0
    # Counted as modelled, the cut floor (800 triangles, over KEEP_WHOLE) would be simplified,
    # and would take 800 of the budget's triangles from the dense object.
    unmarked = simplify(cut, 1000)
    assert unmarked.cell[1] > 0
    cut.sampled_triangles = np.array([0, 798])
    after = simplify(cut, 1000)
    assert after.cell[1] == 0 and (after.triangle_object == 1).sum() == 800
    assert (after.triangle_object == 0).sum() == (before.triangle_object == 0).sum()
    assert after.cell[0] == pytest.approx(before.cell[0])


def _sheet_and_box(n=50):
    """Object 0: a two-sided sheet (its points, then their twins facing the other way, its
    triangles, then theirs reversed); object 1: a one-sided plane below it, as fine."""
    p, t, nrm = _plane((0, 0, 1.0), (2.0, 0, 0), (0, 2.0, 0), n)
    sheet = (np.concatenate([p, p]), np.concatenate([t, t[:, ::-1] + len(p)]), np.concatenate([nrm, -nrm]))
    floor = _plane((0, 0, 0), (2.0, 0, 0), (0, 2.0, 0), n)
    scene = _scene([(0, sheet), (1, floor)])
    back = np.zeros(len(scene.points), dtype=bool)
    back[len(p):2 * len(p)] = True
    scene.back = back
    return scene


def test_a_sheets_back_side_is_drawn_within_the_budget():
    """Both sides of a two-sided sheet count in the budget: the front is simplified to its
    share, so that its twins take the rest (the twins were drawn beyond it: 138K triangles
    for a budget of 100K at a million vertices)."""
    scene = _sheet_and_box()
    assert scene.sheets() is not None
    budget = 3000
    proxy = simplify(scene, budget)
    assert proxy is not None and len(proxy.triangles) <= 1.1 * budget
    sheet = proxy.triangle_object == 0
    assert sheet.sum() % 2 == 0 and sheet.sum() > 0.3 * budget  # its twins are there, and it kept its share


def test_rounds_that_no_longer_take_triangles_off_stop(monkeypatch):
    """Where wider cells stop taking triangles off (objects that touch keep their contact
    points), a round that takes off less than STALL of them is the last, and the fewest
    seen is kept."""
    from cubegi.cubegi_engine import proxy as proxy_module

    scene = _thin_wall_and_floor()
    made, counts = [], iter([9000, 8900, 8400, 9100])
    real = proxy_module._cluster

    def cluster(prep, cell, contact=True):
        out = real(prep, cell, contact)
        if not contact:  # (the searches for the next edge)
            return out
        made.append(cell.copy())
        return proxy_module.CaptureProxy(out.points, np.zeros((next(counts), 3), dtype=np.int64), out.cluster, out.share,
                                         np.zeros(0, dtype=np.int64), out.cell, out.source_triangles)

    monkeypatch.setattr(proxy_module, "_cluster", cluster)
    proxy = simplify(scene, 4000)
    assert len(made) == 2 and len(proxy.triangles) == 8900
    assert np.all(made[1][made[0] > 0] > made[0][made[0] > 0])  # the second round's cells were wider


def test_the_stall_is_judged_on_the_triangles_a_round_can_take_off(monkeypatch):
    """Objects kept whole are in every round's count: a round that takes a sixth of the rest
    off goes on, though the whole count falls by 6%; one that takes 2% off is the last."""
    from cubegi.cubegi_engine import proxy as proxy_module

    smalls = [(k + 1, _plane((3.0 * k, 5.0, 0.0), (1.0, 0, 0), (0, 1.0, 0), 5)) for k in range(200)]  # 50 triangles each
    scene = _scene([(0, _plane((0, 0, 0), (4.0, 0, 0), (0, 4.0, 0), 80))] + smalls)
    kept = 200 * 50
    made, counts = [], iter([kept + 6000, kept + 5000, kept + 4900, kept + 100])
    real = proxy_module._cluster

    def cluster(prep, cell, contact=True):
        out = real(prep, cell, contact)
        if not contact:  # (the searches for the next edge)
            return out
        made.append(1)
        return proxy_module.CaptureProxy(out.points, np.zeros((next(counts), 3), dtype=np.int64), out.cluster, out.share,
                                         np.zeros(0, dtype=np.int64), out.cell, out.source_triangles)

    monkeypatch.setattr(proxy_module, "_cluster", cluster)
    proxy = simplify(scene, kept + 2000)
    assert len(made) == 3 and len(proxy.triangles) == kept + 4900


def test_a_sheets_share_of_the_budget_is_of_its_triangles_as_modelled():
    """A sheet modelled as 2 triangles and cut into 20,000 for its light takes the share of
    its 2, not of its 20,000, beside a one-sided mesh of 100,000: the mesh keeps the budget."""
    from types import SimpleNamespace

    from cubegi.cubegi_engine.proxy import _front_budget

    owner = np.concatenate([np.zeros(20_000, dtype=np.int64), np.ones(100_000, dtype=np.int64)])
    front = SimpleNamespace(triangles=np.stack([np.arange(len(owner))] * 3, axis=1), point_object=owner,
                            sampled_triangles=np.array([19_998, 0]))
    two_sided = np.array([True, False])
    assert _front_budget(50_000, front, two_sided) == round(50_000 / (1 + 2 / 100_002))
    front.sampled_triangles = None
    assert _front_budget(50_000, front, two_sided) == round(50_000 / (1 + 20_000 / 120_000))
    assert _front_budget(None, front, two_sided) is None


def test_a_closed_bake_stops_its_simplification_at_the_next_round(monkeypatch):
    """The simplification runs in a thread while the bake goes on; closed (a cancel), the
    bake stops it before its next round and in each round before the next object's cells
    (it takes two rounds here, seconds at a million vertices)."""
    import time

    from cubegi.cubegi_engine import proxy as proxy_mod
    from cubegi.cubegi_engine import working

    rounds, cluster = [], proxy_mod._cluster

    def slow(prep, cell, contact=True):
        out = cluster(prep, cell, contact)
        if contact:  # (a round, not a search for the next edge)
            rounds.append(cell.copy())
            time.sleep(0.3)
        return out

    monkeypatch.setattr(proxy_mod, "_cluster", slow)
    front = _plane((0.0, 0.0, 0.0), (0, 1.0, 0), (0, 0, 1.0), 20)
    back = _plane((-0.005, 0.0, 0.0), (0, 1.0, 0), (0, 0, 1.0), 20, flip=True)
    floor = _plane((-1.0, 0.0, 0.0), (2.0, 0, 0), (0, 1.0, 0), 200)
    scene = _scene([(0, front), (0, back), (1, floor)])
    assert simplify(scene, 150) is not None and len(rounds) >= 2
    rounds.clear()
    driven = working.Driven(working.in_background(simplify, None, scene, 150))
    driven.next()
    while not rounds:
        time.sleep(0.01)
    driven.close()
    time.sleep(1.0)
    assert len(rounds) == 1


def test_the_next_rounds_edge_is_searched_without_the_touching_cells(monkeypatch):
    """A sheet standing on a dense floor, at a budget its touching cells leave room in: those
    cells are clustered finer and their triangles barely fall as the cells widen, so the
    second round's edge is found by rounds that leave them out (cheap), their triangles
    counted as the first round found them. Two full rounds land within the budget (widening
    by the whole count's fall took three). Where the touching cells hold most of the budget
    (150), the rounds widen by the whole count's fall, as before: no search."""
    from cubegi.cubegi_engine import proxy as proxy_mod

    rounds, searches, cluster = [], [], proxy_mod._cluster

    def counted(prep, cell, contact=True):
        (rounds if contact else searches).append(cell.copy())
        return cluster(prep, cell, contact)

    monkeypatch.setattr(proxy_mod, "_cluster", counted)
    front = _plane((0.0, 0.0, 0.0), (0, 1.0, 0), (0, 0, 1.0), 20)
    back = _plane((-0.005, 0.0, 0.0), (0, 1.0, 0), (0, 0, 1.0), 20, flip=True)
    floor = _plane((-1.0, 0.0, 0.0), (2.0, 0, 0), (0, 1.0, 0), 200)
    scene = _scene([(0, front), (0, back), (1, floor)])
    budget = 2000
    proxy = simplify(scene, budget)
    assert len(rounds) == 2 and 0.7 * budget <= len(proxy.triangles) <= 1.1 * budget
    assert len(searches) >= 2  # the first round's count without the touching cells, then the search
    assert np.all(rounds[1][rounds[0] > 0] > rounds[0][rounds[0] > 0])  # wider
    searched = [c for c in searches[1:] if np.allclose(c, rounds[1])]
    assert searched  # the second round took an edge the search tried

    rounds.clear(), searches.clear()
    simplify(scene, 150)
    steps = [b[1] / a[1] for a, b in zip(rounds, rounds[1:])]
    assert len(rounds) >= 2 and len(searches) == len(rounds) - 1  # each round's count without the touching cells alone
    assert all(s > 1.0 for s in steps)


def test_a_round_that_only_counts_keeps_its_clusters_at_their_means():
    """The search's rounds (without the touching cells) only count triangles: their clusters
    stay at their points' area-weighted means, where a full round places them on the planes
    of their points (a cell where an object's wall meets its floor: on the edge)."""
    from cubegi.cubegi_engine import proxy as proxy_mod

    scene = _scene([(0, _plane((0.0, 0.0, 0.0), (0, 1.0, 0), (0, 0, 1.0), 20)),
                    (0, _plane((0.0, 0.0, 0.0), (1.0, 0, 0), (0, 1.0, 0), 20))])  # one object: a wall on its floor's edge
    prep = crossing.Prepared(np.asarray(scene.points, dtype=np.float64), np.asarray(scene.normals, dtype=np.float64),
                             scene.triangles, scene.point_object, 1, scene.point_areas())
    cell = np.array([0.3])
    counted = proxy_mod._cluster(prep, cell, contact=False)
    means = np.stack([np.bincount(counted.cluster, scene.points[:, a] * counted.share) for a in range(3)], axis=1)
    assert np.allclose(counted.points, means)
    placed = proxy_mod._cluster(prep, cell)
    full_means = np.stack([np.bincount(placed.cluster, scene.points[:, a] * placed.share) for a in range(3)], axis=1)
    assert not np.allclose(placed.points, full_means)  # a full round moves some onto their planes


def test_the_last_round_asks_no_edge_for_a_round_that_never_comes(monkeypatch):
    """Past its last round (ROUNDS) the simplification keeps the fewest it found, without the
    counting rounds that would find a next round's edge (seconds at a million points)."""
    from cubegi.cubegi_engine import proxy as proxy_mod

    rounds, searches, cluster = [], [], proxy_mod._cluster

    def counted(prep, cell, contact=True):
        (rounds if contact else searches).append(cell.copy())
        return cluster(prep, cell, contact)

    monkeypatch.setattr(proxy_mod, "_cluster", counted)
    monkeypatch.setattr(proxy_mod, "ROUNDS", 2)
    front = _plane((0.0, 0.0, 0.0), (0, 1.0, 0), (0, 0, 1.0), 20)
    back = _plane((-0.005, 0.0, 0.0), (0, 1.0, 0), (0, 0, 1.0), 20, flip=True)
    floor = _plane((-1.0, 0.0, 0.0), (2.0, 0, 0), (0, 1.0, 0), 200)
    scene = _scene([(0, front), (0, back), (1, floor)])
    proxy = simplify(scene, 20)  # a budget two rounds do not reach
    assert proxy is not None and len(proxy.triangles) > 1.1 * 20
    assert len(rounds) == 2 and len(searches) == 1  # after the first round only


def _casting(points, triangles, sheet=None):
    return RayCubes.of(NumpyRays, points, triangles, sheet=sheet)


def test_cast_cube_maps_see_the_nearest_side_as_drawn_and_through_a_lone_sheets_back():
    """The probes' capture by rays (capture.RayCubes): each texel its ray's nearest triangle
    past the near distance, at its distance, with barycentric weights that rebuild the hit;
    a two-sided sheet met from behind is its twin, met from the front; a one-sided wall met
    from behind is a back face; a sheet's triangle with no twin is seen through from behind
    (its drawing culls that face)."""
    room = _plane((-3.0, -3.0, -3.0), (0.0, 6.0, 0.0), (0.0, 0.0, 6.0), 2, flip=False)  # x = -3, faces +x (the eye)
    far_wall = _plane((3.0, -3.0, -3.0), (0.0, 0.0, 6.0), (0.0, 6.0, 0.0), 2)  # x = 3: faces -x
    sheet = _plane((1.0, -0.5, -0.5), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), 1)  # x = 1 faces +x: the eye sees its back
    twin = (sheet[0], sheet[1][:, ::-1], -sheet[2])  # its other side: the same corners, wound the other way
    parts = [room, far_wall, sheet, twin]
    offsets = np.cumsum([0] + [len(p[0]) for p in parts])
    points = np.concatenate([p[0] for p in parts])
    tris = np.concatenate([p[1] + o for p, o in zip(parts, offsets)])
    kind = np.concatenate([np.full(len(p[1]), k) for k, p in enumerate(parts)])
    eye = np.zeros((1, 3))
    n = 16
    dirs = cubemap.texel_directions(n)
    through = (np.abs(dirs[0, ..., 1] / dirs[0, ..., 0]) < 0.45) & (np.abs(dirs[0, ..., 2] / dirs[0, ..., 0]) < 0.45)
    assert through.any()

    cap = _casting(points, tris, sheet=kind >= 2).capture(eye, n, np.array([1e-3]))
    seen = cap.tid[0] >= 0
    assert seen[:2].all() and np.isinf(cap.dist[0][~seen]).all()  # the +-X faces see the walls, the rest sky
    hit = np.einsum("kc,kcx->kx", cap.bary[0][seen], points[tris[cap.tid[0][seen]]])
    np.testing.assert_allclose(np.linalg.norm(hit, axis=-1), cap.dist[0][seen], rtol=1e-6)
    np.testing.assert_allclose(hit / cap.dist[0][seen][:, None], dirs[seen], atol=1e-6)
    # +X face (face 0): through the sheet's square, the twin (its side facing the eye), not a back face.
    assert (kind[cap.tid[0, 0][through]] == 3).all() and not cap.backface[0, 0][through].any()
    np.testing.assert_allclose(cap.dist[0, 0][through], 1.0 / dirs[0][through][:, 0], rtol=1e-6)
    # The room's wall at x = -3 faces the eye: every texel of the -X face sees it from the front.
    assert (kind[cap.tid[0, 1]] == 0).all() and not cap.backface[0, 1].any()

    # In any order of the triangles (a twin before its front), and only some of them cast
    # (the rest left out as objects too small to draw): each texel names its own triangle.
    order = np.random.default_rng(5).permutation(len(tris))
    place = np.argsort(order)
    # (A texel centre on a diagonal may name either triangle of the quad: the points and sides
    # are compared, which a wrong triangle would move.)
    turned = _casting(points, tris[order], sheet=kind[order] >= 2).capture(eye, n, np.array([1e-3]))
    assert np.array_equal(turned.tid >= 0, seen[None]) and np.array_equal(turned.dist, cap.dist)
    np.testing.assert_array_equal(kind[order][turned.tid[0][seen]], kind[cap.tid[0][seen]])
    again = np.einsum("kc,kcx->kx", turned.bary[0][seen], points[tris[order][turned.tid[0][seen]]])
    np.testing.assert_allclose(again, hit, atol=1e-9)
    some = RayCubes.of(NumpyRays, points, tris[order], drawn=place[kind != 0], sheet=kind[order] >= 2).capture(eye, n, np.array([1e-3]))
    np.testing.assert_array_equal(kind[order][some.tid[0, 0]], kind[cap.tid[0, 0]])  # the sheet and the far wall, as before
    assert (some.tid[0, 1] < 0).all()  # the wall behind the eye left out: sky

    # Without its twin the sheet is one-sided: seen through from behind, the far wall beyond.
    keep = kind != 3
    alone = np.flatnonzero(keep)
    lone = _casting(points, tris[keep], sheet=kind[keep] == 2).capture(eye, n, np.array([1e-3]))
    assert (kind[alone][lone.tid[0, 0][through]] == 1).all()
    np.testing.assert_allclose(lone.dist[0, 0][through], 3.0 / dirs[0][through][:, 0], rtol=1e-6)
    # Not a sheet: a one-sided wall met from behind, a back face.
    wall = _casting(points, tris[keep]).capture(eye, n, np.array([1e-3]))
    assert (kind[alone][wall.tid[0, 0][through]] == 2).all() and wall.backface[0, 0][through].all()


def test_no_caster_or_nothing_to_cast_leaves_the_capture_to_drawing():
    """RayCubes.of gives None where the host has no ray caster or no triangle is left to cast
    (the bake then draws, as before)."""
    pts, tris, _ = _plane((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), 2)
    assert RayCubes.of(None, pts, tris) is None
    assert RayCubes.of(NumpyRays, pts, tris, drawn=np.zeros(0, dtype=np.int64)) is None
    assert RayCubes.of(NumpyRays, pts, tris) is not None


def test_the_cover_test_casts_over_the_simplified_copy_its_sheets_twins_once(monkeypatch):
    """visibility.CastCover.of_proxy: the cover test's caster over the simplified copy the
    probes saw (a NumpyRays here), a two-sided object's twin pair cast once and met from
    behind as its twin; none without the host's caster, or with COVER_BY_RAYS off."""
    from types import SimpleNamespace

    from cubegi.cubegi_engine import visibility
    from cubegi.cubegi_engine.visibility import CastCover, _cast_covered

    xs = np.arange(4.0)
    row = np.concatenate([np.stack([xs, np.zeros(4), np.zeros(4)], 1), np.stack([xs, np.ones(4), np.zeros(4)], 1)])
    strip = np.array([t for i in range(3) for t in ((i, i + 1, 4 + i), (i + 1, 5 + i, 4 + i))])  # facing +z
    points = np.concatenate([row, row + [0.0, 0.0, 1.0]])  # a sheet at z = 0 (object 0), a one-sided strip at z = 1
    triangles = np.concatenate([strip, strip[:, ::-1], strip + 8])
    owner = np.repeat([0, 0, 1], 6)
    scene = SimpleNamespace(point_object=np.array([0, 1]), scale=5.0, sheet_triangles=lambda: np.repeat([True, False], [6, 0]),
                            triangle_object=lambda: np.array([0] * 6))
    proxy = CaptureProxy(points, triangles, np.zeros(2, dtype=np.int64), np.ones(2), owner, np.zeros(2), len(triangles))
    assert proxy.sheet_triangles(scene).tolist() == [True] * 12 + [False] * 6
    assert CastCover.of_proxy(scene, proxy, None) is None
    cover = CastCover.of_proxy(scene, proxy, NumpyRays)
    assert len(cover.triangles) == 12 and cover.sheet.tolist() == [True] * 6 + [False] * 6
    assert cover.triangle_object.tolist() == [0] * 6 + [1] * 6
    # Up through the sheet from below, to a point above it facing down: its own sheet, met
    # from behind, is its twin facing the point (passed); then the other object's strip.
    eye, up, down = np.array([[1.4, 0.3, -2.0]]), np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, -1.0]])
    assert not _cast_covered(cover, eye, up, np.array([2.5]), np.array([0]), down)[0]  # stops below the strip
    assert _cast_covered(cover, eye, up, np.array([3.5]), np.array([0]), down)[0]
    one_sided = replace(cover, sheet=np.zeros(12, dtype=bool))
    assert _cast_covered(one_sided, eye, up, np.array([2.5]), np.array([0]), down)[0]  # (its own, facing away)
    monkeypatch.setattr(visibility, "COVER_BY_RAYS", False)
    assert CastCover.of_proxy(scene, proxy, NumpyRays) is None
