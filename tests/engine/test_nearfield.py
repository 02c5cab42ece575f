"""The near field's rays, hits and light, in pure numpy (no bpy): against closed forms and a
brute-force ray caster."""

import threading
import time

import numpy as np
import pytest

from cubegi.cubegi_engine import hemisphere, nearfield, nearrays, sh, spatial
from cubegi.cubegi_engine.geometry import inward, planes_of
from cubegi.cubegi_engine.rays import NumpyRays


def _quad(lo, hi, z, up=True):
    """A square from ``lo`` to ``hi`` (x, y) at height ``z``: 4 points, 2 triangles facing
    up (or down)."""
    pts = np.array([[lo, lo, z], [hi, lo, z], [hi, hi, z], [lo, hi, z]], dtype=float)
    tris = np.array([[0, 1, 2], [0, 2, 3]]) if up else np.array([[0, 2, 1], [0, 3, 2]])
    return pts, tris


def _scene(*parts):
    """Points and triangles of several parts, as one list (triangles re-indexed)."""
    pts, tris, n = [], [], 0
    for p, t in parts:
        pts.append(p)
        tris.append(t + n)
        n += len(p)
    return np.concatenate(pts), np.concatenate(tris)


def test_the_ray_pattern_is_cosine_weighted():
    d = hemisphere.ray_pattern(256)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0) and (d[:, 2] > 0).all()
    # For cosine-weighted directions the mean of cos(theta) is 2/3 and of cos^2 is 1/2.
    assert abs(d[:, 2].mean() - 2 / 3) < 2e-3 and abs((d[:, 2] ** 2).mean() - 0.5) < 2e-3
    # Its SH average is the diffuse basis (the cosine lobe) to quadrature accuracy.
    assert np.abs(sh.basis(d).mean(axis=0) - sh.diffuse_basis(np.array([0.0, 0.0, 1.0]))).max() < 0.01


def test_a_point_under_a_plate_sees_only_the_plate():
    """A point 1 cm under a 2 m plate facing it: every ray hits; its light is the plate's
    radiance, and none of the probes' light is kept."""
    plate = _quad(-1, 1, 0.01, up=False)
    point = (np.zeros((1, 3)), np.zeros((0, 3), dtype=int))
    pts, tris = _scene(point, plate)
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    near = nearfield.build(pts, normals, 0.5, tris)
    assert near.rows.tolist() == [0]
    assert np.allclose(near.open_basis[0], sh.diffuse_basis(normals[0]), atol=1e-12)  # all of the probes' light goes
    radiance = np.zeros((len(pts), 3))
    radiance[1:] = [0.2, 0.4, 0.8]
    assert np.allclose(near.gather(radiance), [[0.2, 0.4, 0.8]])
    light = near.correct(np.full((len(pts), 3), 5.0), probe_part=np.full((1, 3), 5.0), radiance=radiance)
    assert np.allclose(light[0], [0.2, 0.4, 0.8]) and np.allclose(light[1:], 5.0)


@pytest.mark.parametrize("by_caster", [False, True])
def test_a_back_face_occludes_and_sends_nothing(monkeypatch, by_caster):
    plate = _quad(-1, 1, 0.01, up=True)  # its back faces the point
    pts, tris = _scene((np.zeros((1, 3)), np.zeros((0, 3), dtype=int)), plate)
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    near = nearfield.build(pts, normals, 0.5, tris, caster=_host_caster(monkeypatch, pts, tris, refuse=False) if by_caster else None)
    assert near.rows.tolist() == [0] and np.allclose(near.open_basis[0], sh.diffuse_basis(normals[0]))
    assert np.allclose(near.gather(np.ones((len(pts), 3))), 0.0)


def test_a_point_in_the_open_and_its_own_surface_cast_nothing():
    """A floor point far from anything: its own (coplanar) triangles are no candidates, so
    it has no near field; a wall beyond the reach changes nothing."""
    floor = _quad(-2, 2, 0.0)
    wall = (np.array([[1.5, -2, 0], [1.5, 2, 0], [1.5, 2, 2], [1.5, -2, 2]], float), np.array([[0, 1, 2], [0, 2, 3]]))
    point = (np.array([[0.0, 0.0, 0.0]]), np.zeros((0, 3), dtype=int))
    pts, tris = _scene(point, floor, wall)
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    near = nearfield.build(pts[:5], normals[:5], 0.5, tris[:2])  # the floor alone
    assert near.count == 0
    near = nearfield.build(pts, normals, 0.5, tris)
    assert 0 not in near.rows.tolist()


def test_where_a_wall_meets_the_floor_half_the_light_is_the_walls():
    """A point on the floor at the foot of a wall that reaches far beyond the rays: the wall
    fills half of its hemisphere (cosine-weighted: half the rays), its light is half the
    wall's radiance and half the probes' over the open half."""
    wall = (np.array([[0.0, -50, 0], [0.0, 50, 0], [0.0, 50, 50], [0.0, -50, 50]]), np.array([[0, 2, 1], [0, 3, 2]]))  # faces -x
    point = (np.array([[0.0, 0.0, 0.0]]), np.zeros((0, 3), dtype=int))
    pts, tris = _scene(point, wall)
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    near = nearfield.build(pts, normals, 1.0, tris, rays=256)
    radiance = np.ones((len(pts), 3))
    assert abs(near.gather(radiance)[0, 0] - 0.5) < 0.02
    # What the probes lose: their light over the wall's half (+x) only. A uniform radiance
    # of 1 loses half; a radiance 1 + x (bright towards the wall) loses the +x half's share,
    # 1/2 + (2/3) * (2/pi) * ... = 1/2 + 2/(3 pi) by the half-space integral of x cos(theta).
    coeffs = np.zeros((9, 3))
    coeffs[0] = 2.0 * np.sqrt(np.pi)  # SH of radiance 1: c00 = 2 sqrt(pi)
    assert np.allclose(near.open_basis[0] @ coeffs, 0.5, atol=0.02)
    coeffs[3] = 2.0 * np.sqrt(np.pi / 3.0)  # SH of radiance x: c11 = 2 sqrt(pi / 3)
    assert np.allclose(near.open_basis[0] @ coeffs, 0.5 + 2.0 / (3.0 * np.pi), atol=0.02)


