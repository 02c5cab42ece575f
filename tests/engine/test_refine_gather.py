"""Light sampled finely enough and gathered where a vertex stands for much surface, in pure
numpy: the refinement of long triangles, the plain ray caster, and the gather by rays."""

import numpy as np
import pytest

from cubegi.cubegi_engine import gather, rays, refine, sh
from cubegi.cubegi_engine.scene import SceneArrays, triangle_areas


def _quad(z, size=4.0, up=True):
    pts = np.array([[0, 0, z], [size, 0, z], [size, size, z], [0, size, z]], dtype=float)
    tris = np.array([[0, 1, 2], [0, 2, 3]]) if up else np.array([[0, 2, 1], [0, 3, 2]])
    return pts, tris


def _scene(parts, sheet=()):
    """A SceneArrays of ``parts`` (points, triangles, albedo), one object each; the objects
    named in ``sheet`` get their back side (twins), as the scene reader gives them."""
    pts, nrm, alb, tri, obj, back = [], [], [], [], [], []
    n = 0
    for k, (p, t, a) in enumerate(parts):
        e = np.cross(p[t[0, 1]] - p[t[0, 0]], p[t[0, 2]] - p[t[0, 0]])
        normal = np.tile(e / np.linalg.norm(e), (len(p), 1))
        albedo = np.tile(a, (len(p), 1))
        if k in sheet:
            p, t = np.concatenate([p, p]), np.concatenate([t, t[:, ::-1] + len(p)])
            normal, albedo = np.concatenate([normal, -normal]), np.concatenate([albedo, albedo])
            b = np.r_[np.zeros(len(p) // 2, bool), np.ones(len(p) // 2, bool)]
        else:
            b = np.zeros(len(p), bool)
        pts.append(p), nrm.append(normal), alb.append(albedo), tri.append(t + n), obj.append(np.full(len(p), k)), back.append(b)
        n += len(p)
    points = np.concatenate(pts)
    return SceneArrays(points, np.concatenate(nrm), np.concatenate(alb), np.zeros_like(points), np.concatenate(tri),
                       point_object=np.concatenate(obj), back=np.concatenate(back) if sheet else None,
                       object_names=[f"o{k}" for k in range(len(parts))])


def test_refining_keeps_every_point_the_surface_and_the_sheets_twins():
    floor = _quad(0.0)
    card = _quad(1.0, size=2.0)
    scene = _scene([(*floor, (0.5, 0.5, 0.5)), (*card, (0.8, 0.2, 0.1))], sheet=(1,))
    scene.gathered = np.zeros(len(scene.points), bool)
    scene.gathered[0] = True
    out, moved = refine.refine(scene, 1.0)
    # Every old point is where it was, with what it had; the new ones lie on their triangles.
    for name in ("points", "normals", "albedo"):
        assert np.array_equal(getattr(out, name)[moved], getattr(scene, name))
    assert np.array_equal(out.back[moved], scene.back) and out.gathered[moved[0]] and out.gathered.sum() == 1
    # No triangle longer than asked; each object's front and back area as before.
    p = out.points[out.triangles]
    assert np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2).max() <= 1.0 + 1e-9
    area = triangle_areas(out.points, out.triangles)
    owner, side = out.point_object[out.triangles[:, 0]], out.back[out.triangles[:, 0]]
    assert [area[(owner == k) & (side == b)].sum() for k, b in ((0, False), (1, False), (1, True))] == pytest.approx([16, 4, 4])
    # The sheet's layout holds (own points, then their twins in the same order).
    sheets = out.sheets()
    b = np.flatnonzero(out.back)
    assert np.allclose(out.points[sheets.twins[b]], out.points[b]) and np.allclose(out.normals[sheets.twins[b]], -out.normals[b])
    # Triangles keep their winding (their normal along their points').
    e = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert (np.einsum("ij,ij->i", e, out.normals[out.triangles[:, 0]]) > 0).all()


def test_a_triangle_is_among_others_with_its_corners_in_any_order():
    rng = np.random.default_rng(5)
    triangles = rng.integers(0, 50, (3000, 3))
    others = np.concatenate([np.roll(triangles[:400], 1, axis=1), triangles[400:800, ::-1], rng.integers(50, 90, (300, 3))])
    found = refine._among(triangles, others)
    wanted = {tuple(sorted(t)) for t in others.tolist()}
    assert found.tolist() == [tuple(sorted(t)) in wanted for t in triangles.tolist()]
    assert found[:800].all() and not refine._among(triangles, others[:0]).any()


def test_refining_leaves_a_scene_of_short_triangles_as_it_is():
    scene = _scene([(*_quad(0.0, size=0.5), (0.5, 0.5, 0.5))])
    out, moved = refine.refine(scene, 1.0)
    assert out is scene and np.array_equal(moved, np.arange(len(scene.points)))


def test_the_refinement_budget_holds_a_huge_low_poly_scene():
    scene = _scene([(*_quad(0.0, size=1000.0), (0.5, 0.5, 0.5))])
    out, _ = refine.refine(scene, 0.01)  # 100,000 cuts a side, were it not held
    assert len(out.points) - len(scene.points) <= refine.MAX_NEW_SHARE * len(scene.points) + refine.MIN_NEW_POINTS


def test_the_numpy_caster_finds_the_nearest_triangle_and_its_side():
    lower, upper = _quad(0.0), _quad(1.0, up=False)
    pts = np.concatenate([lower[0], upper[0]])
    tri = np.concatenate([lower[1], upper[1] + 4])
    caster = rays.NumpyRays(pts, tri)
    origins = np.array([[1.0, 1.0, 0.5], [1.0, 1.0, 0.5], [3.0, 1.0, 2.0], [9.0, 9.0, 0.5]])
    dirs = np.array([[0, 0, 1.0], [0, 0, -1.0], [0, 0, -1.0], [0, 0, 1.0]])
    hits = caster.cast(origins, dirs)
    assert hits.t[:3] == pytest.approx([0.5, 0.5, 1.0]) and np.isinf(hits.t[3]) and hits.triangle[3] == -1
    assert hits.front.tolist()[:3] == [True, True, False]  # the upper quad faces down; the lower up
    x = np.einsum("nk,nkc->nc", hits.bary[:3], pts[tri[hits.triangle[:3]]])
    assert np.allclose(x, origins[:3] + hits.t[:3, None] * dirs[:3])
    assert caster.cast(origins[:1], dirs[:1], reach=np.array([0.4])).triangle[0] == -1


def test_a_gathered_point_under_an_open_sky_sees_it_all_and_under_a_roof_sees_the_roof():
    """A floor alone: its corner's rays all leave (unit sky light 1, nothing hit). Under a roof
    facing it, the same point's rays all meet the roof, whose light it takes whole."""
    floor = _scene([(*_quad(0.0), (0.5, 0.5, 0.5))])
    caster = rays.NumpyRays(floor.points, floor.triangles)
    g = gather.gather(floor, np.array([0]), caster, rays=64)
    assert g.sky[0] == pytest.approx([1.0, 1.0, 1.0]) and g.near.share[0] == pytest.approx(0.0) and len(g.near.hit_row) == 0
    roof = _quad(0.01, size=40.0, up=False)
    roof = (roof[0] - [18.0, 18.0, 0.0], roof[1])
    both = _scene([(*_quad(0.0), (0.5, 0.5, 0.5)), (*roof, (0.9, 0.9, 0.9))])
    g = gather.gather(both, np.array([0]), rays.NumpyRays(both.points, both.triangles), rays=64)
    assert g.sky[0] == pytest.approx([0.0, 0.0, 0.0], abs=1e-12) and g.near.share[0] == pytest.approx(1.0)
    radiance = np.zeros((len(both.points), 3))
    radiance[4:] = [0.2, 0.4, 0.6]
    assert g.near.gather(radiance)[0] == pytest.approx([0.2, 0.4, 0.6])
    # The probes' light is all taken away: its basis is the point's diffuse basis.
    assert np.allclose(g.near.open_basis[0], sh.diffuse_basis(both.normals[0]))


def test_a_gathered_point_facing_a_sheets_back_takes_its_twins_light():
    """A card seen from behind: its back side is its twin's front, whose light the ray takes."""
    floor = _quad(0.0)
    card = _quad(0.01, size=40.0)  # faces up: the floor's point sees its back
    card = (card[0] - [18.0, 18.0, 0.0], card[1])
    scene = _scene([(*floor, (0.5, 0.5, 0.5)), (*card, (0.9, 0.9, 0.9))], sheet=(1,))
    caster = gather.scene_caster(scene, renderer=None)
    g = gather.gather(scene, np.array([0]), caster, rays=32)
    radiance = np.zeros((len(scene.points), 3))
    radiance[scene.back] = [1.0, 2.0, 3.0]  # the card's underside
    assert g.near.gather(radiance)[0] == pytest.approx([1.0, 2.0, 3.0])


def test_the_sun_is_seen_from_a_gathered_point_unless_a_roof_is_in_the_way():
    from cubegi.cubegi_engine.lights import Light

    floor = _scene([(*_quad(0.0), (0.5, 0.5, 0.5))])
    sun = Light("SUN", np.ones(3), np.zeros(3), np.array([0.0, 0.0, -1.0]))
    g = gather.gather(floor, np.array([0, 2]), rays.NumpyRays(floor.points, floor.triangles), rays=8)
    assert gather.light_visibility(g, rays.NumpyRays(floor.points, floor.triangles), sun) == pytest.approx([1.0, 1.0])
    roof = _quad(1.0, size=1.0)  # over the point at the origin only
    both = _scene([(*_quad(0.0), (0.5, 0.5, 0.5)), (*roof, (0.5, 0.5, 0.5))])
    caster = rays.NumpyRays(both.points, both.triangles)
    g = gather.gather(both, np.array([0, 2]), caster, rays=8)
    assert gather.light_visibility(g, caster, sun) == pytest.approx([0.0, 1.0])


def test_only_points_that_stand_for_much_more_surface_than_most_are_gathered():
    big = _quad(0.0, size=10.0)
    fine = np.stack(np.meshgrid(np.linspace(20, 21, 41), np.linspace(0, 1, 41), [0.0], indexing="ij"), -1).reshape(-1, 3)
    idx = np.arange(41 * 41).reshape(41, 41)
    t = np.concatenate([np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:]], -1).reshape(-1, 3),
                        np.stack([idx[:-1, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 3)])
    scene = _scene([(*big, (0.5, 0.5, 0.5)), (fine, t, (0.5, 0.5, 0.5))])
    assert np.flatnonzero(gather.large_points(scene)).tolist() == [0, 1, 2, 3]
    even = _scene([(fine, t, (0.5, 0.5, 0.5))])  # an evenly cut mesh: none stands out
    assert not gather.large_points(even).any()


