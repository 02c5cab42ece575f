"""Baking past one machine on Dask distributed (a LocalCluster of 2 workers here): a batch of
files gives what one-machine bakes give, a failing file does not stop the others, a killed
worker's task is retried, a second run resumes, and an animation split into chunks gives the
one-machine cache."""

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time

import bpy
import numpy as np
import pytest
import scenes
from interrupt import interrupt_cli, still_running

pytest.importorskip("distributed")

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
FAST = ["--grid", "3", "3", "2", "--cube-size", "8", "--bounces", "2"]
# Bakes on workers run the same code on the same machine: the same numbers. 1e-6 of the peak
# allows for another machine's float32 summation order.
SAME_TOL = 1e-6
# Chunks start with a full bake where one machine updates: equal to the tail solve's tolerance.
SOLVE_TOL = 2e-5


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "cubegi_engine", *map(str, args)], cwd=ROOT, capture_output=True, text=True, timeout=300)


@pytest.fixture
def three_files(empty_scene, cubegi, tmp_path):
    """Three small scenes and a corrupt file."""
    paths = []
    for k, build in enumerate((scenes.cornell, scenes.thin_wall, lambda: scenes.closed_box(albedo=0.6, cells=4))):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        build()
        if k == 2:
            scenes.add_light("POINT", (0.2, 0.1, 0.3), 20.0)
        paths.append(tmp_path / f"scene{k}.blend")
        bpy.ops.wm.save_as_mainfile(filepath=str(paths[-1]))
    broken = tmp_path / "broken.blend"
    broken.write_bytes(paths[0].read_bytes()[:3000])
    return paths, broken


def _attributes(path):
    bpy.ops.wm.open_mainfile(filepath=str(path))
    read = __import__("cubegi").cubegi_addon.attributes.read
    return {(ob.name, n): read(ob.data, n) for ob in bpy.data.objects if ob.type == "MESH"
            for n in ("CubeGI_direct", "CubeGI", "CubeGI_total")}


def _same(a, b, tol):
    assert a.keys() == b.keys()
    peak = max(v.max() for v in b.values())
    for key in b:
        np.testing.assert_allclose(a[key], b[key], rtol=0, atol=tol * peak, err_msg=str(key))


@pytest.mark.smoke
def test_a_batch_equals_one_machine_bakes_and_a_bad_file_stops_nothing(three_files, tmp_path):
    paths, broken = three_files
    out = tmp_path / "out"
    # Inputs that cannot be baked: a truncated .blend, a file that is no .blend, one named like
    # the summary. Each is reported; the rest are baked (one rule for every bad input).
    not_blend = tmp_path / "notes.txt"
    not_blend.write_text("not a blend file")
    named_batch = tmp_path / "batch.blend"
    named_batch.write_bytes(paths[0].read_bytes())
    r = _cli("batch", *paths, broken, not_blend, named_batch, "--out-dir", out, "--workers", "2", *FAST)
    assert r.returncode == 2, r.stderr  # files failed: reported, the rest baked
    summary = json.loads((out / "batch.json").read_text())
    status = {os.path.basename(f["file"]): f["status"] for f in summary["files"]}
    assert status == {"scene0.blend": "done", "scene1.blend": "done", "scene2.blend": "done", "broken.blend": "failed",
                      "notes.txt": "failed", "batch.blend": "failed"}
    errors = {os.path.basename(f["file"]): f["error"] for f in summary["files"] if f["status"] == "failed"}
    assert "cannot read the input" in errors["broken.blend"] and "broken.blend: cannot read the input" in r.stdout
    assert "not a .blend file" in errors["notes.txt"] and "batch.json" in errors["batch.blend"]
    assert "3 of 6 files failed" in r.stderr
    assert all(f["probes"] == 18 and f["seconds"] > 0 for f in summary["files"] if f["status"] == "done")
    for k, path in enumerate(paths):
        alone = tmp_path / f"alone{k}.blend"
        assert _cli("bake", path, "-o", alone, *FAST).returncode == 0
        _same(_attributes(out / f"scene{k}.blend"), _attributes(alone), SAME_TOL)
    # A second run resumes: a file is skipped while its content and the options are what its
    # bake was made from (a touched file is unchanged), baked again when either changed.
    def run(*options):
        r = _cli("batch", *paths, "--out-dir", out, "--workers", "2", *options)
        assert r.returncode == 0, r.stderr
        return {os.path.basename(f["file"]): f["status"] for f in json.loads((out / "batch.json").read_text())["files"]}

    time.sleep(1.1)
    os.utime(paths[0])  # newer, same content
    bpy.ops.wm.open_mainfile(filepath=str(paths[1]))
    next(o for o in bpy.data.objects if o.type == "MESH").location.x += 0.01  # the content changes, not only the time
    bpy.ops.wm.save_as_mainfile(filepath=str(paths[1]))
    assert run(*FAST) == {"scene0.blend": "skipped", "scene1.blend": "done", "scene2.blend": "skipped"}
    assert run(*FAST[:-1], "1") == {"scene0.blend": "done", "scene1.blend": "done", "scene2.blend": "done"}  # other options
    assert not [n for n in os.listdir(out) if n.startswith(".cubegi-") or n.endswith(".blend1")]  # nothing half-written