def _brute_force_hits(points, normals, reach, vertices, triangles, rays):
    """Per point and ray, the nearest triangle hit within reach (-1 for none), testing every
    triangle with the same rays as the near field."""
    turn = 2.0 * np.pi * ((points / reach) @ hemisphere.TURN_HASH % 1.0)
    dirs = hemisphere.hemisphere_rays(normals, rays, turn)
    slack = spatial.SLACK * reach + spatial.COORD_SLACK * np.abs(points).max(axis=1)
    out = np.full((len(points), rays), -1)
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    planes = planes_of(a, b, c)
    for i in range(len(points)):
        o = np.repeat(points[i : i + 1] + slack[i] * normals[i], len(a), axis=0)
        for k in range(rays):
            d = np.repeat(dirs[i, k][None], len(a), axis=0)
            t, _, _, hit, _ = spatial.intersect_pairs(o, d, planes, np.full(len(a), reach), np.full(len(a), 2 * slack[i]))
            # Only triangles with a corner in front of the point's plane count (as in the near field).
            front = np.max(np.stack([(v - points[i]) @ normals[i] for v in (a, b, c)]), axis=0) > slack[i]
            t = np.where(hit & front, t, np.inf)
            if np.isfinite(t.min()):
                out[i, k] = int(np.argmin(t))
    return out


