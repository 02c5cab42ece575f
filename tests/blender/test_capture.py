"""GPU capture on llvmpipe: face orientation, occlusion, and the paper's draw-every-bounce
path against the capture-once linear path."""

import importlib
import time

import bpy
import numpy as np
import pytest
import scenes

from cubegi.cubegi_engine import capture, cubemap, transport
from cubegi.cubegi_engine.grid import ProbeGrid


def _collect_and_renderer(cubegi):
    scene_data = importlib.import_module("cubegi.cubegi_addon.scene_data")
    gpu_capture = importlib.import_module("cubegi.cubegi_addon.gpu_capture")
    collected = scene_data.collect(bpy.context)
    arrays = collected.arrays
    return arrays, gpu_capture.GpuRenderer(arrays.points, arrays.triangles)


def test_every_texel_looks_where_it_should(empty_scene, cubegi):
    # A closed, finely cut box around an off-centre eye; the colour of each surface point is
    # its world position, so a texel's colour minus the eye is the direction it looks in.
    v, f = scenes.box_mesh((-3.0, -2.0, -1.5), (2.0, 4.0, 2.5), (10, 12, 8), inward=True)
    scenes.mesh_object("Box", v, f)
    arrays, renderer = _collect_and_renderer(cubegi)
    eye = np.array([0.3, -0.4, 0.2])
    n = 16
    vps = cubemap.cube_view_projections(eye, 0.01, 50.0)
    colour = renderer.render_colour(vps, n, arrays.points).reshape(6, n, n, 3)
    want = cubemap.texel_directions(n)
    got = colour - eye
    got /= np.linalg.norm(got, axis=-1, keepdims=True)
    # Within a texel: the largest texel's half diagonal subtends under 2.6 degrees at n = 16.
    angle = np.degrees(np.arccos(np.clip((got * want).sum(-1), -1, 1)))
    assert angle.max() < 2.6, f"worst texel off by {angle.max():.2f} degrees"

    # The id path: hit point from triangle and barycentric weights, and its distance.
    cap = cubemap.capture_cubes(renderer, eye[None], n, 0.01, 50.0)
    assert (cap.tid >= 0).all() and not cap.backface.any()
    # Each texel names the triangle it sees: its point lies inside it (a neighbour's weights
    # of the same plane would reach past the corners).
    assert cap.bary.min() > -1e-4 and cap.bary.max() < 1.0 + 1e-4
    hit = np.einsum("...c,...cx->...x", cap.bary[0], arrays.points[arrays.triangles[cap.tid[0]]])
    d = hit - eye
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), cap.dist[0], rtol=1e-4)
    cos = (d / np.linalg.norm(d, axis=-1, keepdims=True) * want).sum(-1)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 2.6


def test_depth_test_keeps_the_nearest_surface(empty_scene, cubegi):
    # A thin wall at x = 1 in front of the box's far wall at x = 3: every texel of the +X
    # face that sees the wall must report the wall, not what is behind it.
    v, f = scenes.box_mesh((-3.0, -3.0, -3.0), (3.0, 3.0, 3.0), (4, 4, 4), inward=True)
    scenes.mesh_object("Box", v, f)
    wv, wf = scenes.grid_patch((1.0, -1.0, -1.0), (0, 0, 2.0), (0, 2.0, 0), 2, 2)  # faces -X
    scenes.mesh_object("Wall", wv, wf)
    arrays, renderer = _collect_and_renderer(cubegi)
    cap = cubemap.capture_cubes(renderer, np.zeros((1, 3)), 32, 0.01, 50.0)
    dirs = cubemap.texel_directions(32)[0]
    through_wall = (np.abs(dirs[..., 1] / dirs[..., 0]) < 0.99) & (np.abs(dirs[..., 2] / dirs[..., 0]) < 0.99)
    expected = 1.0 / dirs[..., 0]
    np.testing.assert_allclose(cap.dist[0, 0][through_wall], expected[through_wall], rtol=1e-4)
    assert not cap.backface[0, 0][through_wall].any()