def test_a_batch_key_holds_the_code_that_baked_it(cubegi, tmp_path):
    """A batch skips a file only while its key is unchanged: a bake made by other CubeGI code
    (the same version number) is made again. The key holds a digest of the code's content,
    not of its files' times."""
    from cubegi.cubegi_addon import cluster as cluster_mod

    root = os.path.dirname(os.path.dirname(cluster_mod.__file__))
    copy = tmp_path / "ext"
    for package in ("cubegi_addon", "cubegi_engine"):
        shutil.copytree(os.path.join(root, package), copy / package, ignore=shutil.ignore_patterns("__pycache__"))
    assert cluster_mod.code_digest(copy) == cluster_mod.code_digest(root)
    specular = copy / "cubegi_engine" / "specular.py"
    time.sleep(0.01)
    os.utime(specular)  # newer, same content: the same code
    cluster_mod._CODE_DIGESTS.clear()
    assert cluster_mod.code_digest(copy) == cluster_mod.code_digest(root)
    specular.write_text(specular.read_text().replace("F0_POWER = 0.8", "F0_POWER = 0.7"))
    cluster_mod._CODE_DIGESTS.clear()
    assert cluster_mod.code_digest(copy) != cluster_mod.code_digest(root)
    src = tmp_path / "a.blend"
    src.write_bytes(b"BLENDER")
    assert cluster_mod.job_key(src, ["--fast"])["cubegi_code"] == cluster_mod.code_digest(root)


def test_a_killed_workers_bake_is_retried_and_gives_the_same_light(three_files, tmp_path, cubegi, monkeypatch):
    from distributed import Client, LocalCluster

    from cubegi.cubegi_addon import cluster as cluster_mod
    paths, _ = three_files
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    client = Client(cluster)
    monkeypatch.setattr(cluster_mod, "_client", lambda workers=None, scheduler=None: (client, cluster))
    killed = []

    def kill_a_busy_worker():
        deadline = time.time() + 60
        while time.time() < deadline and not killed:
            busy = [w for w, tasks in client.processing().items() if tasks]
            if busy:
                pids = client.run(os.getpid, workers=busy[:1])
                for pid in pids.values():
                    os.kill(pid, signal.SIGKILL)
                    killed.append(pid)
            time.sleep(0.05)

    killer = threading.Thread(target=kill_a_busy_worker)
    killer.start()
    options = ["--grid", "3", "3", "2", "--cube-size", "8", "--bounces", "2"]
    summary = cluster_mod.batch([str(p) for p in paths], str(tmp_path / "out"), options, workers=2, log=lambda m: None)
    killer.join()
    assert killed, "no worker was busy to kill"
    assert [f.status for f in summary.files] == ["done", "done", "done"]
    for k, path in enumerate(paths):
        alone = tmp_path / f"alone{k}.blend"
        assert _cli("bake", path, "-o", alone, *options).returncode == 0
        _same(_attributes(tmp_path / "out" / f"scene{k}.blend"), _attributes(alone), SAME_TOL)