def test_the_voxel_search_finds_what_testing_every_triangle_finds():
    rng = np.random.default_rng(3)
    centres = rng.uniform(-1, 1, (150, 3))
    edge = rng.normal(size=(150, 2, 3)) * 0.15
    verts = np.concatenate([centres, centres + edge[:, 0], centres + edge[:, 1]])
    tris = np.stack([np.arange(150), np.arange(150) + 150, np.arange(150) + 300], axis=1)
    pts = rng.uniform(-1, 1, (60, 3))
    nrm = rng.normal(size=(60, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    allp = np.concatenate([pts, verts])
    alln = np.concatenate([nrm, np.tile([0.0, 0.0, 1.0], (len(verts), 1))])
    reach, rays = 0.4, 16
    near = nearfield.build(allp, alln, reach, tris + len(pts), rays=rays)
    expected = _brute_force_hits(pts, nrm, reach, allp, tris + len(pts), rays)
    hit_points = near.rows[near.hit_row]
    mine = hit_points < len(pts)
    # Which triangle each of the near field's hits is on: its corners name it.
    key = {tuple(sorted(t)): i for i, t in enumerate((tris + len(pts)).tolist())}
    per_point = {}
    for p, corners in zip(hit_points[mine], near.hit_corner[mine]):
        per_point.setdefault(int(p), []).append(key[tuple(sorted(corners.tolist()))])
    for p in range(len(pts)):
        assert sorted(per_point.get(p, [])) == sorted(t for t in expected[p] if t >= 0), p
    assert (expected >= 0).sum() > 20  # the test has hits to compare


def test_the_triangles_planes_are_made_once_when_the_pieces_ask_at_once(monkeypatch):
    """The near field's pieces of rays ask a shared index for its triangles' planes at the
    same moment: one thread makes them, the other waits for them (not a second copy)."""
    made = []

    def slow_planes(a, b, c):
        made.append(threading.current_thread().name)
        time.sleep(0.2)  # long enough that the other thread asks while it is made
        return planes_of(a, b, c)

    monkeypatch.setattr(spatial, "planes_of", slow_planes)
    rng = np.random.default_rng(5)
    corners = spatial.Corners(*rng.uniform(-1, 1, (3, 40, 3)))
    got = {}
    threads = [threading.Thread(target=lambda k=k: got.__setitem__(k, corners.planes), name=f"piece-{k}") for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(made) == 1, made
    assert got[0] is got[1]
    np.testing.assert_array_equal(got[0], planes_of(corners.a, corners.b, corners.c))


def test_the_near_field_does_not_depend_on_the_order_of_points_or_the_scale():
    plate = _quad(-1, 1, 0.05, up=False)
    floor = _quad(-2, 2, 0.0)
    pts, tris = _scene(floor, plate)
    pts = np.concatenate([pts, np.array([[0.3, -0.2, 0.0], [0.95, 0.1, 0.0], [1.5, 0.0, 0.0]])])
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    normals[4:8] = [0.0, 0.0, -1.0]
    radiance = np.random.default_rng(0).uniform(0, 1, (len(pts), 3))

    def light(order, scale):
        inv = np.argsort(order)
        near = nearfield.build(pts[order] * scale, normals[order], 0.3 * scale, inv[tris])
        out = np.zeros((len(pts), 3))
        out[near.rows] = near.gather(radiance[order])
        return out[inv]

    base = light(np.arange(len(pts)), 1.0)
    assert np.abs(base).max() > 0.1
    order = np.random.default_rng(1).permutation(len(pts))
    for scale in (1.0, 1e-3, 1e3):
        np.testing.assert_allclose(light(order, scale), base, atol=1e-9)


def test_rays_cast_a_few_points_at_a_time_give_the_same_near_field(monkeypatch):
    """The per-ray arrays are made POINTS_AT_ONCE (nearrays) points at a time (a million points' would
    not fit); what is kept of them is the same however the points are split: a plate over a
    floor, points under it, beside it and in a gap, and a covered corner."""
    pts, tris = _scene(_grid(-1, 1, 0.0, 6), _quad(-0.4, 0.6, 0.08, up=False))
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    normals[-4:] = [0.0, 0.0, -1.0]
    hidden = np.zeros(len(pts), dtype=bool)
    hidden[np.flatnonzero(np.all(np.abs(pts[:, :2] - 0.1) < 0.3, axis=1) & (pts[:, 2] == 0))] = True

    def build(at_once):
        monkeypatch.setattr(nearrays, "POINTS_AT_ONCE", at_once)
        return nearfield.build(pts, normals, 0.5, tris, hidden=hidden)

    whole = build(1 << 20)
    assert whole.count > 10 and len(whole.hit_row) > 100
    for at_once in (1, 3, 7):
        split = build(at_once)
        for name in ("rows", "open_basis", "hit_row", "hit_corner", "hit_weight", "share", "hidden"):
            np.testing.assert_array_equal(getattr(split, name), getattr(whole, name), err_msg=f"{name} at {at_once}")


def test_where_the_host_has_a_caster_every_ray_goes_through_it(monkeypatch):
    """Given the host's caster, the points with candidate pairs cast their rays through it,
    not through the voxel index's trace, and see what the index's trace sees: a floor at the
    foot of a wall and under a plate."""
    floor, plate = _quad(-1, 1, 0.0), _quad(-0.3, 0.3, 0.05, up=False)
    wall = (np.array([[0.5, -1, 0], [0.5, 1, 0], [0.5, 1, 1], [0.5, -1, 1]]), np.array([[0, 2, 1], [0, 3, 2]]))
    rng = np.random.default_rng(4)
    points = (np.column_stack([rng.uniform(-0.9, 0.45, (60, 2)), np.zeros(60)]), np.zeros((0, 3), dtype=int))
    pts, tris = _scene(points, floor, plate, wall)
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    radiance = rng.uniform(0.1, 1.0, (len(pts), 3))
    which = np.arange(len(pts)) < 60  # (the meshes' own corners start their rays into their triangles by the caster)
    by_index = nearfield.build(pts, normals, 0.3, tris, rays=64, which=which)
    asked = []

    class Counting(NumpyRays):
        def cast(self, origins, dirs, reach=None):
            asked.append(len(origins))
            return super().cast(origins, dirs, reach)

    by_caster = nearfield.build(pts, normals, 0.3, tris, rays=64, which=which, caster=_host_caster(monkeypatch, pts, tris, Counting))
    assert by_index.count >= 30 and by_caster.rows.tolist() == by_index.rows.tolist()
    assert sum(asked) % 64 == 0 and by_index.count <= sum(asked) // 64 <= 60  # (64 rays each, a point with candidates)
    assert np.abs(by_caster.gather(radiance) - by_index.gather(radiance)).max() < 1e-9
    assert np.abs(by_caster.open_basis - by_index.open_basis).max() < 1e-9


def _host_caster(monkeypatch, pts, tris, kind=NumpyRays, refuse=True):
    """A host's caster over ``tris`` (as :func:`nearfield.build` takes it: every triangle
    tested), with the voxel index's trace refused from here on (unless not ``refuse``: a
    point whose rays met a back face first casts again through it)."""
    def refused(*args):
        raise AssertionError("the voxel index traced rays that the caster was given")

    if refuse:
        monkeypatch.setattr(spatial.VoxelIndex, "trace", refused)
    host = kind(pts, tris)
    return lambda: (host, np.arange(len(tris)), inward(tris, pts))


def test_through_the_caster_coincident_faces_give_the_front_one_in_any_order(monkeypatch):
    """A block's underside lying on a floor (its faces facing down, the floor's up, in one
    plane): a point over them sees the floor, whichever of the two the caster names first
    (float32 cannot tell them apart); as the voxel index sees it, in either order."""
    floor, under = _quad(-1, 1, 0.0), _quad(0.0, 0.5, 0.0, up=False)
    point = (np.array([[0.25, 0.1, 0.3]]), np.zeros((0, 3), dtype=int))
    pts, tris = _scene(point, floor, under)
    normals = np.tile([0.0, 0.0, -1.0], (len(pts), 1))
    normals[1:5] = [0.0, 0.0, 1.0]
    radiance = np.random.default_rng(3).uniform(0.1, 1.0, (len(pts), 3))
    which = np.arange(len(pts)) == 0
    by_index = nearfield.build(pts, normals, 0.5, tris, rays=64, which=which)
    for order in (tris, tris[::-1]):
        near = nearfield.build(pts, normals, 0.5, order, rays=64, which=which, caster=_host_caster(monkeypatch, pts, order, refuse=False))
        assert near.rows.tolist() == [0] and np.allclose(near.gather(radiance), by_index.gather(radiance), atol=1e-12)
    assert by_index.gather(radiance)[0, 0] > 0.1


def test_crowded_points_and_scenes_over_the_budget_are_left_out_and_counted(monkeypatch):
    """A point among more candidate triangles than the cap keeps the probes' light; a scene
    whose pairs would exceed the budget gets no near field, with the reason. Given the host's
    caster, the crowded point casts by clusters through it, unless asked not to."""
    rng = np.random.default_rng(2)
    n = 400
    c = rng.uniform(-0.05, 0.05, (n, 3)) + [0.0, 0.0, 0.1]
    verts = np.concatenate([c, c + [0.02, 0, 0], c + [0, 0.02, 0]])
    tris = np.stack([np.arange(n), np.arange(n) + n, np.arange(n) + 2 * n], axis=1)
    pts = np.concatenate([np.zeros((1, 3)), verts])
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    near = nearfield.build(pts, normals, 0.5, tris + 1)
    assert near.crowded >= 1 and 0 not in near.rows.tolist()
    near = nearfield.build(pts, normals, 0.5, tris + 1, max_pairs=10)
    assert near.count == 0 and "more than 10" in near.skipped
    down = tris[:, ::-1] + 1  # (facing the point: a cluster's ray meeting a back face first counts for nothing)
    caster = _host_caster(monkeypatch, pts, down)
    assert 0 in nearfield.build(pts, normals, 0.5, down, caster=caster).rows.tolist()
    alone = nearfield.build(pts, normals, 0.5, down, caster=caster, clustered=False)
    assert alone.crowded >= 1 and 0 not in alone.rows.tolist()


@pytest.mark.parametrize("touching", [False, True])
def test_points_crowded_by_the_triangles_centres_are_the_ones_the_listing_finds(monkeypatch, touching):
    """Points with more triangles' centres around them than MAX_NEARBY are left out before
    any triangle is listed in its voxels (a million-vertex scene's near field was seconds of
    listing to find every point crowded); the points left out, and every other point's
    pairs, are what listing them all finds: clumps of small triangles of every density over
    a floor, points on the floor and in the clumps."""
    rng = np.random.default_rng(5)
    parts, points = [_grid(-2, 2, 0.0, 8)], []
    for k, count in enumerate((40, 300, 900, 1500, 4000)):
        centre = np.array([-1.6 + 0.8 * k, 0.3 * (-1) ** k, 0.15])
        c = centre + rng.uniform(-0.12, 0.12, (count, 3))
        verts = np.concatenate([c, c + rng.normal(0, 0.01, (count, 3)), c + rng.normal(0, 0.01, (count, 3))])
        parts.append((verts, np.stack([np.arange(count), np.arange(count) + count, np.arange(count) + 2 * count], axis=1)))
        points.append(centre + [0.0, 0.0, -0.15])  # on the floor under the clump
    pts, tris = _scene(*parts)
    pts = np.concatenate([pts, np.array(points)])
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    if touching:
        normals[len(pts) - len(points):] = [0.0, 0.0, -1.0]
    a, b, c = pts[tris[:, 0]], pts[tris[:, 1]], pts[tris[:, 2]]
    reach = np.full(len(pts), 0.3)

    def found():
        index = spatial.VoxelIndex(a, b, c, 0.3)
        return index.candidates(pts, normals, reach, touching=touching)

    fast = found()
    monkeypatch.setattr(spatial.VoxelIndex, "_centre_count", lambda self, key: np.zeros(len(key), dtype=np.int64))
    listed = found()
    assert 0 < fast[2].sum() < len(pts) and (~fast[2]).sum() > 50
    for mine, theirs in zip(fast, listed):
        np.testing.assert_array_equal(mine, theirs)


@pytest.mark.parametrize("reach", [0.05, 0.2])
def test_a_surface_passing_out_of_reach_fades(reach):
    """A plate facing a point at a distance near the reach: its light falls continuously to
    nothing as the plate goes out of reach (no step)."""
    values = []
    for h in np.linspace(0.6 * reach, 1.1 * reach, 11):
        plate = _quad(-50 * reach, 50 * reach, h, up=False)
        pts, tris = _scene((np.zeros((1, 3)), np.zeros((0, 3), dtype=int)), plate)
        near = nearfield.build(pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)), reach, tris)
        values.append(float(near.gather(np.ones((len(pts), 3)))[0, 0]) if near.count else 0.0)
    assert values[0] > 0.2 and values[-1] == 0.0
    assert np.abs(np.diff(values)).max() < 0.2  # no jump


@pytest.mark.parametrize("by_caster", [False, True])
def test_a_corner_hidden_under_a_wall_lends_no_darkness_to_the_floor_beside_it(monkeypatch, by_caster):
    """A floor triangle strip from x = -1 to 0 whose corners at x = 0 stand under a wall
    (covered: no probe sees them, so their light is dark; hidden, as the wall's underside
    lies on them): rays from the wall's foot land on the open floor beside it and take its
    lit corners' light; under a plate 2 cm above the floor (covered), a hit near the hidden
    corners stays dark. Covered corners that lie open keep their own light. The same where
    the host's caster casts the rays."""
    floor = np.array([[-1.0, -1, 0], [0.0, -1, 0], [0.0, 1, 0], [-1.0, 1, 0]])
    floor_tris = np.array([[0, 1, 2], [0, 2, 3]])
    foot = np.array([[-0.01, 0.0, 0.0]])  # on the wall's face, facing -x
    # The wall's underside, lying on the floor over the hidden corners (facing down).
    under = np.array([[-0.01, -1.2, 0.0], [0.3, -1.2, 0.0], [0.3, 1.2, 0.0], [-0.01, 1.2, 0.0]])
    # The wall's face over the foot (a corner of it, as a mesh's points are: a caster starts
    # their rays into their own triangles).
    face = np.array([[-0.01, -0.5, 1.0], [-0.01, 0.5, 1.0]])
    pts = np.concatenate([floor, foot, under, face])
    normals = np.concatenate([np.tile([0.0, 0.0, 1.0], (4, 1)), [[-1.0, 0.0, 0.0]], np.tile([0.0, 0.0, -1.0], (4, 1)),
                              np.tile([-1.0, 0.0, 0.0], (2, 1))])
    floor_tris = np.concatenate([floor_tris, np.array([[0, 2, 1], [0, 3, 2]]) + 5, [[4, 9, 10]]])
    hidden = np.array([False, True, True, False, False, True, True, True, True, False, False])
    radiance = np.array([[1.0] * 3, [0.0] * 3, [0.0] * 3, [1.0] * 3] + [[0.0] * 3] * 7)
    def host(p, t):
        return _host_caster(monkeypatch, p, t, refuse=False) if by_caster else None

    near = nearfield.build(pts, normals, 0.3, floor_tris, rays=64, hidden=hidden, caster=host(pts, floor_tris))
    row = near.rows.tolist().index(4)
    # Half the foot's rays land on the floor; each takes the lit corners' light, 1.
    assert abs(near.gather(radiance)[row, 0] - 0.5) < 0.05
    near_plain = nearfield.build(pts, normals, 0.3, floor_tris, rays=64, caster=host(pts, floor_tris))
    assert near_plain.gather(radiance)[near_plain.rows.tolist().index(4), 0] < 0.2  # barycentric: mostly the dark corner
    # Without the wall's underside the covered corners lie open (a thick wall's outer face,
    # which no probe sees but the sun lights): their own light counts, as barycentric.
    no_under = floor_tris[[0, 1, 4]]
    near_open = nearfield.build(pts, normals, 0.3, no_under, rays=64, hidden=hidden, caster=host(pts, no_under))
    assert near_open.gather(radiance)[near_open.rows.tolist().index(4), 0] < 0.2

    plate = _quad(-0.2, 0.2, 0.02, up=False)
    centre = np.array([[0.0, 0.0, 0.02]])  # the plate's middle, facing down
    pts2 = np.concatenate([pts, plate[0], centre])
    normals2 = np.concatenate([normals, np.tile([0.0, 0.0, -1.0], (5, 1))])
    tris2 = np.concatenate([floor_tris, plate[1] + len(pts)])
    hidden2 = np.concatenate([hidden, np.zeros(5, dtype=bool)])
    radiance2 = np.concatenate([radiance, np.zeros((5, 3))])
    near = nearfield.build(pts2, normals2, 0.1, tris2, rays=64, hidden=hidden2, caster=host(pts2, tris2))
    row = near.rows.tolist().index(len(pts2) - 1)
    # Its rays land on the floor under the plate, near the hidden corners: dark.
    assert near.gather(radiance2)[row, 0] < 0.1


def test_resting_finds_a_face_lying_on_another_surface():
    """A block's underside lying on the ground (the ground's triangle in its plane, facing
    it, over it) rests; the ground beside the block, a point on the underside's rim past the
    ground's edge, and a face lying on a surface that faces the same way do not."""
    ground = _quad(-1, 1, 0.0, up=True)
    underside = np.array([[0.0, 0.0, 0.0], [0.5, 0.5, 0.0], [1.5, 0.0, 0.0], [0.3, 0.3, 1e-3]])
    pts = np.concatenate([ground[0], underside])
    normals = np.concatenate([np.tile([0.0, 0.0, 1.0], (4, 1)), [[0, 0, -1.0], [0, 0, -1.0], [0, 0, -1.0], [0, 0, 1.0]]])
    which = np.arange(4, 8)
    got = spatial.resting(pts, normals, ground[1], 2.0, which)
    # 4: on the ground, facing down: rests. 5: the same. 6: past the ground's edge. 7: facing up (same way), 1 mm above.
    assert got.tolist() == [True, True, False, False]
    assert not spatial.resting(pts, normals, ground[1], 2.0, np.arange(4)).any()  # the ground's own points


def test_the_resting_index_is_kept_for_a_small_scene_and_not_past_the_limit(monkeypatch):
    """A bake asks :func:`spatial.resting` twice: its index is kept for the second ask, but
    not past RESTING_KEPT_BELOW triangles (kept to the bake's end, it held 0.2 GB at a
    million vertices); the answers are the same either way."""
    ground = _quad(-1, 1, 0.0, up=True)
    underside = np.array([[0.0, 0.0, 0.0], [0.5, 0.5, 0.0]])
    pts = np.concatenate([ground[0], underside])
    normals = np.concatenate([np.tile([0.0, 0.0, 1.0], (4, 1)), [[0, 0, -1.0], [0, 0, -1.0]]])
    which = np.arange(4, 6)
    spatial.forget_indexes()
    kept = spatial.resting(pts, normals, ground[1], 2.0, which)
    assert len(spatial._INDEXES) == 1
    spatial.forget_indexes()
    monkeypatch.setattr(spatial, "RESTING_KEPT_BELOW", len(ground[1]))
    made = spatial.resting(pts, normals, ground[1], 2.0, which)
    assert not spatial._INDEXES
    assert kept.tolist() == made.tolist() == [True, True]


@pytest.mark.parametrize("by_caster", [False, True])
def test_a_hit_in_a_gap_takes_only_what_the_gap_lets_in(monkeypatch, by_caster):
    """A coarse floor cell (1 m) half under a plate standing 2 cm above it, and a point on
    the plate's underside looking down: its rays land on the floor under the plate, between
    corners in the open (x = 0) and corners under the plate (x = 1). Barycentric weights
    alone give the hit points much of the open corners' light; the openness of the hit
    points (closed in by the plate) against the open corners' takes nearly all of it away.
    A point in the open, beside the plate, keeps its weights. The same where the host's
    caster casts the rays."""
    floor = (np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float), np.array([[0, 1, 2], [0, 2, 3]]))
    plate = (np.array([[0.5, -0.5, 0.02], [1.5, -0.5, 0.02], [1.5, 1.5, 0.02], [0.5, 1.5, 0.02]]),
             np.array([[0, 2, 1], [0, 3, 2]]))  # facing down, over the floor's half x > 0.5
    under = (np.array([[0.75, 0.5, 0.02], [0.2, 0.5, 0.001]]), np.zeros((0, 3), dtype=int))
    pts, tris = _scene(floor, plate, under)
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    normals[4:9] = [0.0, 0.0, -1.0]  # the plate's corners and the point under it look down
    watched, beside = 8, 9
    caster = _host_caster(monkeypatch, pts, tris) if by_caster else None

    def open_corner_weight(rays):
        monkeypatch.setattr(nearfield, "OPENNESS_RAYS", rays)
        near = nearfield.build(pts, normals, 0.1, tris, caster=caster)
        out = {}
        for p in (watched, beside):
            rows = np.flatnonzero(near.rows == p)
            hits = np.isin(near.hit_row, rows)
            w = near.hit_weight[hits] * np.isin(near.hit_corner[hits], [0, 3])  # the corners at x = 0
            out[p] = (w.sum(), near.hit_weight[hits].sum())
        return out

    plain, weighed = open_corner_weight(0), open_corner_weight(16)
    assert plain[watched][0] > 0.2 * plain[watched][1]  # barycentric: the open corners carry a fifth or more
    assert weighed[watched][0] < 0.2 * plain[watched][0]  # in the gap: little of it
    assert weighed[beside] == pytest.approx(plain[beside])  # nothing over the hit points: as before