def test_draw_every_bounce_matches_capture_once(empty_scene, cubegi):
    # The paper's way (draw the lit scene, project the images) against the linear path
    # (gather from the id capture, project): same probe coefficients.
    v, f = scenes.box_mesh((-2.0, -2.0, 0.0), (2.0, 2.0, 2.5), (8, 8, 5), inward=True)
    scenes.mesh_object("Room", v, f)
    bv, bf = scenes.box_mesh((-0.5, -0.3, 0.0), (0.4, 0.6, 0.9), (2, 2, 2), inward=False)
    scenes.mesh_object("Block", bv, bf)
    arrays, renderer = _collect_and_renderer(cubegi)
    rng = np.random.default_rng(3)
    radiance = rng.random((len(arrays.points), 3))
    g = ProbeGrid((-2, -2, 0), (2, 2, 2.5), (3, 3, 2))
    near, far = cubemap.clip_planes(arrays.scale)
    n = 32
    cap = cubemap.capture_cubes(renderer, g.positions(), n, near, far)
    # Without the visibility test no point is covered, so every texel mixes its triangle's
    # corners as the rasterizer does (with it, the floor under the block is covered, and its
    # triangles are seen by their other corners: visibility.seen_corners_only).
    operators = transport.Transport(arrays, g, cap, visibility=False)
    assert not operators.covered.any()
    linear = operators.project(operators.texel_radiance(radiance))
    drawn = capture.reference_coefficients(renderer, g, arrays, radiance, n, near, far)
    scale = np.abs(drawn[:, 0]).mean()
    # Both sample the same surfaces at the same texel centres; they differ only by float32
    # rounding and rasterisation at triangle edges (a texel on an edge may pick either).
    assert np.abs(linear - drawn).max() < 5e-3 * scale
    assert np.abs(linear - drawn).mean() < 5e-4 * scale


def _room_and_block(cubegi):
    """A room with a block standing 2 cm over its floor, collected, its renderer, and a grid
    of 3 x 3 x 2 probes."""
    v, f = scenes.box_mesh((-2.0, -2.0, 0.0), (2.0, 2.0, 2.5), (8, 8, 5), inward=True)
    scenes.mesh_object("Room", v, f)
    bv, bf = scenes.box_mesh((-0.5, -0.3, 0.02), (0.4, 0.6, 0.9), (2, 2, 2), inward=False)
    scenes.mesh_object("Block", bv, bf)
    arrays, renderer = _collect_and_renderer(cubegi)
    return arrays, renderer, ProbeGrid((-2, -2, 0), (2, 2, 2.5), (3, 3, 2))


