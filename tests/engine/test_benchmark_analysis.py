"""The benchmark's analysis, by hand (pure numpy)."""

import math

import pytest

from benchmarks import analysis as benchmark


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


def test_surfaces_show_the_largest_and_those_holding_the_error():
    after = _rec("s", "cubegi", 1.0, 0.3, default="after")
    surface = {"direct": [1.0, 1.0], "indirect": [1.0, 2.0], "direct_error_share": 0.0}
    after["surfaces"] = {
        "floor": {**surface, "area": 10.0, "indirect_error_share": 0.1},
        "wall": {**surface, "area": 5.0, "indirect_error_share": 0.2},
        "cup": {**surface, "area": 0.1, "indirect_error_share": 0.6},
        "spoon": {**surface, "area": 0.2, "indirect_error_share": 0.1},
    }
    after["error_holders"] = {"direct": {"points": 0, "area_share": 0.0}, "indirect": {"points": 7, "area_share": 0.48}}
    lines = benchmark._surfaces(CYCLES + [after], shown=1)
    rows = [line.split(" | ")[0] for line in lines if line.startswith(("| floor", "| wall", "| cup", "| spoon"))]
    assert rows == ["| floor", "| cup"]  # the largest, then the other holding the most error
    assert "| cup | 0.7% | 1 | 1 | +0.0% | 0.0% | 1 | 2 | -50.0% | 60.0% |  |" in lines
    # A surface baked again at more samples: its mean there, and CubeGI's difference from it.
    after["surfaces"]["floor"]["fine"] = {"direct": 1.0, "indirect": 1.25, "samples": 4096}
    lines = benchmark._surfaces(CYCLES + [after], shown=1)
    assert "| floor | 65.4% | 1 | 1 | +0.0% | 0.0% | 1 | 2 | -50.0% | 10.0% | 1.25 at 4096 (-20.0%) |" in lines
    assert any("baked again alone at more samples" in line for line in lines)
    assert "Half of the squared indirect error is held by 7 vertices (48.0% of the area)." in " ".join(lines)
    assert "| cup |" in benchmark.markdown(CYCLES + [after], {"mode": "test"})
