"""The benchmark: its analysis by hand (pure), and ``--quick`` end to end (real bpy,
llvmpipe and Cycles), writing all three files with both methods present."""

import json
import math
import os
import subprocess
import sys

import pytest

from cubegi_engine import benchmark

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _rec(scene, method, seconds, err, **settings):
    errors = {part: {"rel_rmse": err, "rel_bias": 0.0, "p95_rel": err} for part in ("direct", "indirect", "total")}
    return {"scene": scene, "method": method, "settings": settings, "seconds": seconds, "errors": errors}


CYCLES = [_rec("s", "cycles", 1.0, 0.4, samples=4), _rec("s", "cycles", 4.0, 0.2, samples=16), _rec("s", "cycles", 16.0, 0.1, samples=64)]


def test_cycles_time_at_an_error_interpolates_log_log():
    # 0.2 -> 0.1 over 4 s -> 16 s; error ~ time^-1/2 between, so 0.1414 needs 8 s.
    t, how = benchmark.cycles_time_at(0.2 / math.sqrt(2), CYCLES)
    assert how == "interpolated" and t == pytest.approx(8.0)
    assert benchmark.cycles_time_at(0.2, CYCLES)[0] == pytest.approx(4.0)


def test_cycles_time_outside_the_curve_is_flagged():
    t, how = benchmark.cycles_time_at(0.05, CYCLES)
    assert how == "extrapolated" and t == pytest.approx(64.0)  # half the error: 4x the time
    t, how = benchmark.cycles_time_at(0.9, CYCLES)
    assert how == "at most" and t == 1.0


def test_best_tradeoff_is_on_the_front_with_the_largest_speedup():
    records = CYCLES + [
        _rec("s", "cubegi", 0.5, 0.1, cube=16),   # Cycles needs 16 s: 32x
        _rec("s", "cubegi", 2.0, 0.1, cube=32),   # dominated (slower, same error)
        _rec("s", "cubegi", 0.1, 0.3, cube=8),    # Cycles ~2.25 s: 22.5x
    ]
    best = benchmark.best_tradeoffs(records)["s"]
    assert best["record"]["settings"] == {"cube": 16} and best["speedup"] == pytest.approx(32.0)
    md = benchmark.markdown(records, {"mode": "test"})
    assert "| s | cube 16 | 0.50 s | 10.0% | 16.00 s | 32.0x |" in md


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
    md = (tmp_path / "results.md").read_text()
    assert "## Best trade-off, indirect light" in md and all(f"## {s}" in md for s in scenes)
    png = (tmp_path / "error_vs_time.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    # The references are cached, named by their samples.
    assert sorted(os.listdir(tmp_path / "cache")) == sorted(f"{s}-cycles-16spp.npz" for s in scenes)