def test_the_segment_search_finds_every_triangle_whose_box_meets_the_segment():
    rng = np.random.default_rng(5)
    centres = rng.random((400, 3)) * 4.0
    a, b, c = (centres + rng.normal(scale=0.15, size=(400, 3)) for _ in range(3))
    index = spatial.VoxelIndex(a, b, c, 0.3)
    starts = rng.random((300, 3)) * 4.0
    dirs = rng.normal(size=(300, 3))
    ends = starts + 0.3 * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)  # one voxel edge long
    pp, tt = index.segment_candidates(starts, ends)
    got = set(zip(pp.tolist(), tt.tolist()))
    lo, hi = np.minimum(starts, ends), np.maximum(starts, ends)
    tlo, thi = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
    meet = np.all((lo[:, None] <= thi[None]) & (hi[:, None] >= tlo[None]), axis=2)
    want = set(zip(*[x.tolist() for x in np.nonzero(meet)]))
    assert got == want and len(want) > 50


def test_the_hemisphere_search_finds_every_triangle_in_reach_and_in_front_and_skips_a_walls_own():
    """Points on a wall along an axis (its own triangles, all in its plane, are no candidates,
    and the voxels holding only them are passed over whole) among random triangles: the
    pairs are exactly those a brute-force test of every triangle gives."""
    rng = np.random.default_rng(7)
    g = np.linspace(0.0, 4.0, 41)
    x, y = np.meshgrid(g[:-1], g[:-1])
    x, y = x.ravel(), y.ravel()
    d = g[1] - g[0]
    wall = [np.stack([x, y, np.zeros_like(x)], 1), np.stack([x + d, y, np.zeros_like(x)], 1), np.stack([x, y + d, np.zeros_like(x)], 1)]
    centres = rng.random((300, 3)) * [4.0, 4.0, 0.6]
    loose = [centres + rng.normal(scale=0.1, size=(300, 3)) for _ in range(3)]
    a, b, c = (np.concatenate([w, r]) for w, r in zip(wall, loose))
    index = spatial.VoxelIndex(a, b, c, 0.3)
    points = np.concatenate([rng.random((200, 3)) * [4.0, 4.0, 0.0], rng.random((100, 3)) * [4.0, 4.0, 0.6]])
    normals = np.concatenate([np.tile([0.0, 0.0, 1.0], (200, 1)), rng.normal(size=(100, 3))])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    reach = np.full(len(points), 0.3)
    pp, tt, crowded = index.candidates(points, normals, reach)
    assert not crowded.any()
    got = set(zip(pp.tolist(), tt.tolist()))
    # Brute force: the box within reach, the plane within reach, a corner in front by more than the slack.
    lo, hi = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
    box = np.all((points[:, None] >= lo[None] - 0.3) & (points[:, None] <= hi[None] + 0.3), axis=2)
    unit = np.cross(b - a, c - a)
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    plane = np.abs(points @ unit.T - np.einsum("ij,ij->i", unit, a)[None]) <= 0.3
    front = np.max(np.stack([np.einsum("ptc,pc->pt", v[None] - points[:, None], normals) for v in (a, b, c)]), axis=0)
    slack = spatial.SLACK * 0.3 + spatial.COORD_SLACK * np.abs(points).max(axis=1)
    passes = box & plane & (front > slack[:, None])
    assert got <= set(zip(*[v.tolist() for v in np.nonzero(passes)]))
    # Every triangle whose centre lies within the reach, in front, is there.
    to_centre = index.centre[None] - points[:, None]
    close = (np.linalg.norm(to_centre, axis=2) <= 0.3) & (np.einsum("ptc,pc->pt", to_centre, normals) > 0)
    want = set(zip(*[v.tolist() for v in np.nonzero(passes & close)]))
    assert want <= got and len(want) > 100
    assert not any(t < len(x) for p, t in got if p < 200)  # a wall point: none of the wall's own triangles


