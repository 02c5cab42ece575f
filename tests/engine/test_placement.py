"""Probes inside geometry, found before the capture: moved out within their cells, or left out."""

import numpy as np

from cubegi.cubegi_engine import placement, spatial
from cubegi.cubegi_engine.grid import ProbeGrid, ProbeSubset
from cubegi.cubegi_engine.rays import NumpyRays


def _box(lo, hi, inward=False):
    """A closed box's 12 triangles (outward normals, or inward): ``(points (8, 3), triangles (12, 3))``."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    pts = np.array([[x, y, z] for z in (lo[2], hi[2]) for y in (lo[1], hi[1]) for x in (lo[0], hi[0])])
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]  # outward
    tris = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    return pts, (tris[:, ::-1] if inward else tris)


def _grid():
    return ProbeGrid((-1.5, -1.5, -1.5), (1.5, 1.5, 1.5), (3, 3, 3))  # unit cells, centre probe at the origin


def test_a_probe_inside_a_small_block_moves_out_within_its_cell():
    pts, tris = _box((-0.3, -0.25, -0.2), (0.3, 0.25, 0.2))
    got = placement.place(_grid(), pts, tris)
    centre = 13
    assert got.moved == 1 and got.left_out == 0 and got.keep.all()
    assert np.count_nonzero(np.any(got.displacement != 0, axis=1)) == 1
    new = _grid().positions()[centre] + got.displacement[centre]
    assert (np.abs(got.displacement[centre]) <= placement.MAX_SHIFT + 1e-12).all()
    outside = np.any((new < [-0.3, -0.25, -0.2]) | (new > [0.3, 0.25, 0.2]))
    assert outside, new
    # Clear of the block's surface by about MARGIN of a cell (MARGIN along the ray it left by).
    gap = np.max(np.maximum(np.abs(new) - [0.3, 0.25, 0.2], 0.0))
    assert gap >= 0.5 * placement.MARGIN
    # A subset of the grid carries the move: its probe stands there; weights are the cell's.
    sub = ProbeSubset(_grid(), got.keep, got.displacement)
    np.testing.assert_allclose(sub.positions()[centre], new)
    assert sub.moved == 1
    i0, w0 = _grid().trilinear(np.array([[0.1, 0.2, 0.3]]))
    i1, w1 = sub.trilinear(np.array([[0.1, 0.2, 0.3]]))
    np.testing.assert_array_equal(i0, i1)
    np.testing.assert_allclose(w0, w1)


def test_a_probe_inside_a_thin_wall_stops_where_it_has_the_most_room():
    """A 4 cm slab through the grid's centre probe, in an open cell: the probe leaves through
    a face and goes on to the farthest stop (BEYOND) in its cell, not a tenth of a cell from
    the wall it was inside (where the wall fills half of what it sees)."""
    pts, tris = _box((-0.02, -1.4, -1.4), (0.02, 1.4, 1.4))
    got = placement.place(_grid(), pts, tris)
    assert got.moved >= 1 and got.keep[13]
    x = abs(got.displacement[13][0])
    assert x - 0.02 > placement.MARGIN + 0.15, got.displacement[13]  # beyond the first stop
    assert np.all(np.abs(got.displacement[13]) <= placement.MAX_SHIFT + 1e-12)


def test_a_probe_deep_in_a_block_with_no_way_out_in_its_cell_is_left_out():
    pts, tris = _box((-0.8, -0.8, -0.8), (0.8, 0.8, 0.8))
    got = placement.place(_grid(), pts, tris)
    assert got.moved == 0 and got.left_out == 1
    assert not got.keep[13] and got.keep.sum() == 26


def test_probes_in_the_open_or_in_a_room_stay_where_they_are():
    pts, tris = _box((-1.4, -1.4, -1.4), (1.4, 1.4, 1.4), inward=True)  # a room around every probe
    got = placement.place(_grid(), pts, tris)
    assert got.moved == 0 and got.left_out == 0 and got.keep.all() and not got.displacement.any()
    asked = np.zeros(27, dtype=bool)
    asked[:5] = True  # only these are candidates (the rest light no point)
    got = placement.place(_grid(), *_box((5, 5, 5), (6, 6, 6)), candidates=asked)
    np.testing.assert_array_equal(got.keep, asked)


def test_when_every_probe_reads_as_inside_none_is_moved_or_left_out():
    # The room's normals turned outward (a mesh with flipped normals): every probe sees back faces.
    pts, tris = _box((-1.4, -1.4, -1.4), (1.4, 1.4, 1.4), inward=False)
    grid = ProbeGrid((-1.5, -1.5, -1.5), (1.5, 1.5, 1.5), (2, 2, 2))
    t, back, _ = placement.trace(grid.positions(), placement.VoxelIndex(*(pts[tris[:, k]] for k in range(3)), 1.5),
                              np.full(8, 1.5))
    assert placement.inside(t, back).all()
    got = placement.place(grid, pts, tris)
    assert got.keep.all() and got.moved == 0 and got.left_out == 0


def test_objects_under_a_texel_from_every_probe_are_small():
    from cubegi.cubegi_engine.bake import small_objects

    cube = _box((-0.005, -0.005, -0.005), (0.005, 0.005, 0.005))
    pts = np.concatenate([cube[0] + [1.0, 0.0, 0.0], cube[0] * 10 + [1.0, 0.0, 0.0], cube[0] + [0.02, 0.0, 0.0]])
    tris = np.concatenate([cube[1], cube[1] + 8, cube[1] + 16])
    owner = np.repeat([0, 1, 2], 12)
    probes = np.zeros((1, 3))
    # 16^2: a texel spans 0.125 rad. 1.7 cm at 1 m: small; 17 cm at 1 m: not; 1.7 cm at 2 cm: not.
    assert small_objects(pts, tris, owner, probes, 16).tolist() == [True, False, False]
    # 256^2: a texel spans 0.0078 rad: the 1.7 cm cube at 1 m spans two.
    assert small_objects(pts, tris, owner, probes, 256).tolist() == [False, False, False]
    assert small_objects(pts, tris, None, probes, 16).tolist() == []


def test_a_crowded_probe_is_asked_through_the_hosts_caster_and_left_out_not_moved(monkeypatch):
    """The voxel index leaves out as crowded a probe with more than MAX_NEARBY triangles
    around it (here 4: the block's 12 are too many), so its rays meet nothing and it reads
    as outside. Through the host's caster it is found inside the block and left out; it is
    not moved (a crowded probe's ways out are not trusted), and the probes around it, also
    crowded, are found outside and kept."""
    monkeypatch.setattr(spatial, "MAX_NEARBY", 4)
    pts, tris = _box((-0.3, -0.25, -0.2), (0.3, 0.25, 0.2))
    index = placement.VoxelIndex(*(pts[tris[:, k]] for k in range(3)), 1.0)
    _, back, crowded = placement.trace(_grid().positions(), index, np.ones(27))
    assert crowded[13] and not back[13].any()
    got = placement.place(_grid(), pts, tris)
    assert got.keep.all() and got.moved == 0 and got.left_out == 0  # unseen
    got = placement.place(_grid(), pts, tris, rays=lambda: placement.HostRays(NumpyRays(pts, tris)))
    assert not got.keep[13] and got.keep.sum() == 26
    assert got.moved == 0 and got.left_out == 1 and got.crowded == 1 and not got.displacement.any()


def test_the_hosts_caster_meets_a_two_sided_sheet_from_behind_as_its_twins_front():
    """A probe under a one-sided quad facing up meets its back face; where the quad is a
    two-sided object's (its twin stands there, facing down), the probe meets a front face."""
    pts = np.array([[-1.0, -1.0, 0.2], [1.0, -1.0, 0.2], [1.0, 1.0, 0.2], [-1.0, 1.0, 0.2]])
    tris = np.array([[0, 1, 2], [0, 2, 3]])  # counter-clockwise from above: facing up
    up = np.array([[0.0, 0.0, 1.0]])
    for sheet, backs in ((None, True), (np.array([True, True]), False)):
        t, back = placement.HostRays(NumpyRays(pts, tris), sheet).trace(np.zeros((1, 3)), np.ones(1), up)
        assert back[0, 0] == backs and abs(t[0, 0] - 0.2) < 1e-9
