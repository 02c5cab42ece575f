"""The engine's types that outlive a bake, by hand: the geometry fingerprint, the probe
field, the settings' checks and the report's JSON (pure numpy)."""

import hashlib
import json
import math
import time

import numpy as np
import pytest

from cubegi.cubegi_engine import sh
from cubegi.cubegi_engine.errors import BakeError
from cubegi.cubegi_engine.field import ProbeField
from cubegi.cubegi_engine.grid import ProbeGrid
from cubegi.cubegi_engine.records import AnimationResult, BounceRecord, FrameRecord, LeftOut, LeftOutKind, Route, TailReport
from cubegi.cubegi_engine.report import BakeReport, GridReport, NearFieldReport, ReferenceReport
from cubegi.cubegi_engine.scene import SceneArrays
from cubegi.cubegi_engine.settings import MAX_BOUNCES, BakeSettings

# Float32 SH coefficients through float64 evaluation.
FIELD_TOL = 1e-5


def _two_quads(shift=0.0):
    """Two objects of two triangles each; the second one moved by ``shift`` along Z."""
    quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    points = np.concatenate([quad, quad + [0, 0, 1.0 + shift]])
    tris = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    n = np.tile([0.0, 0.0, 1.0], (8, 1))
    return SceneArrays(points, n, np.full((8, 3), 0.5), np.zeros((8, 3)), tris,
                       point_object=np.repeat([0, 1], 4), object_names=["Floor", "Lid"])


def test_the_fingerprint_finds_what_changed():
    a, b = _two_quads(), _two_quads()
    assert a.fingerprint() == b.fingerprint() and not a.fingerprint().changed(b.fingerprint())
    moved = _two_quads(shift=0.25)
    assert moved.fingerprint().changed(a.fingerprint()) == {"Lid"}
    # Materials are not geometry: a new albedo keeps the fingerprint.
    recoloured = _two_quads()
    recoloured.albedo[:] = 0.9
    assert recoloured.fingerprint() == a.fingerprint()
    # A first object with more points shifts the second's indices but not its fingerprint.
    grown = SceneArrays(
        np.concatenate([a.points[:4], [[2, 2, 0]], a.points[4:]]), np.tile([0.0, 0, 1], (9, 1)), np.full((9, 3), 0.5),
        np.zeros((9, 3)), np.array([[0, 1, 2], [0, 2, 3], [5, 6, 7], [5, 7, 8]]),
        point_object=np.array([0, 0, 0, 0, 0, 1, 1, 1, 1]), object_names=["Floor", "Lid"],
    )
    assert grown.fingerprint().changed(a.fingerprint()) == {"Floor"}


def test_the_fingerprint_takes_each_objects_own_points_in_any_order_of_the_arrays():
    """Each object's digest covers its own points, normals and triangles, in their order,
    wherever the arrays put them: objects interleaved hash as one mask per object does, and
    the same geometry gives the same digests; an object with no points has a digest too."""
    rng = np.random.default_rng(3)
    owner = rng.integers(0, 4, 400)
    owner[owner == 2] = 3  # object 2 has no points
    points, normals = rng.random((400, 3)), rng.random((400, 3))
    tris = rng.integers(0, 400, (900, 3)).astype(np.int32)
    interleaved = SceneArrays(points, normals, np.full((400, 3), 0.5), np.zeros((400, 3)), tris,
                              point_object=owner, object_names=["A", "B", "C", "D"])
    made = interleaved.fingerprint()
    for k, (name, digest) in enumerate(made.objects):
        sel = owner == k
        h, t = hashlib.blake2b(digest_size=16), hashlib.blake2b(digest_size=16)
        h.update(points[sel].tobytes())
        h.update(normals[sel].tobytes())
        t.update((tris[owner[tris[:, 0]] == k] - (int(np.argmax(sel)) if sel.any() else 0)).tobytes())
        h.update(t.digest())
        assert (name, digest) == (interleaved.object_names[k], h.hexdigest())
        assert made.layout[k] == (name, int(sel.sum()), t.hexdigest())
    # The same arrays laid out object by object: the same digests where the triangles are
    # the same relative to each object's first point (an object of its own points alone).
    order = np.argsort(owner, kind="stable")
    ordered = SceneArrays(points[order], normals[order], np.full((400, 3), 0.5), np.zeros((400, 3)),
                          np.argsort(order)[tris], point_object=owner[order], object_names=["A", "B", "C", "D"])
    assert ordered.fingerprint().layout[2] == made.layout[2]  # no points, no triangles: alike
    assert [n for n, _, _ in ordered.fingerprint().layout] == ["A", "B", "C", "D"]
    assert [c for _, c, _ in ordered.fingerprint().layout] == [c for _, c, _ in made.layout]