def _lamp_moving_in_a_room(tmp_path, last):
    """A room lit by a lamp that moves from frame 1 to ``last``, saved; its path."""
    v, f = scenes.box_mesh((-2, -2, 0), (2, 2, 2.5), (6, 6, 4), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    lamp = scenes.add_light("POINT", (1.2, -1.2, 2.0), 150.0)
    lamp.keyframe_insert("location", frame=1)
    lamp.location = (-1.2, 1.2, 1.6)
    lamp.keyframe_insert("location", frame=last)
    src = tmp_path / "anim.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(src))
    return src


def _frames_in(folder):
    return sorted(n for n in os.listdir(folder) if n.startswith("frame_"))


def test_an_animation_in_chunks_gives_the_one_machine_cache(empty_scene, cubegi, tmp_path):
    src = _lamp_moving_in_a_room(tmp_path, last=16)
    one, many = tmp_path / "one" / "out.blend", tmp_path / "many" / "out.blend"
    one.parent.mkdir()
    many.parent.mkdir()
    assert _cli("bake-animation", src, "-o", one, "--frames", "1", "16", *FAST).returncode == 0
    report = tmp_path / "many.json"
    r = _cli("bake-animation", src, "-o", many, "--frames", "1", "16", "--workers", "2", "--report", report, *FAST)
    assert r.returncode == 0, r.stderr
    rep = json.loads(report.read_text())
    assert [(c["first"], c["last"]) for c in rep["chunks"]] == [(1, 8), (9, 16)]
    assert [f["frame"] for f in rep["frames"]] == list(range(1, 17))
    assert [f["path"] for f in rep["frames"]][:2] == ["full", "lights"] and rep["frames"][8]["path"] == "full"
    assert _frames_in(many.parent / "out.cubegi") == _frames_in(one.parent / "out.cubegi")
    for frame in range(1, 17):
        name = f"frame_{frame:04d}.npz"
        with np.load(one.parent / "out.cubegi" / name) as a, np.load(many.parent / "out.cubegi" / name) as b:
            _same({k: b[k] for k in b.files}, {k: a[k] for k in a.files}, SOLVE_TOL)
    assert not [n for n in os.listdir(many.parent) if n.startswith(".cubegi-")]
    bpy.ops.wm.open_mainfile(filepath=str(many))
    assert bpy.context.scene.cubegi.animation_cache == "//out.cubegi"
    # Run again: with nothing changed it bakes nothing and says so; after the input changed
    # (the lamp quartered) every frame is baked again (before: "baked 0 frames", the old cache).
    again = ("bake-animation", src, "-o", many, "--frames", "1", "16", "--workers", "2", *FAST)
    r = _cli(*again)
    assert r.returncode == 0 and "is up to date" in r.stdout and "nothing baked" in r.stdout, r.stdout + r.stderr
    with np.load(many.parent / "out.cubegi" / "frame_0005.npz") as data:
        before = data["Room:direct"]
    bpy.ops.wm.open_mainfile(filepath=str(src))
    bpy.data.lights["point"].energy /= 4.0
    bpy.ops.wm.save_as_mainfile(filepath=str(src))
    r = _cli(*again)
    assert r.returncode == 0 and "baked 16 frames" in r.stdout, r.stdout + r.stderr
    with np.load(many.parent / "out.cubegi" / "frame_0005.npz") as data:
        np.testing.assert_allclose(data["Room:direct"], before / 4.0, rtol=1e-4, atol=1e-6 * before.max())


def test_an_unreachable_scheduler_is_refused_in_one_line(three_files, tmp_path):
    """A scheduler address where nothing listens is the user's situation: status 2 and one
    line saying what to do (before: status 3 and "please report it")."""
    paths, _ = three_files
    import socket

    with socket.socket() as s:  # a free port on this machine, closed again: nothing listens there
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    r = _cli("batch", paths[0], "--out-dir", tmp_path / "out", "--scheduler", f"tcp://127.0.0.1:{port}", *FAST)
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "cannot reach the Dask scheduler" in lines[0] and "please report" not in lines[0], r.stderr


def test_ctrl_c_in_a_batch_stops_every_bake_keeps_the_finished_ones_and_prints_no_traceback(three_files, tmp_path):
    """Ctrl-C reaches the command, its Dask workers and their bakes (a terminal's process
    group): status 130, one line naming the files baked (whole, with their reports; a run
    again skips them), ``batch.json`` listing the rest as interrupted, no traceback from any
    process (before: a traceback from each worker and "nothing was written"), no bake left
    running; another dashboard on Dask's default port adds no line."""
    paths, _ = three_files
    inputs = []
    for k in range(8):  # eight inputs on two workers: some are done, some under way, some not started
        inputs.append(tmp_path / f"in{k}.blend")
        inputs[-1].write_bytes(paths[k % 3].read_bytes())
    out = tmp_path / "out"
    def one_done():  # a report the batch has stamped as done (written whole, so readable)
        return any("batch_key" in p.read_text() for p in out.glob("*.json"))

    # Another Dask dashboard on its default port (a second batch on the machine): still one line.
    with socket.socket() as other:
        try:
            other.bind(("", 8787))
            other.listen()
        except OSError:
            pass  # taken already: the same case
        rc, stdout, err = interrupt_cli(["batch", *inputs, "--out-dir", out, "--workers", "2", *FAST], one_done)
    assert rc == 128 + signal.SIGINT, stdout + err
    assert err.splitlines() and all(ln.startswith("cubegi: ") for ln in err.splitlines()), err  # one line, nothing else
    summary = json.loads((out / "batch.json").read_text())
    status = {os.path.basename(f["file"]): f["status"] for f in summary["files"]}
    done = sorted(n for n, s in status.items() if s == "done")
    assert done and set(status.values()) <= {"done", "interrupted"} and len(done) < len(inputs), [(f["status"], f["error"]) for f in summary["files"]]
    assert err.splitlines() == [f"cubegi: interrupted; {len(done)} of {len(inputs)} files are baked into {out} "
                                f"({', '.join(n for n in status if n in done)}; each whole, with its report; a run again "
                                "skips them); batch.json lists the rest as interrupted"]
    for name, s in status.items():
        stem = name.removesuffix(".blend")
        assert (out / f"{stem}.blend").exists() == (s == "done") or s == "interrupted", name
    assert not [n for n in os.listdir(out) if n.startswith(".cubegi")]
    time.sleep(1.0)
    assert still_running(str(tmp_path)) == []  # no bake runs on
    again = _cli("batch", *inputs, "--out-dir", out, "--workers", "2", *FAST)
    assert again.returncode == 0, again.stderr
    rerun = {os.path.basename(f["file"]): f["status"] for f in json.loads((out / "batch.json").read_text())["files"]}
    assert rerun == {n: "skipped" if n in done else "done" for n in status}


def test_ctrl_c_in_an_animation_on_a_cluster_keeps_the_frames_and_says_so(empty_scene, cubegi, tmp_path):
    src = _lamp_moving_in_a_room(tmp_path, last=400)
    out = tmp_path / "out.blend"
    cache = tmp_path / "out.cubegi"
    rc, stdout, err = interrupt_cli(["bake-animation", src, "-o", out, "--frames", "1", "400", "--workers", "2", *FAST],
                                    lambda: len(list(cache.glob("frame_*.npz"))) >= 4)
    assert rc == 128 + signal.SIGINT, stdout + err
    assert err.splitlines() == [f"cubegi: interrupted; the frames baked so far are kept in {cache} (each frame whole); "
                                f"{out} was not written; a run again bakes every frame"], err
    for frame in cache.glob("frame_*.npz"):
        with np.load(frame) as data:
            assert set(data.files) == {"Room:direct", "Room:indirect"}
    assert not out.exists() and not (cache / cubegi.cubegi_addon.animation.KEY_FILE).exists()
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".cubegi")]
    time.sleep(1.0)
    assert still_running(str(tmp_path)) == []


def test_the_local_workers_log_nothing_but_a_crash_and_the_environment_is_as_it_was(cubegi, monkeypatch):
    """A batch's local workers keep distributed's logging off the terminal below a crash
    (a worker's warning as Ctrl-C cancelled its task was a second line now and then): set in
    the environment while the cluster lives (a worker started again takes it too), then
    gone; a level the user set is theirs. This process's own logging is as it was."""
    import logging

    from cubegi.cubegi_addon import cluster

    state_machine = logging.getLogger("distributed.worker.state_machine")
    for given, want in ((None, logging.CRITICAL), ("error", logging.ERROR)):
        if given is None:
            monkeypatch.delenv(cluster.WORKER_LOGGING, raising=False)
        else:
            monkeypatch.setenv(cluster.WORKER_LOGGING, given)
        client, local = cluster._client(workers=1)
        try:
            level = client.submit(state_machine.getEffectiveLevel, pure=False).result(timeout=120)
            during = os.environ.get(cluster.WORKER_LOGGING)
        finally:
            cluster._close(client, local)
        assert level == want and during == (given or "critical")
        assert os.environ.get(cluster.WORKER_LOGGING) == given
    assert state_machine.getEffectiveLevel() < logging.CRITICAL
