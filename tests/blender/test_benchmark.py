"""The benchmark ``--quick`` end to end (real bpy, llvmpipe and Cycles), writing all three
files with both methods present."""

import json
import math
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_quick_benchmark_writes_results_for_both_methods(tmp_path):
    env = dict(os.environ)
    r = subprocess.run(
        [sys.executable, "-m", "cubegi_engine", "benchmark", "--quick", "--out", str(tmp_path)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    data = json.loads((tmp_path / "results.json").read_text())
    records = data["records"]
    scenes = {r["scene"] for r in records}
    assert scenes == {"room", "cornell", "courtyard", "white_box_0.95", "thin_wall"}
    for scene in scenes:
        methods = {r["method"] for r in records if r["scene"] == scene}
        assert methods == {"cubegi", "cycles"}, scene
    for rec in records:
        assert rec["seconds"] > 0
        for part in ("direct", "indirect", "total"):
            assert all(math.isfinite(v) for v in rec["errors"][part].values())
    # Cycles' error falls as its samples rise (1 -> 4 samples halves the noise).
    for scene in scenes:
        cyc = sorted((r for r in records if r["scene"] == scene and r["method"] == "cycles"), key=lambda r: r["settings"]["samples"])
        assert cyc[-1]["errors"]["indirect"]["rel_rmse"] < cyc[0]["errors"]["indirect"]["rel_rmse"]
    # Where the default bake's error sits: every scene's surfaces share all of it, and some
    # vertices hold half of it.
    for rec in (r for r in records if r["settings"].get("default") == "after"):
        for part in ("direct", "indirect"):
            assert sum(x[f"{part}_error_share"] for x in rec["surfaces"].values()) == pytest.approx(1.0), (rec["scene"], part)
            assert rec["error_holders"][part]["points"] >= 1 and 0 < rec["error_holders"][part]["area_share"] <= 1
    md = (tmp_path / "results.md").read_text()
    assert "## Best trade-off, indirect light" in md and all(f"## {s}" in md for s in scenes)
    assert "share of the squared error" in md and "Half of the squared indirect error is held by" in md
    png = (tmp_path / "error_vs_time.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    # The references are cached, named by their samples (the large surfaces of few vertices
    # baked again at 16 times those, where a scene has any).
    cached = os.listdir(tmp_path / "cache")
    assert sorted(f for f in cached if "-surfaces-" not in f) == sorted(f"{s}-cycles-16spp.npz" for s in scenes)
    assert all(f.endswith("-cycles-256spp.npz") for f in cached if "-surfaces-" in f)


def test_quick_scaling_benchmark_writes_both_sweeps(tmp_path, cubegi):
    """``benchmark --scaling --quick``: each bake in a process of its own, the JSON with both
    sweeps (more vertices take longer; more probes capture more) and the real scene's where
    the public scenes are here, the fits and the plot."""
    r = subprocess.run(
        [sys.executable, "-m", "cubegi_engine", "benchmark", "--scaling", "--quick", "--out", str(tmp_path)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    data = json.loads((tmp_path / "scaling.json").read_text())
    small, large = data["vertices"]
    assert large["vertices"] > 3 * small["vertices"] and large["seconds"] > small["seconds"]
    few, many = data["probes"]
    assert many["probes"] > 4 * few["probes"] and many["probes_captured"] > few["probes_captured"]
    for rec in data["vertices"] + data["probes"]:
        assert rec["peak_gb"] >= rec["before_gb"] > 0 and rec["timings"]["capture"] > 0
        assert 0 < rec["longest_step_seconds"] < rec["seconds"] and rec["longest_step_after"]  # as the modal bake steps it
    assert set(data["fits"]) == {"seconds_vs_vertices", "seconds_vs_probes"}
    assert (tmp_path / "scaling.png").stat().st_size > 10_000
    from benchmarks.public_scenes import scenes_dir

    if scenes_dir() is None:
        assert data["real"] == [] and "left out" in r.stdout + r.stderr
    else:
        (real,) = data["real"]
        assert real["scene"] == "breakfast_room" and real["vertices"] > 100_000 and real["timings"]["capture"] > 0
        assert real["capture_triangles"] < real["triangles"]  # simplified for the probes


def test_scaling_helpers(cubegi):
    from benchmarks import scaling

    assert abs(scaling.slope([1, 10, 100], [2, 20, 200]) - 1.0) < 1e-9
    assert abs(scaling.slope([1, 10, 100], [1, 100, 10_000]) - 2.0) < 1e-9
    for probes in (50, 200, 1000, 2000):
        res = scaling.resolution_for(probes)
        assert 0.6 * probes <= res[0] * res[1] * res[2] <= 1.5 * probes


def test_a_large_surface_of_few_vertices_is_baked_again_at_more_samples(tmp_path, empty_scene, cubegi):
    """A floor of one quad under a finely cut block: the floor (4 vertices, most of the area)
    is baked again alone at the samples asked, cached; the block is not."""
    import bpy
    import numpy as np

    from benchmarks import scenes as bench_scenes
    from benchmarks import sweep

    grey = bench_scenes.material("Grey", (0.5, 0.5, 0.5))
    bench_scenes.mesh_object("Floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], [(0, 1, 2, 3)], grey)
    v, f = bench_scenes.box((-0.3, -0.3, 0.0), (0.3, 0.3, 0.6), (8, 8, 8))
    bench_scenes.mesh_object("Block", v, f, bench_scenes.material("White", (0.8, 0.8, 0.8)))
    bench_scenes.add_light("POINT", (0.5, 0.5, 2.0), 200.0)
    objects = sweep._meshes()
    scored = {ob.name: cubegi.cubegi_addon.scene_data.vertex_areas(ob) for ob in objects}
    fine, samples = sweep.fine_surfaces(str(tmp_path), "t", 8, objects, scored, log=lambda *_: None)
    assert samples == 8 and sorted(fine) == ["Floor"]
    assert fine["Floor"]["direct"] > 0 and np.isfinite(fine["Floor"]["indirect"])
    assert os.listdir(tmp_path) == ["t-surfaces-cycles-8spp.npz"]
    again, _ = sweep.fine_surfaces(str(tmp_path), "t", 8, objects, scored, log=lambda *_: None)
    assert again == fine  # from the cache
    assert len(bpy.data.objects["Block"].data.vertices) > sweep.FINE_VERTICES