def test_a_triangle_in_front_by_a_hair_over_the_slack_stays_a_candidate():
    """Its front height (6.0000000000008e-6) tops the ray's slack (6e-6) by less than the
    rounding of the box tests, which sum the same terms in another order: they must not
    drop what the exact test keeps."""
    a = np.array([[0.5734587395483763, 0.5992276899478435, -0.028348147998352394]])
    b = np.array([[0.5, 0.3, -0.029348147998352395]])
    c = np.array([[0.3, 0.5, -0.030348147998352393]])
    point = np.array([[0.25, 0.25, 0.0]])
    normal = np.array([[0.05713338417787122, 0.028108684469556604, 0.997970780268528]])
    pp, tt, _ = spatial.VoxelIndex(a, b, c, 0.25).candidates(point, normal, np.array([0.5]))
    assert pp.tolist() == [0] and tt.tolist() == [0]


def test_longer_rays_for_some_points_replace_their_rows():
    """Two points under a plate 0.3 high: with a reach of 0.1 neither meets it; rays of 1.0
    cast by the second alone (``which``) find it, and replacing the rows gives that point
    the plate's light while the first keeps its own (none)."""
    plate = _quad(-2, 2, 0.3, up=False)
    points = (np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]]), np.zeros((0, 3), dtype=int))
    floor = _quad(-2, 2, -0.001)
    pts, tris = _scene(points, plate, floor)
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    short = nearfield.build(pts, normals, 0.1, tris)
    assert 0 not in short.rows and 1 not in short.rows
    which = np.zeros(len(pts), dtype=bool)
    which[1] = True
    far = nearfield.build(pts, normals, 1.0, tris, which=which)
    assert far.rows.tolist() == [1] and far.share[0] > 0.8
    both = short.replaced_rows(far)
    assert 1 in both.rows and 0 not in both.rows
    radiance = np.zeros((len(pts), 3))
    radiance[2:6] = 1.0  # the plate
    gathered = both.gather(radiance)
    row = int(np.flatnonzero(both.rows == 1)[0])
    assert np.allclose(gathered[row], far.share[0], atol=0.05)
    # Replacing rows a field already has: the old ones go.
    again = far.replaced_rows(far)
    assert again.rows.tolist() == [1] and np.allclose(again.gather(radiance), far.gather(radiance))