def test_a_cut_panels_form_factor_is_its_outlines_for_receivers_whose_plane_crosses_it():
    """A flat emitter cut 4 x 4: for receivers whose tangent plane crosses it (clipped to
    their hemispheres), its outline clipped whole gives the sum of its 32 triangles' form
    factors."""
    from cubegi.cubegi_engine import emitters

    n = 4
    g = np.linspace(0.0, 1.0, n + 1)
    verts = np.array([(x, y, 1.0) for y in g for x in g])
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    tris = np.concatenate([np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:]], -1).reshape(-1, 3),
                           np.stack([idx[:-1, :-1], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 3)])
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-1, 2, 200), rng.uniform(-1, 2, 200), rng.uniform(0.0, 2.0, 200)])
    normals = rng.normal(size=(200, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    whole = emitters._group_ff(points, normals, tris, verts[tris])
    by_triangle = sum(emitters._two_sided_ff(points, normals, verts[t]) for t in tris)
    height = normals @ verts.T - np.einsum("sc,sc->s", normals, points)[:, None]
    crossed = (height.min(axis=1) < 0) & (height.max(axis=1) > 0)
    assert crossed.sum() > 50
    assert whole == pytest.approx(np.clip(by_triangle, 0, None), abs=1e-9)


def test_a_cut_sheets_points_do_not_rest_on_its_own_other_side():
    """A sheet cut finely has points on its triangles' edges that are not its twins' own:
    none of them counts as lying on another surface (its back side is its own)."""
    from cubegi.cubegi_engine import spatial

    scene = _scene([(*_quad(0.0), (0.5, 0.5, 0.5))], sheet=(0,))
    out, _ = refine.refine(scene, 0.3)
    front = np.flatnonzero(~out.back)
    assert len(front) > 80
    assert not spatial.resting(out.points, out.normals, out.triangles, out.scale, front, out.sheets()).any()


def test_a_vertex_covered_by_what_it_rests_on_is_not_gathered_and_one_only_touched_is():
    """A floor whose every corner lies under a slab facing it (a plinth's footprint): no
    point is gathered, and nothing fails. A floor corner that another surface, facing the
    other way in the same plane, only touches along an edge is gathered (its corners,
    nudged into its face, are open)."""
    floor = _quad(0.0)
    slab = _quad(0.0, up=False)  # the same square, facing down: over every floor corner
    scene = _scene([(*floor, (0.5, 0.5, 0.5)), (*slab, (0.5, 0.5, 0.5))])
    g = gather.gather(scene, np.arange(4), rays.NumpyRays(scene.points, scene.triangles), rays=8)
    assert g.count == 0 and g.sky.shape == (0, 3)
    beside = _quad(0.0, up=False)
    beside = (beside[0] + [4.0, 0.0, 0.0], beside[1])  # shares the floor's edge x = 4
    scene = _scene([(*floor, (0.5, 0.5, 0.5)), (*beside, (0.5, 0.5, 0.5))])
    g = gather.gather(scene, np.array([1]), rays.NumpyRays(scene.points, scene.triangles), rays=8)
    assert g.rows.tolist() == [1] and g.sky[0] == pytest.approx([1.0, 1.0, 1.0])


def test_triangles_at_a_gathered_point_are_cut_finer_and_their_count_is_kept():
    """A triangle with a gathered corner is cut GATHERED_CELLS of a cell apart (half its
    corner's rays meet the surfaces at its feet), the others SAMPLE_CELLS; the front
    triangles each object gained are kept for the probes' budget."""
    from cubegi.cubegi_engine.grid import ProbeGrid

    floor = _quad(0.0, size=12.0)
    wall = _quad(1.0, size=12.0)
    scene = _scene([(*floor, (0.5, 0.5, 0.5)), (*wall, (0.5, 0.5, 0.5))], sheet=(1,))
    grid = ProbeGrid((-1.0, -1.0, -1.0), (13.0, 13.0, 13.0), (8, 8, 8))  # cells of 2 m
    cell = float(grid.point_cell_edge(np.zeros((1, 3)))[0])
    plain, _ = refine.refine_for_grid(scene, grid)
    scene.gathered = np.zeros(len(scene.points), bool)
    scene.gathered[0] = True  # a floor corner
    out, moved = refine.refine_for_grid(scene, grid)
    p = out.points[out.triangles]
    edge = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2).max(axis=1)
    owner = out.point_object[out.triangles[:, 0]]
    assert edge[owner == 0].max() <= refine.GATHERED_CELLS * cell + 1e-9
    assert refine.GATHERED_CELLS * cell < edge[owner == 1].max() <= refine.SAMPLE_CELLS * cell + 1e-9
    assert plain.sampled_triangles[0] < out.sampled_triangles[0]
    front = ~out.back[out.triangles[:, 0]]
    assert np.array_equal(out.sampled_triangles, np.bincount(owner[front], minlength=2) - [2, 2])


def test_a_hit_takes_only_the_corners_it_sees_along_its_triangle():
    """A floor triangle runs under a wall standing on it (x = 2): a hit on the near side takes
    its near corners' light, made whole, not the far corner's (outside, in the sun); a corner
    on the wall's foot is seen; a hit that sees no corner keeps them all."""
    floor = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [0.0, 4.0, 0.0], [2.0, 0.0, 0.0]])
    wall = np.array([[2.0, -1.0, 0.0], [2.0, 5.0, 0.0], [2.0, 5.0, 2.0], [2.0, -1.0, 2.0]])
    points = np.concatenate([floor, wall])
    caster = rays.NumpyRays(points, np.array([[0, 1, 2], [4, 5, 6], [4, 6, 7]]))
    bary = np.array([[0.5, 0.25, 0.25], [0.5, 0.25, 0.25]])
    got = gather._seen_corners(caster, points, np.array([[0, 1, 2], [0, 3, 2]]), np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0]]), bary, 4.0)
    assert got[0] == pytest.approx([2 / 3, 0.0, 1 / 3])  # the far corner left out, the rest made whole
    assert got[1] == pytest.approx(bary[1])  # its corner (2, 0, 0) stands at the wall's foot: seen
    boxed = gather._seen_corners(caster, points, np.array([[1, 1, 1]]), np.array([[1.0, 1.0, 0.0]]), bary[:1], 4.0)
    assert boxed[0] == pytest.approx(bary[0])  # no corner seen: all kept