def test_the_probe_field_gives_a_uniform_sky_its_radiance_for_any_normal():
    grid = ProbeGrid((0, 0, 0), (2, 2, 2), (2, 2, 2))
    coeffs = np.zeros((8, 9, 3), dtype=np.float32)
    coeffs[:, 0, :] = np.array([0.5, 1.0, 2.0]) * 2.0 * math.sqrt(math.pi)  # L * (Y00 integral = sqrt(4 pi))
    field = ProbeField(grid, coeffs, np.ones(8, dtype=bool))
    rng = np.random.default_rng(1)
    n = rng.normal(size=(50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    light = field.light_at(rng.uniform(0, 2, size=(50, 3)), n)
    np.testing.assert_allclose(light, np.tile([0.5, 1.0, 2.0], (50, 1)), rtol=FIELD_TOL)


def test_the_probe_field_interpolates_trilinearly_and_leaves_out_invalid_probes():
    grid = ProbeGrid((0, 0, 0), (2, 1, 1), (2, 1, 1))  # probes at x = 0.5 and 1.5
    coeffs = np.zeros((2, 9, 3), dtype=np.float32)
    coeffs[0, 0, :], coeffs[1, 0, :] = 1.0, 3.0
    up = np.tile([0.0, 0.0, 1.0], (3, 1))
    pts = np.array([[0.5, 0.5, 0.5], [1.0, 0.5, 0.5], [1.5, 0.5, 0.5]])
    e = float(sh.diffuse_basis(up[0])[0])  # the light of a unit Y00 coefficient
    light = ProbeField(grid, coeffs, np.ones(2, dtype=bool)).light_at(pts, up)
    np.testing.assert_allclose(light[:, 0], np.array([1.0, 2.0, 3.0]) * e, rtol=FIELD_TOL)
    only_second = ProbeField(grid, coeffs, np.array([False, True])).light_at(pts, up)
    # The point on the invalid probe has no valid probe with weight: it keeps its plain weights.
    np.testing.assert_allclose(only_second[:, 0], np.array([1.0, 3.0, 3.0]) * e, rtol=FIELD_TOL)


@pytest.mark.parametrize("kw,setting", [
    (dict(cube_size=2), "cube_size"), (dict(cube_size=4096), "cube_size"), (dict(bounces=-1), "bounces"),
    (dict(bounces=MAX_BOUNCES + 1), "bounces"), (dict(tolerance=0.0), "tolerance"), (dict(shadow_size=0), "shadow_size"),
])
def test_settings_name_what_is_out_of_range(kw, setting):
    with pytest.raises(BakeError) as info:
        BakeSettings(**kw).validate()
    assert info.value.setting == setting
    assert BakeSettings().validate() == BakeSettings()


def _report(**kw):
    rec = BounceRecord(1, 0.01, 0.005, 0.002, [0.1, 0.2, 0.3], 0.2, [0.5, 0.5, 0.5], 0.5, 0.25, [1.0, 1.0, 1.0], "CubeGI_bounce_1")
    fields = dict(
        settings=BakeSettings().as_dict(lit="NONE"), grid=GridReport([2, 2, 2], 8, [0.0] * 3, [1.0] * 3, probes_moved=2), points=10, triangles=12,
        lights=1, sky=[0.0, 0.0, 0.0], meshes_baked=["Room"], notes=["a note"], direct_seconds=0.1,
        direct_mean_light=[1.0, 1.0, 1.0], emitter_energy_factor=[1.0, 1.0, 1.0], bounces=[rec],
        indirect_mean_light=[0.3, 0.3, 0.3], tail=TailReport(0.25, "geometric", True, mean_light=[0.1] * 3, share_of_indirect=0.2),
        timings={"total": 1.5},
        near_field=NearFieldReport(5, 40, 60, 1, 0.25, 0.01),
        reference=ReferenceReport(16, 2.0, 0.5, ["CubeGI_ref_direct"],
                                  {part: {"rel_rmse": 0.1, "rel_bias": 0.0, "p95_rel": 0.2} for part in ("direct", "indirect", "total")},
                                  objects=[{"name": "Shop", "error_share": 0.61, "direct_bias": -0.001, "indirect_bias": 0.336},
                                           {"name": "Case", "error_share": 0.2, "direct_bias": None, "indirect_bias": None}]),
        left_out=[LeftOut(LeftOutKind.LIGHT, "Away: reaches no surface", names=("Away",)),
                  LeftOut(LeftOutKind.PROBES, "3 of 8 light no vertex", 3)],
    )
    fields.update(kw)
    return BakeReport(**fields)


def test_the_report_round_trips_through_strict_json():
    report = _report()
    again = BakeReport.from_json(report.to_json())
    assert again == report
    assert again.summary_lines() == report.summary_lines() and "baked 1 meshes, 8 probes" in report.summary_lines()[0]
    d = json.loads(report.to_json())
    assert d["scene"]["meshes_baked"] == ["Room"] and d["bounces"][0]["attribute"] == "CubeGI_bounce_1"
    assert d["estimated_remaining_error"] == 0.25 and d["total_seconds"] == 1.5
    assert d["grid"]["probes_moved"] == 2 and "probes_left_inside" not in d["grid"] and d["near_field"]["hits"] == 40
    assert d["reference"]["renderer"] == "cycles" and d["capture_geometry"] is None
    assert "probes: 2 found inside geometry were moved out of it, within their cells" in report.summary_lines()
    assert "  Shop: 61% of the error; mean direct -0.1%, indirect +33.6% against Cycles" in report.summary_lines()
    none = "n/a (next to none in Cycles)"
    assert f"  Case: 20% of the error; mean direct {none}, indirect {none} against Cycles" in report.summary_lines()
    # What was left out: typed in the report, lines in its text and its JSON's "left_out".
    assert d["left_out"] == ["light Away: reaches no surface", "probes: 3 of 8 light no vertex"]
    assert d["left_out_items"][1] == {"kind": "probes", "count": 3, "names": [], "text": "3 of 8 light no vertex"}
    assert "left out: light Away: reaches no surface" in report.summary_lines()
    assert [LeftOut.from_line(x) for x in d["left_out"]][0].kind == LeftOutKind.LIGHT
    del d["left_out_items"]  # a report of a version that wrote the lines alone
    assert [x.line() for x in BakeReport.from_dict(d).left_out] == d["left_out"]
    d["left_out"].append("a line no kind names")  # another version's: kept as it reads
    assert BakeReport.from_dict(d).left_out[-1] == LeftOut(LeftOutKind.OTHER, "a line no kind names")
    assert list(d["grid"])[:5] == ["resolution", "lo", "hi", "probes", "grids"]


def test_the_report_json_has_no_nan_or_inf():
    text = _report(direct_mean_light=[float("nan"), float("inf"), 1.0]).to_json()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text)["direct"]["mean_light"] == [None, None, 1.0]


def test_a_probe_behind_a_points_surface_does_not_light_it():
    """A moving object sits on a probe: the probe behind each vertex's surface (inside the
    object) is left out with ``one_sided``, so it cannot light the object from inside."""
    grid = ProbeGrid((0, 0, 0), (2, 1, 1), (2, 1, 1))  # probes at x = 0.5 (inside) and 1.5
    coeffs = np.zeros((2, 9, 3), dtype=np.float32)
    coeffs[0, 0, :], coeffs[1, 0, :] = 100.0, 1.0  # the probe inside sees a bright inside
    field = ProbeField(grid, coeffs, np.ones(2, dtype=bool))
    pts = np.array([[0.9, 0.5, 0.5]])
    out = np.array([[1.0, 0.0, 0.0]])  # facing +X: the probe at 0.5 is behind it
    e = float(sh.diffuse_basis(out[0])[0])
    both = field.light_at(pts, out)
    one = field.light_at(pts, out, one_sided=True)
    np.testing.assert_allclose(one[0, 0], 1.0 * e, rtol=FIELD_TOL)  # the outside probe's light alone
    assert both[0, 0] > 30 * one[0, 0]
    # No probe in front: the plain weights stand (never a zero weight sum).
    back = field.light_at(np.array([[1.7, 0.5, 0.5]]), out, one_sided=True)
    assert np.isfinite(back).all() and back[0, 0] > 0


def test_the_field_gives_several_parts_in_one_pass_as_it_gives_each():
    """``light_parts`` shares the weights and the product between parts; each part equals
    ``light_at`` of that part alone (plain and one-sided weights, inside and outside the
    grid)."""
    rng = np.random.default_rng(3)
    grid = ProbeGrid((0, 0, 0), (3, 2, 2), (3, 2, 2))
    coeffs = rng.uniform(0.0, 1.0, (12, 9, 3)).astype(np.float32)
    coeffs[:, 0] += 2.0  # mostly positive light
    source = (0.3 * coeffs).astype(np.float32)
    valid = np.ones(12, dtype=bool)
    valid[4] = False
    field = ProbeField(grid, coeffs, valid, source)
    pts = rng.uniform(-0.5, 3.5, (400, 3))
    nrm = rng.normal(size=(400, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    for one_sided in (False, True):
        parts = field.light_parts(pts, nrm, ("direct", "indirect", "all"), one_sided=one_sided)
        for part, got in zip(("direct", "indirect", "all"), parts):
            alone = field.light_at(pts, nrm, part=part, one_sided=one_sided)
            np.testing.assert_allclose(got, alone, rtol=FIELD_TOL, atol=1e-6)  # float32 sums in another order
            assert got.flags["C_CONTIGUOUS"] and got.shape == (400, 3)
        # direct + indirect is all (up to the deringing of each, none rings here)
        np.testing.assert_allclose(parts[0] + parts[1], parts[2], rtol=1e-4, atol=1e-5)


def _operator(p=4, s=30, seed=0, landing=None):
    """A MatrixOperator of a small random capture (p probes, s points)."""
    from types import SimpleNamespace

    from cubegi.cubegi_engine.relight import MatrixOperator
    from cubegi.cubegi_engine.transport import _gather_matrix

    rng = np.random.default_rng(seed)
    t = 24  # texels per probe
    transport = SimpleNamespace(
        probe_count=p,
        corners=rng.integers(0, s, (p, t, 3)),
        bary=rng.dirichlet(np.ones(3), (p, t)).astype(np.float32),
        sh_weights=rng.uniform(0.0, 0.05, (t, 9)).astype(np.float32),
        index=np.stack([rng.permutation(p)[np.arange(8) % p] for _ in range(s)]),
        point_weights=rng.uniform(0.0, 0.05, (s, 8, 9)).astype(np.float32),
        proxy=None,
    )
    transport.gather_project_matrix = lambda: _gather_matrix(transport, s)
    return MatrixOperator(transport, np.full((s, 3), 0.7), landing, rng.uniform(0.5, 1.5, s))


def test_the_bounce_series_balances_every_bounce_and_its_tail_sums_the_rest():
    """One series for the bake and relighting (cubegi_engine.series): each balanced bounce
    brings the power the bounce before sent that lands, with the factors it reports; given
    those factors the series makes the same bounces again; the tail is the sum of every
    later bounce at the last factor, by GMRES and by the kept inverse alike."""
    from cubegi.cubegi_engine.series import bounce_series, landed_power, tail_sum

    s = 30
    landing = np.random.default_rng(2).uniform(0.6, 0.9, (s, 3))
    op = _operator(s=s, landing=landing)
    radius = max(np.max(np.abs(np.linalg.eigvals(op.M[ch]))) for ch in range(3))
    op.M = op.M * (0.6 / radius)
    direct = np.random.default_rng(3).uniform(0.0, 1.0, (s, 3))
    series = bounce_series(op, direct)
    bounces = [next(series) for _ in range(4)]
    sent = landed_power(op.albedo * direct, landing, op.areas)
    for bounce in bounces:
        assert np.all(bounce.factor != 1.0) and np.all((bounce.factor > 0.5) & (bounce.factor < 2.0))
        np.testing.assert_allclose(op.u @ bounce.balanced, sent, rtol=1e-9)
        sent = np.einsum("cq,qc->c", op.v, bounce.balanced)
    factors = np.stack([b.factor for b in bounces])
    again = list(bounce_series(op, factors=factors, first=bounces[0].coeffs))
    for a, b in zip(again, bounces):
        np.testing.assert_allclose(a.balanced, b.balanced, rtol=1e-12)
    np.testing.assert_allclose(op.factors(direct, 4), factors, rtol=1e-12)

    last, g = bounces[-1], bounces[-1].factor
    later = bounce_series(op, factors=np.tile(g, (200, 1)), first=op.apply(last.balanced))
    summed = sum(b.balanced for b in later)
    by_gmres = tail_sum(op, last.coeffs, g, tol=1e-12)
    assert by_gmres.iterations > 0 and by_gmres.residual <= 1e-12
    np.testing.assert_allclose(by_gmres.balanced, summed, rtol=1e-8, atol=1e-12)
    by_inverse = tail_sum(op, last.coeffs, g, inverse=op.inverse(g))
    np.testing.assert_allclose(by_inverse.balanced, summed, rtol=1e-8, atol=1e-12)


def test_the_tail_solve_keeps_its_inverse_and_refines_it_for_a_nearby_factor():
    """Every tail solve equals a direct solve of (1 - f M) x = c; a nearby factor is served
    from the kept inverse (refined), a far one makes a new inverse, and a material edit
    drops the kept ones."""
    op = _operator()
    n = op.size
    radius = max(np.max(np.abs(np.linalg.eigvals(op.M[ch]))) for ch in range(3))
    op.M = op.M * (0.6 / radius)  # a spectral radius of 0.6 at f = 1
    c = np.random.default_rng(1).normal(size=(n, 3))

    def exact(f):
        return np.stack([np.linalg.solve(np.eye(n) - f[ch] * op.M[ch], c[:, ch]) for ch in range(3)], axis=1)

    f1 = np.array([1.0, 0.9, 1.1])
    np.testing.assert_allclose(op.inverse(f1)(c), exact(f1), rtol=1e-9, atol=1e-12)
    kept = [entry[1] for entry in op._inverses]
    f2 = f1 * 1.03
    np.testing.assert_allclose(op.inverse(f2)(c), exact(f2), rtol=1e-8, atol=1e-10)
    assert all(entry[1] is inv for entry, inv in zip(op._inverses, kept))  # refined, not remade
    f3 = np.array([1.6, 1.6, 1.6])  # far: refinement does not converge in its steps
    np.testing.assert_allclose(op.inverse(f3)(c), exact(f3), rtol=1e-8, atol=1e-10)
    assert all(entry[0] == 1.6 for entry in op._inverses)
    op.set_albedo(np.full((len(op.albedo), 3), 0.5))
    assert op._inverses == [None, None, None]


def test_quality_presets_and_their_checks():
    from cubegi.cubegi_engine.settings import QUALITY

    assert BakeSettings() == BakeSettings.preset("balanced")
    draft = BakeSettings.preset("Draft", bounces=2)
    assert (draft.cells, draft.cube_size, draft.bounces) == (QUALITY["DRAFT"]["cells"], QUALITY["DRAFT"]["cube_size"], 2)
    with pytest.raises(BakeError) as err:
        BakeSettings.preset("ultra")
    assert err.value.setting == "quality" and "draft, balanced, final" in str(err.value)
    for bad in (0, 65):
        with pytest.raises(BakeError) as err:
            BakeSettings(cells=bad).validate()
        assert err.value.setting == "cells"


def test_an_animation_result_counts_its_paths_and_reads_as_the_report_writes_it():
    frames = (FrameRecord(1, 0.5, Route.FULL, [0.1] * 3, [0.2] * 3, {"probes": 42, "capture_reused": False}),
              FrameRecord(2, 0.01, Route.LIGHTS, [0.1] * 3, [0.2] * 3, {"changed": ["Lamp"]}),
              FrameRecord(3, 0.02, Route.LIGHTS, [0.3] * 3, [0.1] * 3, {"changed": ["Lamp"]}))
    result = AnimationResult(frames, 0.53, "/tmp/cache")
    assert result.paths() == {"full": 1, "lights": 2} and list(result.paths()) == ["full", "lights"]
    d = json.loads(json.dumps(result.to_dict(), allow_nan=False))
    assert [f["path"] for f in d["frames"]] == ["full", "lights", "lights"] and d["cache"] == "/tmp/cache"
    assert d["frames"][0]["probes"] == 42 and d["frames"][1]["changed"] == ["Lamp"] and d["frames"][2]["mean_direct"] == [0.3] * 3
    assert tuple(FrameRecord.from_dict(f) for f in d["frames"]) == frames  # as a cluster's chunks read them back


def test_a_finished_step_hands_back_the_memory_its_thread_freed(monkeypatch):
    """Each long step runs in a thread of its own, and glibc keeps what a thread frees in
    that thread's arena (0.2-0.5 GB between the stages of a million-vertex bake): a finished
    step gives it back (``malloc_trim``), found wherever the C library is glibc; its result
    and its error reach the caller as before."""
    import platform

    from cubegi.cubegi_engine import working

    if platform.libc_ver()[0] == "glibc":
        assert working._MALLOC_TRIM is not None
    given = []
    monkeypatch.setattr(working, "give_back_memory", lambda: given.append(1))
    assert working.run(working.in_background(lambda: np.ones(1 << 20).sum(), None)) == 1 << 20
    with pytest.raises(ZeroDivisionError):
        working.run(working.in_background(lambda: 1 / 0, None))
    assert len(given) == 2


def test_a_closed_or_failed_generator_stops_the_threads_its_steps_started():
    """The threads a driven generator's steps start (and the threads those start, and a
    nested run's) stop at their next piece once it is closed (a cancel) or fails: no piece
    starts after, where before all 200 ran. Run to its end, every piece runs, as before."""
    import time

    from cubegi.cubegi_engine import working

    def pieces(ran):
        def slow(item):
            ran.append(time.perf_counter())
            time.sleep(0.01)
            return item

        return lambda: working.in_parallel(slow, range(200))

    def nested(ran):  # a job started inside a job, which drives a generator of its own
        return working.result(working.start(lambda: working.run(working.in_background(pieces(ran), None))))

    def settled(ran):
        time.sleep(0.3)
        count = len(ran)
        time.sleep(0.3)
        return count, len(ran)

    ran = []
    driven = working.Driven(working.in_background(nested, None, ran))
    driven.next()
    while not ran:
        time.sleep(0.005)
    driven.close()
    stopped = time.perf_counter()
    count, later = settled(ran)
    assert count == later and count < 200 and sum(t > stopped for t in ran) <= working.WORKERS

    def failing(ran):
        working.start(pieces(ran))
        while not ran:
            yield None
        raise ValueError("a failed step")

    ran = []
    with pytest.raises(ValueError):
        working.run(failing(ran))
    count, later = settled(ran)
    assert count == later < 200
    ran = []
    assert working.run(working.in_background(pieces(ran), None)) == list(range(200)) and len(ran) == 200
    assert not issubclass(working.Cancelled, Exception)  # no fallback catches it


def test_a_cancelled_bakes_thread_keeps_no_voxel_index():
    """The voxel indexes a bake's stages share are let go at its end (``forget_indexes``);
    a thread of a cancelled bake that makes one after that keeps none (it held its arrays
    until the next bake ended)."""
    import threading

    from cubegi.cubegi_engine import spatial, working

    points = np.array([[0.0, 0, 0], [1.0, 0, 0], [0.0, 1, 0]])
    tri = np.array([[0, 1, 2]])
    go = threading.Event()

    def late():
        go.wait(5.0)
        return spatial.voxel_index(points, tri, 0.5)

    def steps():
        return (yield from working.in_background(late, None))

    spatial.forget_indexes()
    driven = working.Driven(steps())
    driven.next()
    driven.close()  # (the bake's end lets go of its indexes, then the thread asks)
    spatial.forget_indexes()
    go.set()
    deadline = time.perf_counter() + 5.0
    while time.perf_counter() < deadline and threading.active_count() > 1 and any(
            t.name == "cubegi-work" and t.is_alive() for t in threading.enumerate()):
        time.sleep(0.01)
    assert spatial._INDEXES == []
    assert spatial.voxel_index(points, tri, 0.5) is not None and len(spatial._INDEXES) == 1  # kept outside a cancelled bake
    spatial.forget_indexes()
