"""The tree of boxes the GPU's ray caster walks (cubegi_engine.boxtree), and the main thread's
service that runs a thread's GPU calls (working.on_main), without Blender."""

import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from cubegi_engine import boxtree, working
from cubegi_engine.rays import NumpyRays
from cubegi_engine.records import Progress, Stage


def _soup(rng, count, offset=0.0):
    """``count`` random triangles of a few centimetres to a metre in a 4 x 4 x 2 m box."""
    centres = rng.uniform((0, 0, 0), (4, 4, 2), size=(count, 1, 3))
    size = rng.uniform(0.02, 1.0, size=(count, 1, 1))
    points = (centres + size * rng.normal(size=(count, 3, 3))).reshape(-1, 3) + offset
    return points, np.arange(3 * count).reshape(-1, 3)


def _rays(rng, count, offset=0.0):
    origins = rng.uniform((0, 0, 0), (4, 4, 2), size=(count, 3)) + offset
    dirs = rng.normal(size=(count, 3))
    return origins, dirs / np.linalg.norm(dirs, axis=1, keepdims=True)


def test_every_box_holds_what_lies_under_it_and_every_triangle_is_in_one_leaf():
    rng = np.random.default_rng(1)
    points, triangles = _soup(rng, 700)
    tree = boxtree.build(points, triangles)
    m = len(tree.skip)
    leaf = tree.count > 0
    assert np.sort(tree.order).tolist() == list(range(700))
    # The leaves' runs cover every slot once, in order, none longer than LEAF.
    assert np.array_equal(tree.first[leaf], np.concatenate([[0], np.cumsum(tree.count[leaf])[:-1]]))
    assert tree.count[leaf].sum() == 700 and tree.count.max() <= boxtree.LEAF
    corners = tree.corners[:, 0:1] + np.concatenate([np.zeros((700, 1, 3), np.float32), tree.corners[:, 1:]], axis=1)
    for node in range(m):  # (700 triangles: every node)
        lo, hi = tree.boxes[node]
        if leaf[node]:
            held = corners[tree.first[node]:tree.first[node] + tree.count[node]].reshape(-1, 3)
            assert tree.skip[node] == node + 1
        else:
            left, right = node + 1, tree.skip[node + 1]
            assert tree.skip[right] == tree.skip[node]  # the right child's subtree ends where the node's does
            held = tree.boxes[[left, right]].reshape(-1, 3)
        assert (held >= lo).all() and (held <= hi).all(), node
    # The triangles, less the centre, are the caller's, in the caller's order.
    again = corners.astype(np.float64) + tree.centre
    assert again[np.argsort(tree.order)] == pytest.approx(points[triangles], abs=1e-5)


@pytest.mark.parametrize("offset", [0.0, 1000.0])
def test_the_walk_meets_what_testing_every_triangle_meets(offset):
    """The walk (the shader's, in numpy) against every triangle tested: the same nearest hit
    within float32's precision, also a kilometre from the origin (the tree is kept less its
    centre); a shadow ray's first hit found answers as the nearest."""
    rng = np.random.default_rng(2)
    points, triangles = _soup(rng, 400, offset)
    tree = boxtree.build(points, triangles)
    origins, dirs = _rays(rng, 400, offset)
    reach = rng.uniform(0.2, 5.0, size=400)
    plain = NumpyRays(points, triangles).cast(origins, dirs, reach)
    which, t = boxtree.walk(tree, origins, dirs, reach)
    assert plain.hit.sum() > 100 and (~plain.hit).sum() > 50
    assert np.array_equal(which >= 0, plain.hit)
    assert t[plain.hit] == pytest.approx(plain.t[plain.hit], abs=1e-4)  # float32 at 1 km: about 1e-4 m
    assert (which == plain.triangle).mean() > 0.98  # (two triangles at one distance: either)
    shadow, _ = boxtree.walk(tree, origins, dirs, reach, any_hit=True)
    assert np.array_equal(shadow >= 0, plain.hit)


def test_of_triangles_at_one_distance_the_walk_reports_the_lowest_index():
    """Coincident triangles (a mesh's faces doubled, as imported scenes have them) are met at
    one distance: the walk reports the caller's lowest index, as testing every triangle does,
    wherever the tree put them."""
    rng = np.random.default_rng(6)
    points, triangles = _soup(rng, 200)
    doubled = np.concatenate([triangles[::-1], triangles])  # each twin twice, the higher index first in the array
    origins, dirs = _rays(rng, 300)
    which, _ = boxtree.walk(boxtree.build(points, doubled), origins, dirs, 3.0)
    plain = NumpyRays(points, doubled).cast(origins, dirs, 3.0)
    assert (which >= 0).sum() > 50 and np.array_equal(which, plain.triangle)