def _patch(lo, u, v, n, up):
    """An ``n x n`` grid of squares from corner ``lo`` along ``u`` and ``v``, facing along
    ``u x v`` (or against it unless ``up``)."""
    g = np.linspace(0.0, 1.0, n + 1)
    pts = np.array([np.add(lo, a * np.asarray(u) + b * np.asarray(v)) for b in g for a in g], dtype=float)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    tris = np.concatenate([np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:]], -1).reshape(-1, 3),
                           np.stack([idx[:-1, :-1], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 3)])
    return pts, tris if up else tris[:, ::-1]


def test_surfaces_close_to_an_emitter_are_cut_as_fine_as_the_gap_and_its_light_stays_as_modelled():
    """A lamp's quad (0.5 m in 25 cm squares) 1 cm under a ceiling of 25 cm squares, a floor
    2 m below: the ceiling's triangles by the lamp, and the lamp's own, are cut until each
    lies farther from the other than NEAR_EMITTER of its longest edge, or is 2 EMITTER_CELLS
    of a cell long; the floor is left as it is. The lamp's light is its triangles' as
    modelled (the same at every point as before the cut; its pieces do not count again), and
    an object that starts to emit later (an edit of its material) emits as any."""
    from cubegi.cubegi_engine import emitters
    from cubegi.cubegi_engine.grid import ProbeGrid

    ceiling = _patch((0.0, 0.0, 2.0), (0, 4, 0), (4, 0, 0), 16, up=True)  # faces down
    lamp = _patch((1.75, 1.75, 1.99), (0, 0.5, 0), (0.5, 0, 0), 2, up=True)  # faces down
    floor = _patch((0.0, 0.0, 0.0), (4, 0, 0), (0, 4, 0), 4, up=True)
    scene = _scene([(*ceiling, (0.8, 0.8, 0.8)), (*lamp, (0.8, 0.8, 0.8)), (*floor, (0.5, 0.5, 0.5))])
    scene.emission[scene.point_object == 1] = (5.0, 5.0, 5.0)
    grid = ProbeGrid((0.0, 0.0, 0.0), (4.0, 4.0, 2.0), (16, 16, 8))  # cells of 25 cm
    cell = 0.25
    out, moved = refine.refine_near_emitters(scene, grid)
    assert np.array_equal(out.points[moved], scene.points)

    p = out.points[out.triangles]
    longest = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2).max(axis=1)
    centre = p.mean(axis=1)
    owner = out.point_object[out.triangles[:, 0]]
    s = np.linspace(0.0, 1.0, 101)  # the lamp and the ceiling over it sampled every 5 mm
    lamp_at = np.array([(1.75 + 0.5 * a, 1.75 + 0.5 * b, 1.99) for a in s for b in s])
    over_at = np.array([(1.5 + a, 1.5 + b, 2.0) for a in s for b in s])
    for mine, other in ((0, lamp_at), (1, over_at)):
        sel = np.flatnonzero(owner == mine)
        near = np.linalg.norm(centre[sel] - other.mean(axis=0), axis=1) < 1.5  # (the rest lies metres away)
        dist = np.full(len(sel), np.inf)
        dist[near] = [np.linalg.norm(other - c, axis=1).min() + 3.6e-3 for c in centre[sel[near]]]
        fine = longest[sel] <= 2.0 * refine.EMITTER_CELLS * cell + 1e-9
        assert np.all(fine | (dist > refine.NEAR_EMITTER * longest[sel])), mine
        assert fine.sum() >= 32  # cut down to the finest by the gap
    assert (owner == 0).sum() > 2 * 16 * 16 and (owner == 1).sum() > 8
    assert (owner == 2).sum() == 2 * 4 * 4  # the floor, 2 m away, as modelled

    corners, radiance = emitters.emissive_triangles(out)
    before, _ = emitters.emissive_triangles(scene)
    assert len(corners) == len(before) == 8 and np.allclose(np.sort(out.points[corners].reshape(-1, 9), axis=0),
                                                            np.sort(scene.points[before].reshape(-1, 9), axis=0))
    assert radiance == pytest.approx(5.0)
    light = emitters.emitter_direct(out, None, 0, shadows=False)[moved]
    assert light[scene.point_object == 2].min() > 0
    assert light == pytest.approx(emitters.emitter_direct(scene, None, 0, shadows=False), rel=5e-3, abs=1e-9)

    out.emission[out.point_object == 2] = (1.0, 1.0, 1.0)  # the floor glows after the bake
    corners, _ = emitters.emissive_triangles(out)
    assert len(corners) == 8 + 2 * 4 * 4


