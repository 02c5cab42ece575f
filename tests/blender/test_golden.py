"""The demo Room and every benchmark scene bake to the values kept in
``tests/blender/data/golden_bakes.npz`` (see ``tests/blender/golden.py``): a restructuring of the code must
not move the light."""

import golden
import numpy as np
import pytest

# The bake is deterministic on one machine (two runs agree bit for bit); across machines, GPU
# drivers and numpy releases float32 sums may be ordered differently (numpy 2.5 moves one
# vertex of the white box by 1.2e-6 of its light), so allow a hundred-thousandth of the
# scene's brightest value: far below any change of the light model.
GOLDEN_TOL = 1e-5


@pytest.fixture(scope="module")
def kept():
    return np.load(golden.PATH)


@pytest.mark.parametrize("scene", golden.SCENES)
def test_bake_reproduces_the_kept_values(scene, kept, cubegi, empty_scene):
    baked = golden.bake_scene(scene)
    names = sorted(k for k in kept.files if k.startswith(scene + "/"))
    assert sorted(baked) == names
    peak = max(float(kept[k].max()) for k in names)
    for k in names:
        np.testing.assert_allclose(baked[k], kept[k], rtol=0, atol=GOLDEN_TOL * peak, err_msg=k)


@pytest.mark.parametrize("scene", ["courtyard@turned"])
def test_the_bake_is_the_same_on_one_core_and_on_eight(scene, cubegi, empty_scene, monkeypatch):
    """Work cut into pieces for the worker threads gives the same light, bit for bit, as the
    same work done whole in one thread: each piece's numbers are its own. (The pieces are made
    small here so that this scene is cut into many.)"""
    from cubegi.cubegi_engine import geometry, nearrays, working

    monkeypatch.setattr(working, "WORKERS", 1)
    alone = golden.bake_scene(scene)
    monkeypatch.setattr(working, "WORKERS", 8)
    monkeypatch.setattr(geometry, "MIN_PIECE", 64)
    monkeypatch.setattr(nearrays, "CAST_PIECE", 8)
    pieces = []
    real = working.in_parallel
    monkeypatch.setattr(working, "in_parallel", lambda fn, items: pieces.append(len(items)) or real(fn, items))
    shared = golden.bake_scene(scene)
    assert max(pieces, default=0) >= 8  # the work was cut
    assert sorted(shared) == sorted(alone)
    for k in alone:
        np.testing.assert_array_equal(shared[k], alone[k], err_msg=k)