def _grid(lo, hi, z, n, up=True):
    """A square from ``lo`` to ``hi`` (x, y) at height ``z`` cut into ``n`` x ``n`` cells:
    its ``(n+1)^2`` points and ``2 n^2`` triangles facing up (or down)."""
    t = np.linspace(lo, hi, n + 1)
    pts = np.array([[x, y, z] for y in t for x in t])
    k = np.arange(n * (n + 1)).reshape(n, n + 1)[:, :n].ravel()  # each cell's lower-left corner
    a, b, c, d = k, k + 1, k + n + 2, k + n + 1
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return pts, (tris if up else tris[:, ::-1])


def test_light_trapped_between_two_close_plates_is_summed_to_the_end():
    """A lamp's white back 1 cm under a white ceiling: the tail's light bounces between them
    (each round trip keeps albedo^2 of it); the near field's sum of those bounces equals the
    linear system's solution, not the few first terms of it."""
    lamp, ceiling = _grid(-0.2, 0.2, 0.0, 8), _grid(-0.3, 0.3, 0.01, 12, up=False)
    pts, tris = _scene(lamp, ceiling)
    normals = np.zeros_like(pts)
    normals[: len(lamp[0]), 2], normals[len(lamp[0]):, 2] = 1.0, -1.0
    near = nearfield.build(pts, normals, 0.05, tris, rays=64)
    assert near.count > len(lamp[0])
    albedo = np.full((len(pts), 3), 0.8)
    light = np.full((len(pts), 3), 0.3)  # the probes' light of the tail
    part = np.full((near.count, 3), 0.2)  # the probes' light in the hit directions
    before = np.full((len(pts), 3), 1.0)
    summed = near.correct_sum(light, part, albedo, before)
    # The same sum solved: L_rows = base + G a (before + L), with L the probes' light off the rows.
    g = np.stack([near.gather(np.repeat(np.eye(len(pts))[:, [k]], 3, axis=1))[:, 0] for k in range(len(pts))], axis=1)
    rows = near.rows
    off = np.setdiff1d(np.arange(len(pts)), rows)
    rhs = light[rows] - part + g @ (0.8 * before) + 0.8 * g[:, off] @ light[off]
    solved = np.linalg.solve(np.eye(near.count) - 0.8 * g[:, rows], rhs)
    assert np.abs(summed[rows] - solved).max() <= 1e-5 * np.abs(solved).max()
    # A handful of bounces would miss a good share of it: the sum is not a few terms.
    few = light.copy()
    for _ in range(4):
        few[rows] = light[rows] - part + near.gather(albedo * (before + few))
    assert (solved - few[rows]).max() > 0.05 * solved.max()