def test_triangles_at_one_point_still_split_into_leaves():
    """Triangles whose centres share a Morton code (a fan round one point) split at the
    middle of their run: no leaf holds more than LEAF; and a scene of no triangles is a tree
    of no nodes, which nothing meets."""
    angles = np.linspace(0, 2 * np.pi, 41)
    rim = np.stack([np.cos(angles), np.sin(angles), np.zeros(41)], axis=1)
    points = np.concatenate([[[0.0, 0.0, 0.0]], rim, -rim])
    fan = np.array([[0, 1 + k, 2 + k] for k in range(40)] + [[0, 43 + k, 42 + k] for k in range(40)])
    tree = boxtree.build(points, fan)
    assert tree.count.max() <= boxtree.LEAF and tree.count.sum() == 80
    met, _ = boxtree.walk(tree, [[0.3, 0.1, 1.0]], [[0.0, 0.0, -1.0]])
    assert met[0] >= 0
    empty = boxtree.build(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    assert len(empty.skip) == 0 and boxtree.walk(empty, [[0, 0, 0]], [[0, 0, 1]])[0][0] == -1


def test_a_threads_call_runs_on_the_main_thread_while_it_waits_for_the_work():
    """``on_main`` from a bake's thread: the main thread runs the call while it waits
    (``wait``), the thread gets its answer or its error."""
    ran_on = []

    def gpu_call(x):
        ran_on.append(threading.current_thread() is threading.main_thread())
        if x < 0:
            raise ValueError("refused")
        return 2 * x

    def work():
        out = [working.on_main(gpu_call, k) for k in range(5)]
        with pytest.raises(ValueError, match="refused"):
            working.on_main(gpu_call, -1)
        return out

    assert working.run(working.in_background(work, None)) == [0, 2, 4, 6, 8]
    assert ran_on == [True] * 6
    assert working.on_main(gpu_call, 3) == 6 and ran_on[-1]  # (the main thread's own: at once)


def test_a_call_the_main_thread_does_not_take_is_refused_in_time(monkeypatch):
    """A thread the main thread does not wait for (its own) gets NotServed after
    TAKE_CALL_SECONDS, and the call is not left behind to run later."""
    monkeypatch.setattr(working, "TAKE_CALL_SECONDS", 0.2)
    out = {}

    def alone():
        t = time.perf_counter()
        try:
            working.on_main(lambda: out.setdefault("ran", True))
        except working.NotServed:
            out["refused"] = time.perf_counter() - t

    thread = threading.Thread(target=alone)
    thread.start()
    thread.join()
    assert 0.15 < out["refused"] < 2.0 and "ran" not in out
    assert working.run(working.in_background(lambda: 1, None)) == 1 and "ran" not in out  # (no call waits for the next wait)


def test_pieces_run_from_the_main_thread_have_their_calls_served(monkeypatch):
    """``in_parallel`` on the main thread (an update run there) serves its pieces' calls
    while it waits for them, and ``result`` does while it waits for a job: none is refused."""
    monkeypatch.setattr(working, "WORKERS", 2)
    monkeypatch.setattr(working, "TAKE_CALL_SECONDS", 0.5)

    def piece(k):
        return working.on_main(lambda: (k, threading.current_thread() is threading.main_thread()))

    assert working.in_parallel(piece, range(6)) == [(k, True) for k in range(6)]
    assert working.result(working.start(piece, 7)) == (7, True)


def test_the_main_thread_serves_calls_between_its_batches_of_drawing(monkeypatch):
    """A thread's calls handed to the main thread while it draws batches of its own (the
    probes, while the near field's rays are traced) are run between the batches, before the
    main thread waits for anything: none waits for the end of the drawing or is refused."""
    monkeypatch.setattr(working, "TAKE_CALL_SECONDS", 0.5)
    asked, served = threading.Event(), []

    def work():
        asked.set()
        return working.on_main(lambda: served.append(threading.current_thread() is threading.main_thread()) or len(served))

    job = working.start(work)
    asked.wait()

    def batch(a, b):
        time.sleep(0.1)  # (the call is handed over meanwhile)
        return len(served)

    assert working.run(working.in_batches(20, 1, batch, lambda done: None))[-1] == 1  # served before the drawing ended
    assert served == [True] and working.result(job) == 1


def test_abandoned_work_stops_at_its_next_piece_and_its_calls_are_served_meanwhile():
    """``abandon`` (a failed step's own work, which nothing will take): the job stops at its
    next checkpoint, the main thread serving its calls while it waits for that (it would
    wait for them); and a thread whose call the main thread took but has not ended leaves
    once the work it is for stops (a main thread stopped inside it would never end it)."""
    served = []

    def work():
        for _ in range(1000):
            working.checkpoint()
            served.append(working.on_main(lambda: threading.current_thread() is threading.main_thread()))
            time.sleep(0.01)

    job = working.start(work)
    while not served:
        working.serve_waiting()
    t = time.perf_counter()
    working.abandon(job)
    assert time.perf_counter() - t < 1.0 and job.finished.is_set() and not job.thread.is_alive()
    assert isinstance(job.out.get("error"), working.Cancelled) and all(served) and len(served) < 1000

    box, out = [], {}

    def blocking():  # (the main thread inside the call when the work stops)
        box[0].stop.set()
        out["left_first"] = box[0].finished.wait(2.0)

    box.append(working.start(working.on_main, blocking))
    with pytest.raises(working.Cancelled):
        working.result(box[0])
    assert out["left_first"]


def _steps_with_work(work, started):
    """A bake's shape: steps that start ``work`` in a thread, yield, and abandon it when they
    fail or are closed (as a new capture abandons its near field's rays)."""
    job = working.start(work)
    started.append(job)
    try:
        yield Progress(Stage.CAPTURE, 0, 1, "capturing")
        yield Progress(Stage.CAPTURE, 1, 1, "captured")
    except BaseException:
        working.abandon(job)
        raise


def test_a_run_whose_progress_fails_stops_its_steps_work_before_it_raises():
    """A driver whose progress callback fails (the output's pipe closed: ``| head``) closes
    its steps at once: their clean-up stops and waits for the work they started, while its
    thread can still end (closed when collected at the interpreter's exit, it was not)."""
    started = []

    def work():
        for _ in range(1000):
            working.checkpoint()
            time.sleep(0.01)

    def progress(step):
        raise BrokenPipeError("the output's reader is gone")

    steps = _steps_with_work(work, started)
    with pytest.raises(BrokenPipeError):
        working.run(steps, progress)
    assert steps.gi_frame is None  # closed
    assert started[0].finished.is_set() and not started[0].thread.is_alive()
    assert isinstance(started[0].out.get("error"), working.Cancelled)


def test_a_process_whose_bake_fails_with_work_under_way_exits():
    """The same in a process of its own that lets the error end it while the work is in a
    long piece with no checkpoint (numpy's): it exits with the error, and does not wait
    forever for a thread the interpreter's exit has stopped (a bake piped to ``head``
    hung so, and so did a cluster's bake whose worker was killed)."""
    code = (
        "import time\n"
        "from cubegi_engine import working\n"
        "from tests.engine.test_boxtree import _steps_with_work\n"
        "def work():\n"
        "    time.sleep(1.5)\n"
        "    working.checkpoint()\n"
        "def progress(step):\n"
        "    raise BrokenPipeError('the output reader is gone')\n"
        "working.run(_steps_with_work(work, []), progress)\n"
    )
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    r = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and "BrokenPipeError" in r.stderr


def test_steps_closed_as_the_interpreter_exits_wait_for_no_thread(monkeypatch):
    """Steps left open until the interpreter's exit collects them abandon their work
    without waiting for it: a daemon thread is stopped for good then, and its end would
    never come."""
    release = threading.Event()
    job = working.start(release.wait)
    monkeypatch.setattr(working.sys, "is_finalizing", lambda: True)
    leaving = threading.Thread(target=working.abandon, args=(job,), daemon=True)
    leaving.start()
    leaving.join(5.0)
    left = not leaving.is_alive()
    release.set()
    assert left and job.stop.is_set()


def test_no_ray_slips_between_two_triangles_along_their_shared_edge(monkeypatch):
    """A plate cut into a grid of triangles 10 cm over a floor (the scene's refinement cut
    it so), shadow rays from the floor towards a lamp, each crossing the plate on the line
    ``y = 0`` the triangles share: every one meets the plate (in float32 a ray along a
    shared edge missed both triangles, and a floor vertex under the plate came out lit)."""
    cell = 1.0 / 32.0
    xs, ys = 0.3125 + cell * np.arange(6), cell * np.arange(-2, 3)
    grid = np.array([(x, y, 0.1) for y in ys for x in xs])
    corner = np.arange(len(grid)).reshape(len(ys), len(xs))[:-1, :-1].ravel()
    w = len(xs)
    triangles = np.concatenate([np.stack([corner, corner + 1, corner + w + 1], axis=1),
                                np.stack([corner, corner + w + 1, corner + w], axis=1)])
    tree = boxtree.build(grid, triangles)
    lamp = np.array([0.0, 0.0, 2.0])
    x = np.linspace(0.35, 0.44, 400)
    origins = np.stack([x, np.full(400, -4.9547236439622114e-13), np.full(400, 1.6431676820374843e-05)], axis=1)
    to_lamp = lamp - origins
    reach = np.linalg.norm(to_lamp, axis=1)
    dirs = to_lamp / reach[:, None]
    met, _ = boxtree.walk(tree, origins, dirs, reach, any_hit=True)
    assert (met >= 0).all()
    monkeypatch.setattr(boxtree, "EDGE_SLACK", 0.0)
    met, _ = boxtree.walk(tree, origins, dirs, reach, any_hit=True)
    assert not (met >= 0).all()  # (what the slack is for: without it some slip through)


def test_a_near_hit_is_taken_again_in_float64_among_the_triangles_at_its_corners():
    """A float32 caster's near hit at a crease (a floor meeting a wall, rays from a hair off
    the floor into the corner) may name the wrong one of the two surfaces: taken again in
    float64 against the triangles at the hit triangle's corners, it names what testing every
    triangle names; a far hit is left as the caster gave it."""
    from cubegi_engine.geometry import corner_triangles
    from cubegi_engine.rays import near_hits_again

    points = np.array([[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0], [0, 0, 2], [0, 2, 2], [4, 0, 0]], dtype=np.float64)
    triangles = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 5], [0, 5, 4], [1, 6, 2]])
    rng = np.random.default_rng(7)
    origins = np.column_stack([rng.uniform(1e-4, 1e-3, 200), rng.uniform(0.1, 1.9, 200), rng.uniform(1e-6, 1e-4, 200)])
    dirs = rng.normal(size=(200, 3)) - [1.0, 0.0, 1.0]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    plain = NumpyRays(points, triangles).cast(origins, dirs)
    origins, dirs, plain = origins[plain.hit], dirs[plain.hit], NumpyRays(points, triangles).cast(origins[plain.hit], dirs[plain.hit])
    assert np.isin(plain.triangle, [0, 1]).sum() > 20 and np.isin(plain.triangle, [2, 3]).sum() > 20
    swapped = np.array([1, 0, 3, 2, 4])[plain.triangle]  # the other triangle of the same face
    wall_or_floor = np.where(np.isin(plain.triangle, [0, 1]), 2, 0)  # the other surface
    guess = np.where(np.arange(len(origins)) % 2 == 0, swapped, wall_or_floor)
    which, t = near_hits_again(points, triangles, corner_triangles(triangles, len(points)), 4.0, origins, dirs, None, guess,
                               plain.t.astype(np.float32).astype(np.float64))
    assert np.array_equal(which, plain.triangle) and t == pytest.approx(plain.t, rel=1e-9)
    # A caster's hit that float64 finds nearer than any triangle at its corners is kept: a cut
    # farther than it may lie past a triangle the caster's walk no longer tested.
    deep = plain.t > 6e-4
    which, _ = near_hits_again(points, triangles, corner_triangles(triangles, len(points)), 4.0, origins, dirs, None, guess,
                               np.where(deep, plain.t - 5e-4, plain.t))
    assert deep.sum() > 10 and np.array_equal(which[deep], guess[deep]) and np.array_equal(which[~deep], plain.triangle[~deep])
    far = plain.t * 1e4  # (beyond NEAR_AGAIN of the scene's size: not asked again)
    which, _ = near_hits_again(points, triangles, corner_triangles(triangles, len(points)), 4.0, origins, dirs, None, guess, far)
    assert np.array_equal(which, guess)
    # A near hit that float64 finds on none of the triangles at its corners (a ray that the
    # caster's float32 let graze an edge) stands as the caster gave it.
    past = np.array([[3.5, 1.5, 1e-4]]), np.array([[0.0, 0.0, -1.0]])  # beside triangle 4, over nothing
    which, t = near_hits_again(points, triangles, corner_triangles(triangles, len(points)), 4.0, *past, None, np.array([4]),
                               np.array([1e-4]))
    assert which.tolist() == [4] and t.tolist() == [1e-4]