def _lamp_under_a_ceiling(lamp_z=1.99, squares=16):
    ceiling = _patch((0.0, 0.0, 2.0), (0, 4, 0), (4, 0, 0), squares, up=True)  # faces down
    lamp = _patch((1.75, 1.75, lamp_z), (0, 0.5, 0), (0.5, 0, 0), 2, up=True)
    scene = _scene([(*ceiling, (0.8, 0.8, 0.8)), (*lamp, (0.8, 0.8, 0.8))])
    scene.emission[scene.point_object == 1] = (5.0, 5.0, 5.0)
    return scene


def test_cuts_by_an_emitter_keep_the_arrays_they_cut_and_spare_a_panel_in_its_ceilings_plane(monkeypatch):
    """The arrays cut by an emitter keep the fingerprint of the arrays they were cut from,
    which the same geometry with the lamp dark (not cut) has too: an update tells an edit
    that lit or darkened a lamp close to a surface from one that changed the geometry. A
    panel set into its ceiling's plane lights nothing in front of it there, so nothing is
    cut; a budget too small for every cut the gap asks still cuts the triangles nearest the
    lamp."""
    from cubegi.cubegi_engine.grid import ProbeGrid

    grid = ProbeGrid((0.0, 0.0, 0.0), (4.0, 4.0, 2.0), (16, 16, 8))
    scene = _lamp_under_a_ceiling()
    lit, _ = refine.refine_near_emitters(scene, grid)
    dark = _lamp_under_a_ceiling()
    dark.emission[:] = 0.0  # the lamp switched off
    plain, _ = refine.refine_near_emitters(dark, grid)
    assert len(lit.points) > len(scene.points) == len(plain.points)
    assert not lit.fingerprint().same_geometry(plain.fingerprint()) and lit.cut_from.same_geometry(plain.cut_from)
    moved = _lamp_under_a_ceiling()
    moved.points[moved.point_object == 1, 0] += 0.1
    assert not refine.refine_near_emitters(moved, grid)[0].cut_from.same_geometry(lit.cut_from)

    flush, _ = refine.refine_near_emitters(_lamp_under_a_ceiling(lamp_z=2.0), grid)
    assert len(flush.points) == len(scene.points)

    monkeypatch.setattr(refine, "MAX_NEW_SHARE", 0.05)
    monkeypatch.setattr(refine, "MIN_NEW_POINTS", 0)
    small = _lamp_under_a_ceiling(squares=64)  # 6 cm squares: 49 ceiling squares over the lamp alone
    out, _ = refine.refine_near_emitters(small, grid)
    assert len(small.points) < len(out.points) <= 1.05 * len(small.points)