def test_an_emitter_close_in_front_of_a_surface_is_found_with_its_gap():
    from cubegi.cubegi_engine.emitters import trapped_light
    from cubegi.cubegi_engine.scene import SceneArrays

    def scene(gap):
        lamp, ceiling = _grid(-0.2, 0.2, 0.0, 8), _grid(-0.3, 0.3, gap, 12, up=False)
        pts, tris = _scene(lamp, ceiling)
        normals = np.zeros_like(pts)
        normals[: len(lamp[0]), 2], normals[len(lamp[0]):, 2] = 1.0, -1.0
        emission = np.zeros_like(pts)
        emission[: len(lamp[0])] = 5.0
        owner = np.repeat([0, 1], [len(lamp[0]), len(ceiling[0])])
        arrays = SceneArrays(pts, normals, np.full_like(pts, 0.8), emission, tris, point_object=owner, object_names=["Lamp", "Ceiling"])
        return arrays, nearfield.build(pts, normals, 0.05, tris, rays=64)

    arrays, near = scene(0.01)
    (found,) = trapped_light(arrays, near)
    assert (found.emitter, found.surface) == (0, 1) and abs(found.gap - 0.01) < 1e-6
    assert found.points >= 25 and found.view > 0.9
    assert trapped_light(*scene(0.2)) == []  # out of the near field's reach
    arrays.emission[:] = 0.0
    assert trapped_light(arrays, near) == []  # a plain surface close to another: nothing trapped


def _open_box(size, n):
    """A box ``size`` wide and deep, open at the top, its faces cut into ``n`` x ``n`` cells
    and facing in (a cup's inside): points, triangles, normals."""
    parts, normals = [], []
    base_pts, base_tris = _grid(-size / 2, size / 2, 0.0, n)
    turns = [np.eye(3)]
    for axis, sign in ((0, 1), (0, -1), (1, 1), (1, -1)):  # a floor turned up into each wall
        ang = sign * np.pi / 2
        c, s = np.cos(ang), np.sin(ang)
        turns.append(np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) if axis == 0 else np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]))
    for turn in turns:
        pts = base_pts @ turn.T
        up = turn @ [0.0, 0.0, 1.0]
        if turn is not turns[0]:  # a wall: moved to the side it faces away from, up to the rim
            pts = pts - up * size / 2 + [0.0, 0.0, size / 2]
        parts.append((pts, base_tris))
        normals.append(np.tile(up, (len(pts), 1)))
    pts, tris = _scene(*parts)
    return pts, tris, np.concatenate(normals)


def test_crowded_points_share_the_rays_of_their_cluster_through_a_caster(monkeypatch):
    """The inside of a finely cut cup is crowded (more candidate triangles than the cap): left
    out without a caster of the host's; with one, one point per small cluster casts its rays
    through it and the others gather exactly what it gathers, each with its own normal's
    open basis."""
    from cubegi.cubegi_engine.rays import NumpyRays

    monkeypatch.setattr(nearfield, "MAX_CANDIDATES", 16)
    pts, tris, normals = _open_box(0.2, 24)
    # every normal points into the box
    assert np.all(np.einsum("ij,ij->i", normals, [0.0, 0.0, 0.1] - pts) > -1e-9)
    alone = nearfield.build(pts, normals, 0.2, tris)
    assert alone.crowded > len(pts) // 2 and alone.alias is None
    near = nearfield.build(pts, normals, 0.2, tris, caster=lambda: (NumpyRays(pts, tris), np.arange(len(tris)), inward(tris, pts)))
    assert near.crowded == 0 and near.count == alone.count + alone.crowded  # every crowded point has a row
    assert np.isin(alone.rows, near.rows).all()
    members, theirs = near.alias
    assert len(members) > len(np.unique(theirs)) > 10  # clusters of several points
    radiance = np.random.default_rng(0).uniform(0.0, 1.0, (len(pts), 3))
    gathered = near.gather(radiance)
    np.testing.assert_array_equal(gathered[members], gathered[theirs])
    # Every hit is on a front face inside the cup: a unit radiance gathers each row's share.
    np.testing.assert_allclose(near.gather(np.ones((len(pts), 3)))[:, 0], near.share, atol=1e-9)
    bottom_middle = np.argmin(np.linalg.norm(pts - [0.0, 0.0, 0.0], axis=1))
    assert near.share[list(near.rows).index(bottom_middle)] > 0.3
    # A member's open basis is its rep's, turned to its own normal.
    rows = near.rows
    turned = near.open_basis[theirs] + near.share[theirs, None] * (sh.diffuse_basis(normals[rows[members]]) - sh.diffuse_basis(normals[rows[theirs]]))
    np.testing.assert_allclose(near.open_basis[members], turned, atol=1e-12)