def test_the_tables_trace_the_near_field_beside_the_visibility_test_and_fail_whole(empty_scene, cubegi, monkeypatch):
    """The tables trace the near field's rays in a thread while they test which probes see each
    point: the near field is the one built after that test; an error in either reaches the
    caller, and a failed test stops the rays and waits for them (nothing of the failed tables
    runs on)."""
    nearfield = cubegi.cubegi_engine.nearfield
    arrays, renderer, g = _room_and_block(cubegi)
    near, far = cubemap.clip_planes(arrays.scale)
    cap = cubemap.capture_cubes(renderer, g.positions(), 16, near, far)
    tables = transport.Transport(arrays, g, cap)
    after = nearfield.build(arrays.points, arrays.normals, nearfield.NEAR_REACH * g.point_cell_edge(arrays.points), arrays.triangles,
                            hidden=tables.covered, owner=arrays.point_object, sheets=arrays.sheets(), keep_index=False,
                            emitting=np.any(arrays.emission > 0, axis=1))
    assert tables.near.count > 100 and tables.covered.any()  # the floor under the block
    for name in ("rows", "open_basis", "hit_row", "hit_corner", "hit_weight", "share", "hidden"):
        assert np.array_equal(getattr(tables.near, name), getattr(after, name)), name

    real_trace, ended = nearfield.trace, []

    def slow_trace(*args, **kwargs):
        try:
            time.sleep(0.3)
            return real_trace(*args, **kwargs)
        except BaseException as exc:
            ended.append(exc)
            raise

    def failing_test(*args, **kwargs):
        raise RuntimeError("the visibility test failed")

    monkeypatch.setattr(nearfield, "trace", slow_trace)
    monkeypatch.setattr(transport.Transport, "_seen_weights", failing_test)
    with pytest.raises(RuntimeError, match="visibility test failed"):
        transport.Transport(arrays, g, cap)
    # Its rays were stopped, and waited for: they had ended when the error came.
    assert len(ended) == 1 and isinstance(ended[0], cubegi.cubegi_engine.working.Cancelled)
    monkeypatch.undo()
    monkeypatch.setattr(nearfield, "trace", lambda *args, **kwargs: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        transport.Transport(arrays, g, cap)


def test_a_new_capture_traces_the_near_field_before_drawing_and_a_failed_one_waits_for_it(empty_scene, cubegi, monkeypatch):
    """A new capture's near field is traced from before the probes are drawn (the bake starts
    it after the suns' light): its tables take those rays (none traced again) and equal those
    that trace them themselves. A bake whose drawing fails stops those rays and hands on the
    error once their thread has ended."""
    nearfield, working, bake = cubegi.cubegi_engine.nearfield, cubegi.cubegi_engine.working, cubegi.cubegi_engine.bake
    arrays, renderer, g = _room_and_block(cubegi)
    settings = cubegi.cubegi_engine.settings.BakeSettings(cube_size=16)
    real_trace, calls = nearfield.trace, []
    monkeypatch.setattr(nearfield, "trace", lambda *a, **k: calls.append(1) or real_trace(*a, **k))
    early = working.run(capture.ProbeCapture.take_steps(arrays, g, renderer, settings,
                                                        tracing=capture.start_near_field(arrays, g, renderer, settings)))
    assert len(calls) == 1  # the tables took the rays handed to them
    own = capture.ProbeCapture.take(arrays, g, renderer, settings)
    assert len(calls) == 2
    monkeypatch.undo()
    assert early.transport.near.count > 100
    for name in ("rows", "open_basis", "hit_row", "hit_corner", "hit_weight", "share", "hidden"):
        assert np.array_equal(getattr(early.transport.near, name), getattr(own.transport.near, name)), name

    jobs = []

    def slow_trace(*args, **kwargs):
        time.sleep(0.5)
        return real_trace(*args, **kwargs)

    def failing_draw(*args, **kwargs):
        raise RuntimeError("the drawing failed")

    real_start = capture.start_near_field
    monkeypatch.setattr(nearfield, "trace", slow_trace)
    monkeypatch.setattr(bake, "start_near_field", lambda *a: jobs.append(real_start(*a)) or jobs[-1])
    monkeypatch.setattr(capture, "capture_cubes", failing_draw)
    with pytest.raises(RuntimeError, match="drawing failed"):
        working.run(bake.bake_steps(arrays, g, renderer, settings))
    # Started before the drawing, stopped, and waited for.
    (job,) = jobs
    assert not job.thread.is_alive() and isinstance(job.out.get("error"), working.Cancelled)


def test_culling_draws_what_drawing_everything_draws(empty_scene, cubegi):
    """A scene of many chunks (a finely cut box around a finely cut block): each view draws
    only the chunks whose box reaches into it, and sees what the whole scene drawn gives
    (ids, distances, colours); on average a view leaves out a quarter of the triangles or more."""
    gpu_capture = importlib.import_module("cubegi.cubegi_addon.gpu_capture")
    v, f = scenes.box_mesh((-3.0, -2.0, -1.5), (2.0, 4.0, 2.5), (40, 40, 40), inward=True)
    scenes.mesh_object("Box", v, f)
    v, f = scenes.box_mesh((-0.5, 0.5, -1.5), (0.5, 1.5, 0.5), (20, 20, 20), inward=False)
    scenes.mesh_object("Block", v, f)
    arrays, culled = _collect_and_renderer(cubegi)
    chunk = importlib.import_module("cubegi.cubegi_addon.draw_layout").CULL_CHUNK
    assert len(arrays.triangles) > 8 * chunk and culled.chunk_boxes is not None
    whole = gpu_capture.GpuRenderer(arrays.points, arrays.triangles)
    whole.chunk_boxes = None  # draws every triangle in every view
    eyes = np.array([[0.3, -0.4, 0.2], [-2.5, 3.5, 2.0], [1.5, -1.5, -1.0]])
    vps = cubemap.cube_view_projections_many(eyes, 0.01, 50.0)
    ranges = culled._ranges(culled._local(vps))
    drawn = np.array([sum(c for _, c in r) for r in ranges]) / (3 * len(arrays.triangles))
    assert drawn.mean() < 0.75 and drawn.min() < 0.3, drawn
    a = culled.render(vps, np.repeat(eyes, 6, axis=0), None, 32)
    b = whole.render(vps, np.repeat(eyes, 6, axis=0), None, 32)
    for got, want in zip(a, b):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(culled.render_colour(vps, 32, arrays.points), whole.render_colour(vps, 32, arrays.points))


def test_each_drawn_triangle_has_a_provoking_vertex_of_its_own(cubegi):
    """The id pass's layout (see gpu_capture): every triangle's last corner (or first) is a
    vertex no other triangle provokes, naming it; corners keep their positions and winding."""
    draw_layout = importlib.import_module("cubegi.cubegi_addon.draw_layout")
    v, f = scenes.box_mesh((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), (6, 5, 4), inward=True)
    tris = np.array([[q[0], q[k], q[k + 1]] for q in f for k in range(1, len(q) - 1)])
    for last in (True, False):
        indices, extra, owner = draw_layout.provoking_layout(tris, len(v), last)
        own = indices[:, 2 if last else 0]
        assert len(np.unique(own)) == len(tris)
        np.testing.assert_array_equal(owner[own], np.arange(len(tris)))
        assert len(extra) < len(tris)  # most triangles found a corner of their own
        source = np.concatenate([np.arange(len(v)), extra])[indices]
        turned = [np.roll(tris, -k, axis=1) for k in range(3)]
        assert all(any((source[i] == t[i]).all() for t in turned) for i in range(len(tris)))


def test_barycentric_weights_rebuild_each_point_s_projection_on_its_triangle(cubegi):
    """The weights the capture reports for a texel (its triangle's rows, made once per
    renderer): over the corners they give the point's projection on the triangle's plane
    (least squares, asked of numpy), and a third each on a triangle of no area."""
    draw_layout = importlib.import_module("cubegi.cubegi_addon.draw_layout")
    rng = np.random.default_rng(5)
    points = rng.uniform(-1.0, 1.0, (60, 3))
    points[59] = points[58]  # a triangle with two corners in one place
    tris = np.vstack([rng.permutation(58)[:57].reshape(19, 3), [[57, 58, 59]]])
    rows = draw_layout.barycentric_rows(points, tris)
    which = rng.integers(0, len(tris), 500)
    corners = points[tris[which]]  # (k, 3, 3)
    at = np.einsum("kj,kjc->kc", rng.dirichlet([1.0, 1.0, 1.0], 500), corners) + rng.normal(0.0, 0.05, (500, 3))
    got = draw_layout.barycentric(rows, which, at)
    for k in range(500):
        a, b, c = corners[k]
        if which[k] == len(tris) - 1:
            np.testing.assert_allclose(got[k], [1.0 / 3.0] * 3, atol=1e-6)
            continue
        w = np.linalg.lstsq(np.column_stack([b - a, c - a]), at[k] - a, rcond=None)[0]
        np.testing.assert_allclose(got[k], [1.0 - w.sum(), w[0], w[1]], atol=1e-4)


def test_a_renderer_with_nothing_to_draw_sees_nothing(cubegi):
    """Every triangle left out of the drawing (``drawn`` empty): every texel sees nothing."""
    gpu_capture = importlib.import_module("cubegi.cubegi_addon.gpu_capture")
    v, f = scenes.box_mesh((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), (2, 2, 2), inward=True)
    tris = np.array([[q[0], q[k], q[k + 1]] for q in f for k in range(1, len(q) - 1)])
    vps = cubemap.cube_view_projections(np.zeros(3), 0.01, 10.0)
    for drawn, seen in ((None, True), (np.zeros(0, dtype=np.int64), False)):
        renderer = gpu_capture.GpuRenderer(np.asarray(v, dtype=np.float64), tris, drawn)
        tid, _, dist, back = renderer.render(vps, np.zeros((6, 3)), None, 8)
        assert (tid >= 0).all() == seen and (tid < 0).all() != seen
        assert np.isfinite(dist).all() == seen and not back.any()


def test_the_id_pass_and_the_depth_pass_agree(cubegi):
    """The id pass's distances are worked out from the point a texel reports, the depth
    pass's in the shader: the same triangle and distance in every texel, for a cube map and
    for an orthographic (sun) view."""
    gpu_capture = importlib.import_module("cubegi.cubegi_addon.gpu_capture")
    rng = np.random.default_rng(0)
    renderer = gpu_capture.GpuRenderer(rng.uniform(-1.0, 1.0, (300, 3)), np.arange(300).reshape(100, 3))
    d = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    ortho = cubemap.orthographic(2.0, 0.1, 10.0) @ cubemap.look_matrix(5.0 * d, -d, cubemap.any_perpendicular(d))
    eye = np.array([0.1, 0.05, -0.1])
    for vps, eyes, axes, n in ((ortho[None], 5.0 * d[None], -d[None], 64),
                               (cubemap.cube_view_projections(eye, 0.01, 10.0), np.repeat(eye[None], 6, axis=0), None, 32)):
        tid, bary, dist, _ = renderer.render(vps, eyes, axes, n, with_bary=True)
        tid2, _, dist2, _ = renderer.render(vps, eyes, axes, n, with_bary=False)
        hit = tid >= 0
        assert hit.sum() > 100
        np.testing.assert_array_equal(tid, tid2)
        np.testing.assert_allclose(dist[hit], dist2[hit], rtol=1e-5)
        assert bary[hit].min() > -1e-4


def test_a_partitions_faces_lying_on_the_ceiling_and_a_wall_take_no_light(empty_scene, cubegi):
    """A 1.5 cm partition standing from the floor to the ceiling of a room of 1.5 m quads, an
    area light on one side: its top lies on the ceiling, one end on a wall. No probe is in
    front of those faces; the probes under the ceiling saw them in its plane, from behind,
    and lit them as the ceiling (2.8 and 3.2 against the lit face's 7.6). Cycles gives them
    none (a hand-made flat: its partition's indirect light +10.7% -> -0.6% against Cycles)."""
    white = scenes.material("White", (0.8, 0.8, 0.8))
    v, f = scenes.box_mesh((-3.0, -2.05, 0.0), (3.0, 2.05, 2.55), (4, 4, 4), inward=True)
    scenes.mesh_object("Shell", v, f, white)
    v, f = scenes.box_mesh((-0.0075, -0.9, 0.0), (0.0075, 2.05, 2.55), (1, 5, 5), inward=False)
    scenes.mesh_object("Partition", v, f, white)
    scenes.add_light("AREA", (-1.6, 0.3, 2.45), 300.0, size=0.5)
    assert bpy.ops.cubegi.bake() == {"FINISHED"}
    kept = cubegi.cubegi_addon.session.kept(bpy.context.scene)
    arrays, solution = kept.bake.arrays, kept.bake.result.solution
    lit = (np.asarray(solution.direct) + np.asarray(solution.indirect)).mean(axis=1)
    wall = arrays.point_object == list(arrays.object_names).index("Partition")
    on_others = wall & ((arrays.normals[:, 2] > 0.9) | (arrays.normals[:, 1] > 0.9))  # the top, the end at y = 2.05
    assert on_others.sum() >= 20
    print(lit[on_others].max(), lit[wall & (arrays.normals[:, 0] < -0.9)].mean())
    assert np.all(lit[on_others] == 0.0), lit[on_others].max()
    assert lit[wall & (arrays.normals[:, 0] < -0.9)].mean() > 1.0  # its face towards the light


def test_a_cast_capture_sees_what_the_drawn_one_sees(empty_scene, cubegi):
    """The probes' capture by rays through the GPU module's caster (capture.RayCubes, what a
    simplified scene's probes take) against the same triangles drawn: the same triangle, side
    and distance at nearly every texel (an edge is float rounding either way), a two-sided
    sheet seen from behind as its twin in both."""
    v, f = scenes.box_mesh((-3.0, -2.0, -1.5), (2.0, 4.0, 2.5), (6, 6, 6), inward=True)
    scenes.mesh_object("Room", v, f)
    v, f = scenes.box_mesh((-0.5, 0.5, -1.5), (0.5, 1.5, 0.5), (3, 3, 3), inward=False)
    scenes.mesh_object("Block", v, f)
    v, f = scenes.grid_patch((-1.5, -1.0, 0.3), (2.5, 0.4, 0.0), (0.0, 1.5, 0.0), 4, 3)  # an open sheet, tilted
    scenes.mesh_object("Sheet", v, f)
    arrays, _ = _collect_and_renderer(cubegi)
    sheet = arrays.sheet_triangles()
    assert sheet is not None and sheet.any()
    gpu_capture = importlib.import_module("cubegi.cubegi_addon.gpu_capture")
    renderer = gpu_capture.GpuRenderer(arrays.points, arrays.triangles, sheet=sheet)
    eyes = np.array([[0.3, -0.4, 0.9], [-1.0, 0.2, -0.6], [1.5, 3.0, 2.0], [-2.5, -1.5, 0.0]])
    near = np.full(len(eyes), 0.01)
    drawn = cubemap.capture_cubes(renderer, eyes, 16, near, 50.0)
    cast = capture.RayCubes.of(renderer.rays, arrays.points, arrays.triangles, sheet=sheet).capture(eyes, 16, near)
    same = cast.tid == drawn.tid
    assert same.mean() > 0.97, same.mean()
    np.testing.assert_array_equal(cast.backface[same], drawn.backface[same])
    np.testing.assert_allclose(cast.dist[same], drawn.dist[same], rtol=2e-4)
    np.testing.assert_allclose(cast.bary[same], drawn.bary[same], atol=2e-3)
    back_side = arrays.back_triangles()[np.maximum(cast.tid, 0)] & (cast.tid >= 0)
    assert back_side[same].sum() > 20  # the sheet's underside, seen through its twin


def test_a_finely_cut_rug_covers_the_floor_under_it_from_every_probe(empty_scene, cubegi, monkeypatch):
    """A rug cut into 2.5 cm squares on a room's floor: the texels around a probe's ray to a
    floor point under it (some 20 cm apart there) see rug triangles many squares from the one
    the ray crosses, beyond the rings searched around them. The exact rays, cast through the
    GPU module's caster (visibility.CastCover), cover the floor under it from every probe;
    the rings alone let the probes light most of it."""
    gather = importlib.import_module("cubegi.cubegi_engine.gather")
    v, f = scenes.box_mesh((-2.0, -2.0, 0.0), (2.0, 2.0, 2.5), (8, 8, 5), inward=True)
    scenes.mesh_object("Room", v, f)
    v, f = scenes.box_mesh((-0.8, -0.8, 0.005), (0.8, 0.8, 0.015), (64, 64, 1), inward=False)
    scenes.mesh_object("Rug", v, f)
    arrays, renderer = _collect_and_renderer(cubegi)
    g = ProbeGrid((-2, -2, 0), (2, 2, 2.5), (3, 3, 2))
    near, far = cubemap.clip_planes(arrays.scale)
    cap = cubemap.capture_cubes(renderer, g.positions(), 16, near, far)
    p = arrays.points
    under = np.flatnonzero((np.abs(p[:, 0]) <= 0.6) & (np.abs(p[:, 1]) <= 0.6) & (p[:, 2] < 1e-6) & (arrays.normals[:, 2] > 0.9))
    assert len(under) == 9  # the floor's points under the rug
    caster = gather.near_caster(arrays, renderer)
    assert transport.Transport(arrays, g, cap, caster=caster).covered[under].all()
    monkeypatch.setattr(importlib.import_module("cubegi.cubegi_engine.visibility"), "COVER_BY_RAYS", False)
    assert transport.Transport(arrays, g, cap, caster=caster).covered[under].sum() < len(under) // 2