def test_a_closed_white_loop_keeps_at_most_the_loop_gain_of_its_light():
    """Two points each of whose rays all meet the other (a pocket under a white saucer's rim,
    closed as far as 16 rays tell): summed without end, any light reaching them would grow
    without bound. Each keeps at most MAX_LOOP_GAIN of what it gathers, so the sum is the
    geometric series at that gain, found in a few steps; a grey loop is summed as it is."""
    third = np.full((2, 3), 1.0 / 3.0)
    near = nearfield.NearField(np.array([0, 1]), np.zeros((2, 9)), np.array([0, 1]), np.array([[1, 1, 1], [0, 0, 0]]),
                               third, rays=16, share=np.ones(2))
    before = np.full((2, 3), 0.01)
    zero = np.zeros((2, 3))
    g = nearfield.MAX_LOOP_GAIN
    assert 0.9 < g < 1.0
    white = near.settle(zero, zero, np.ones((2, 3)), before)
    np.testing.assert_allclose(white, 0.01 * g / (1.0 - g), rtol=1e-3)
    grey = near.settle(zero, zero, np.full((2, 3), 0.5), before)
    np.testing.assert_allclose(grey, 0.01, rtol=1e-3)  # L = 0.5 (0.01 + L)


def test_a_caster_ray_that_meets_a_back_face_first_is_no_sample(monkeypatch):
    """A ray through the host's caster that meets a back face first set out into a solid (or
    met a face turned the wrong way): it is left out and the point's other rays stand for it,
    so every row still gathers its whole share from the front faces it sees."""
    from cubegi.cubegi_engine.rays import NumpyRays

    monkeypatch.setattr(nearfield, "MAX_CANDIDATES", 16)
    pts, tris, normals = _open_box(0.2, 24)
    wall = np.flatnonzero(np.isclose(pts[tris].mean(axis=1)[:, 0], 0.1))  # the wall at x = +0.1, its faces turned out
    tris[wall] = tris[wall][:, ::-1]
    near = nearfield.build(pts, normals, 0.2, tris, caster=lambda: (NumpyRays(pts, tris), np.arange(len(tris)), inward(tris, pts)))
    assert near.count > len(pts) // 2
    np.testing.assert_allclose(near.gather(np.ones((len(pts), 3)))[:, 0], near.share, atol=1e-9)
    bottom_middle = np.argmin(np.linalg.norm(pts - [0.0, 0.0, 0.0], axis=1))
    assert 0.3 < near.share[list(near.rows).index(bottom_middle)] < 1.0


def test_the_near_fields_balance_scales_added_light_down_and_never_up():
    from cubegi.cubegi_engine.series import near_factor

    probe = np.array([2.0, 1.0, 4.0])
    # Light added: the points' total goes back to the probes'.
    added = np.array([0.5, 0.25, 1.0])
    assert np.allclose(near_factor(probe, added) * (probe + added), probe)
    # Light taken away (a concave edge's shadow): kept as gathered, not scaled back up.
    assert np.array_equal(near_factor(probe, -0.1 * probe), np.ones(3))
    # Per channel: one of each.
    mixed = near_factor(probe, np.array([1.0, -0.2, 0.0]))
    assert np.allclose(mixed, [2.0 / 3.0, 1.0, 1.0])


def test_a_probe_sees_a_triangle_with_a_covered_corner_by_its_seen_corners():
    from cubegi.cubegi_engine.visibility import seen_corners_only

    covered = np.array([False, False, True, True])
    corners = np.array([[[0, 1, 2], [0, 1, 3], [2, 3, 1], [0, 1, 0], [2, 3, 2]]])  # (1 probe, 5 texels, 3)
    bary = np.array([[[0.2, 0.3, 0.5], [0.6, 0.4, 0.0], [0.7, 0.3, 0.0], [0.3, 0.3, 0.4], [0.1, 0.1, 0.8]]], dtype=np.float32)
    out = seen_corners_only(bary, corners, covered)
    assert np.allclose(out.sum(axis=-1), bary.sum(axis=-1))  # every texel keeps its whole weight
    assert np.allclose(out[0, 0], [0.4, 0.6, 0.0])  # the covered corner's 0.5 shared 2 : 3
    assert np.allclose(out[0, 1], bary[0, 1])  # its covered corner had no weight
    assert np.allclose(out[0, 2], [0.0, 0.0, 1.0])  # at the covered corners: the seen one's light
    assert np.allclose(out[0, 3], bary[0, 3])  # nothing covered
    assert np.allclose(out[0, 4], bary[0, 4])  # all covered: nothing to move to
    corner_light = np.array([1.0, 2.0, 50.0, 80.0])  # the hidden side's light
    seen = (out[0] * corner_light[corners[0]]).sum(axis=-1)
    assert seen[0] <= 2.0 and seen[2] == pytest.approx(2.0)


def test_a_sheets_back_side_met_through_its_fronts_triangle_faces_the_other_way():
    """The host's caster meets a sheet's back side through its front's triangle, with the
    twin points as its corners: the gap and hidden-corner tests take the normal of the side
    those corners lie on (the twin's), not the front's."""
    from cubegi.cubegi_engine.nearhits import _side_normals
    from cubegi.cubegi_engine.scene import Sheets

    pts, tris = _quad(-1, 1, 0.0)
    pts = np.concatenate([pts, pts])
    tris = np.concatenate([tris, tris[:, ::-1] + 4])  # the twins, wound the other way
    sheets = Sheets(np.arange(8) >= 4, np.zeros(8, dtype=np.int64), tris)
    index = spatial.VoxelIndex(pts[tris[:, 0]], pts[tris[:, 1]], pts[tris[:, 2]], 0.5, sheets)
    hit_tri = np.array([0, 0, 2])
    corners = np.stack([tris[0], tris[0] + 4, tris[2]])  # the front's, the front's turned to the twins, the twin's own
    up = _side_normals(index, hit_tri, corners)
    assert np.allclose(up, [[0, 0, 1], [0, 0, -1], [0, 0, -1]])
