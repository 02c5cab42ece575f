"""Bakes past one machine: many files, or one animation's frame range in chunks, on Dask
distributed (a LocalCluster by default, any running scheduler by address; through
``dask-jobqueue``, the Slurm or PBS clusters studios already run).

Each bake runs in a process of its own, started by a Dask worker: ``python -m cubegi_engine
bake ...`` (or ``bake-animation --frames A B``). bpy holds one scene per process, so one
process per bake keeps bakes apart; a crash (a segfault, a GPU context that fails to start)
ends only that process: the file is reported as failed and the others go on. A worker that
dies itself (killed, out of memory) is replaced by Dask and its task retried. Every output
is written whole by the bake itself (temporary name, renamed), so an interrupted job leaves
finished outputs whole and no half-written file; a second run skips what is done and valid.

Run from the source tree (the command line): imports no bpy; needs ``dask`` and
``distributed``. A task is ``subprocess.run`` of a command line, so a worker imports
nothing of CubeGI: it needs this source tree at the same path, its Python (the venv with
bpy) and EGL for the GPU module (see docs/command-line.md#baking-on-a-cluster).
"""

import hashlib
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass
from enum import StrEnum

from ..cubegi_engine import __version__
from ..cubegi_engine.errors import ERROR_PREFIX, BakeError, Interrupted
from ..cubegi_engine.records import FrameRecord
from ..cubegi_engine.report import BakeReport
from . import files

# The source tree every worker runs ``python -m cubegi_engine`` from.
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# Seconds one bake may take in its process before it is stopped and reported as failed.
BAKE_TIMEOUT = 3600
# A chunk of an animation starts with a full bake (about 0.45 s on the demo Room here) and
# then updates a frame at a time (23-71 ms): below this many frames a chunk's full bake
# outweighs its updates, so a chunk has at least this many frames (measured with
# benchmarks/bench_animation.py: a full bake costs 6x to 19x a frame's update).
MIN_FRAMES_PER_CHUNK = 8
# Tasks of a worker that died are retried this many times.
RETRIES = 2
# Seconds between the progress lines a job prints.
PROGRESS_SECONDS = 5.0
# The field of a bake's report that holds what it was made from (job_key).
KEY_FIELD = "batch_key"
# The exit statuses of a bake stopped by Ctrl-C or SIGTERM (its own 128 + signal, or the
# signal's where it came before the command line's handlers): it wrote nothing.
STOPPED = {-signal.SIGINT, -signal.SIGTERM, 128 + signal.SIGINT, 128 + signal.SIGTERM}
# Seconds an interrupted job waits for its workers to finish the bakes under way (which stop
# on the same Ctrl-C) before it closes them.
STOP_SECONDS = 10
# Seconds to wait for a scheduler to answer before the batch is refused.
SCHEDULER_TIMEOUT = 10
SUMMARY = "batch.json"
# The environment variable distributed reads its logger levels from (dask's config: logging.distributed).
WORKER_LOGGING = "DASK_LOGGING__DISTRIBUTED"


class BatchStatus(StrEnum):
    """What became of one bake of a batch (or one chunk of an animation)."""

    DONE = "done"
    SKIPPED = "skipped"  # done before, with the same input, options and version
    FAILED = "failed"
    INTERRUPTED = "interrupted"


@dataclass(frozen=True)
class BatchRecord:
    """One file of a batch: its ``status``, and where it was baked (``seconds``: its bake's
    own time, from its report), its output and report, probes and estimated missing light;
    ``error``: why it failed."""

    file: str
    status: BatchStatus
    seconds: float | None = None
    output: str | None = None
    report: str | None = None
    probes: int | None = None
    estimated_remaining_error: float | None = None
    error: str | None = None

    def to_dict(self) -> dict:
        return {**asdict(self), "status": str(self.status)}


@dataclass(frozen=True)
class BatchSummary:
    """A batch: its files in the order given, its time, and where it ran."""

    files: tuple[BatchRecord, ...]
    seconds: float
    workers: int | None
    scheduler: str | None

    def count(self, status: BatchStatus) -> int:
        return sum(r.status == status for r in self.files)

    def to_dict(self) -> dict:
        return {"files": [r.to_dict() for r in self.files], "seconds": self.seconds, "workers": self.workers,
                "scheduler": self.scheduler}


@dataclass(frozen=True)
class ChunkRecord:
    """One chunk of an animation baked on a cluster: frames ``first..last``, its status and
    error, and its frames' records."""

    first: int
    last: int
    status: BatchStatus
    error: str | None = None
    frames: tuple[FrameRecord, ...] = ()


@dataclass(frozen=True)
class ClusterAnimation:
    """An animation baked on a cluster: every frame's record in order, the chunks baked, the
    time, the cache folder, and whether it was up to date (nothing baked)."""

    frames: tuple[FrameRecord, ...]
    chunks: tuple[ChunkRecord, ...]
    seconds: float
    cache: str
    up_to_date: bool

    def to_dict(self) -> dict:
        return {"frames": [f.to_dict() for f in self.frames],
                "chunks": [{"first": c.first, "last": c.last, "status": str(c.status)} for c in self.chunks],
                "seconds": self.seconds, "cache": self.cache, "up_to_date": self.up_to_date}


def _client(workers=None, scheduler=None):
    """A Dask client: to ``scheduler`` if given, else to a LocalCluster of ``workers``
    processes of one thread each (each bake is a process of its own anyway)."""
    try:
        import dask
        from distributed import Client, LocalCluster
    except ImportError:
        raise BakeError("baking on a cluster needs dask and distributed: pip install dask distributed") from None
    if scheduler:
        try:
            return Client(scheduler, timeout=SCHEDULER_TIMEOUT), None
        except (OSError, TimeoutError, ValueError) as exc:  # the user's address or network, not a CubeGI defect
            reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise BakeError(f"cannot reach the Dask scheduler at {scheduler} ({reason}); start it (dask scheduler) or "
                            "check the address") from None
    # The workers start with Ctrl-C ignored (an inherited disposition): Ctrl-C reaches every
    # process of the terminal's group, and a worker would end with a traceback of its own.
    # The bakes they run stop on it (the command line catches it); this process closes the
    # cluster.
    ignore = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if ignore else None
    # The workers log nothing to the terminal but a crash: the batch reports each bake's
    # outcome itself (a worker's warning as Ctrl-C cancelled its task, printed now and then,
    # was a second line). A worker process takes its levels from the environment it starts
    # with, when it imports distributed: set while the cluster lives (a worker started again
    # takes it too), unless the user set it.
    ours = WORKER_LOGGING not in os.environ
    if ours:
        os.environ[WORKER_LOGGING] = "critical"
    cluster = None
    try:
        # One task on a worker at a time (none waits there behind a bake): the tasks a worker
        # is processing are then the bakes it runs (see _stop).
        # Its dashboard on a free port (None means 8787: a second batch on the machine printed
        # distributed's warning that the port is taken).
        with dask.config.set({"distributed.scheduler.worker-saturation": 1.0}):
            cluster = LocalCluster(n_workers=int(workers or 2), threads_per_worker=1, processes=True, dashboard_address=":0")
    finally:
        if ignore:
            signal.signal(signal.SIGINT, previous)
        if ours and cluster is None:  # not started
            os.environ.pop(WORKER_LOGGING, None)
    cluster.cubegi_logging = ours  # (see _close)
    return Client(cluster), cluster


def _close(client, cluster):
    """Close the client (and the local cluster); its closing chatter (logged cancellations)
    is kept off the terminal. Returns the KeyboardInterrupt of a Ctrl-C while closing, or
    None (the local workers are daemon processes: they end with this one)."""
    import logging

    log = logging.getLogger("distributed")
    level = log.level
    log.setLevel(logging.CRITICAL)
    try:
        client.close()
        if cluster is not None:
            cluster.close()
    except KeyboardInterrupt as exc:
        return exc
    finally:
        log.setLevel(level)
        if getattr(cluster, "cubegi_logging", False):  # the workers' logging, set for them alone
            os.environ.pop(WORKER_LOGGING, None)
    return None


def _submit(client, args, timeout=BAKE_TIMEOUT):
    """One bake as a task: ``subprocess.run`` of ``python -m cubegi_engine *args`` in the
    source tree (only the standard library crosses to the worker)."""
    command = [sys.executable, "-m", "cubegi_engine", *args]
    return client.submit(subprocess.run, command, cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                         retries=RETRIES, pure=False)


def _outcome(future):
    """``(BatchStatus, error)`` of a finished task: its process's exit, or the task's failure."""
    if future.status != "finished":
        exc = future.exception()
        if isinstance(exc, subprocess.TimeoutExpired):
            return BatchStatus.FAILED, f"stopped after {exc.timeout} s"
        return BatchStatus.FAILED, f"its worker failed {RETRIES + 1} times ({type(exc).__name__}: {exc})"
    r = future.result()
    if r.returncode == 0:
        return BatchStatus.DONE, None
    if r.returncode in STOPPED:
        return BatchStatus.INTERRUPTED, None
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith(ERROR_PREFIX)]
    if errors:
        return BatchStatus.FAILED, errors[-1].removeprefix(ERROR_PREFIX)
    return BatchStatus.FAILED, f"the bake's process ended with status {r.returncode} (a crash; the other bakes went on)"


def _wait(client, futures, log, finished):
    """Wait for every task, calling ``finished(k, future)`` as the ``k``-th finishes (in the
    order they finish; it must be safe to call twice for one task), with a line every
    PROGRESS_SECONDS. Returns None, or the
    KeyboardInterrupt (Ctrl-C, SIGTERM) that stopped it, once the tasks not started are
    cancelled and the bakes under way have ended (:func:`_stop`; ``finished`` is called for
    those that finished)."""
    from distributed import wait

    t0 = time.perf_counter()
    left = dict(enumerate(futures))
    stopped = None
    try:
        while left:
            try:
                wait(list(left.values()), timeout=PROGRESS_SECONDS, return_when="FIRST_COMPLETED")
            except TimeoutError:
                pass
            done = [k for k, f in left.items() if f.done()]
            for k in done:
                finished(k, left[k])
                del left[k]  # after: an interrupt inside finished() (its write) has it finished again below
            if not done:
                log(f"{len(futures) - len(left)}/{len(futures)} done after {time.perf_counter() - t0:.0f} s")
    except KeyboardInterrupt as exc:  # the bakes under way stop too: they get the same Ctrl-C
        stopped = exc
        _stop(client, list(left.values()))
        for k in [k for k, f in left.items() if f.status == "finished"]:
            finished(k, left.pop(k))
    return stopped


def _stop(client, futures):
    """After an interrupt: cancel the tasks no worker has started, and give the bakes under
    way up to STOP_SECONDS to end (they stop on the same Ctrl-C), so that closing the workers
    cuts no task short (a worker closed mid-task logs it, and its bake would run on)."""
    from distributed import wait

    try:
        running = {key for keys in client.processing().values() for key in keys}
        client.cancel([f for f in futures if f.key not in running and not f.done()])
        wait([f for f in futures if f.key in running], timeout=STOP_SECONDS)
    except (TimeoutError, KeyboardInterrupt):  # a bake that does not stop, or a second Ctrl-C: close now
        pass


def _paths(src, out_dir):
    name = os.path.splitext(os.path.basename(src))[0]
    return os.path.join(out_dir, f"{name}.blend"), os.path.join(out_dir, f"{name}.json")


def _record(src, out_dir, status, error=None):
    """A file's :class:`BatchRecord` (read from its report where it was baked)."""
    if status not in (BatchStatus.DONE, BatchStatus.SKIPPED):
        return BatchRecord(src, status, error=error)
    out, path = _paths(src, out_dir)
    with open(path) as fh:
        report = BakeReport.from_json(fh.read())
    return BatchRecord(src, status, round(report.total_seconds, 3), out, path, report.grid.probes,
                       report.estimated_remaining_error, error)


def job_key(src, options):
    """What a file's bake was made from: the input's content (SHA-256 of its bytes, not its
    time), the bake options, CubeGI's version and its code (:func:`code_digest`: a bake made
    by other code is made again, whatever the version says). A batch skips a file only while
    this is unchanged; images or libraries the file links to are not part of it."""
    digest = hashlib.sha256()
    with open(src, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return {"input_sha256": digest.hexdigest(), "options": list(options), "cubegi_version": __version__,
            "cubegi_code": code_digest()}


_CODE_DIGESTS = {}


def code_digest(root=None):
    """SHA-256 of CubeGI's own code: every ``.py`` file of ``cubegi_addon`` and ``cubegi_engine``
    under ``root`` (the extension's folder; default: this one), by path and content; made once
    per process and folder."""
    root = os.path.realpath(root or os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    if root not in _CODE_DIGESTS:
        digest = hashlib.sha256()
        for package in ("cubegi_addon", "cubegi_engine"):
            for folder, dirs, names in sorted(os.walk(os.path.join(root, package))):
                dirs.sort()
                for name in sorted(n for n in names if n.endswith(".py")):
                    path = os.path.join(folder, name)
                    digest.update(os.path.relpath(path, root).encode() + b"\0")
                    with open(path, "rb") as fh:
                        digest.update(hashlib.sha256(fh.read()).digest())
        _CODE_DIGESTS[root] = digest.hexdigest()
    return _CODE_DIGESTS[root]


def _done_before(src, out_dir, key):
    """True if ``src``'s output and report exist and its report carries ``key`` (resume)."""
    out, report = _paths(src, out_dir)
    try:
        with open(report) as fh:
            data = json.load(fh)
        return data.get("input") == os.path.realpath(src) and os.path.isfile(out) and data.get(KEY_FIELD) == key
    except (OSError, ValueError, KeyError):
        return False


def _stamp(report, key):
    """Add ``key`` to a finished bake's report (written whole, as every CubeGI file)."""
    with open(report) as fh:
        data = json.load(fh)
    data[KEY_FIELD] = key
    text = json.dumps(data, indent=2, allow_nan=False)
    files.write_all([(report, files.text(text))])



def batch(inputs, out_dir, options, workers=None, scheduler=None, log=print, refused=None):
    """Bake every file of ``inputs`` into ``out_dir`` (``name.blend``, ``name.json``); returns
    the :class:`BatchSummary` and writes it to ``out_dir/batch.json``. ``refused``: {input: why} of inputs
    that cannot be baked (reported as failed, as is an input whose report would be the
    summary); the others are baked."""
    os.makedirs(out_dir, exist_ok=True)
    names = [os.path.splitext(os.path.basename(f))[0] for f in inputs]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise BakeError(f"two inputs would write the same output name: {', '.join(twice)}; rename one")
    refused = {os.path.realpath(k): v for k, v in (refused or {}).items()}
    for src in map(os.path.realpath, inputs):
        if _paths(src, out_dir)[1] == os.path.join(out_dir, SUMMARY):
            refused.setdefault(src, f"its report would be the batch's summary {SUMMARY}; rename the file")
    t0 = time.perf_counter()
    records, todo = {}, []
    for src, why in refused.items():
        records[src] = _record(src, out_dir, BatchStatus.FAILED, why)
    keys = {src: job_key(src, options) for src in map(os.path.realpath, inputs) if src not in refused}
    for src in keys:
        if _done_before(src, out_dir, keys[src]):
            records[src] = _record(src, out_dir, BatchStatus.SKIPPED)
        else:
            todo.append(src)
    stopped = None
    if todo:
        client, cluster = _client(workers, scheduler)
        try:
            if cluster is None and getattr(client, "dashboard_link", None):
                log(f"batch: the Dask dashboard: {client.dashboard_link}")
            futures = [_submit(client, ["bake", src, "-o", _paths(src, out_dir)[0], "--report", _paths(src, out_dir)[1], *options])
                       for src in todo]

            def finished(k, future):
                src = todo[k]
                status, error = _outcome(future)
                if status == BatchStatus.DONE:
                    _stamp(_paths(src, out_dir)[1], keys[src])  # as each finishes: an interrupted batch resumes
                records[src] = _record(src, out_dir, status, error)
                log(f"batch: {os.path.basename(src)} {status} ({sum(s in records for s in todo)}/{len(todo)})")

            stopped = _wait(client, futures, lambda m: log(f"batch: {m}"), finished)
        finally:
            stopped = _close(client, cluster) or stopped
        for src in todo:
            records.setdefault(src, _record(src, out_dir, BatchStatus.INTERRUPTED))
    summary = BatchSummary(tuple(records[os.path.realpath(f)] for f in inputs), round(time.perf_counter() - t0, 3),
                           None if scheduler else int(workers or 2), scheduler)
    text = json.dumps(summary.to_dict(), indent=2, allow_nan=False)
    files.write_all([(os.path.join(out_dir, SUMMARY), files.text(text))])
    if stopped is not None:
        done = [os.path.basename(src) for src in todo if records[src].status == BatchStatus.DONE]
        raise Interrupted.keeping(stopped, f"{len(done)} of {len(todo)} files are baked into {out_dir}"
                                  + (f" ({', '.join(done)}; each whole, with its report; a run again skips them)" if done else "")
                                  + f"; {SUMMARY} lists the rest as interrupted")
    return summary


def summary_lines(summary: BatchSummary):
    """The batch's table: file, status, seconds, probes, estimated missing light."""
    rows = [("file", "status", "seconds", "probes", "missing")]
    for rec in summary.files:
        err = rec.estimated_remaining_error
        rows.append((os.path.basename(rec.file), str(rec.status), f"{rec.seconds:.2f}" if rec.seconds is not None else "-",
                     str(rec.probes or "-"), f"{100 * err:.2g}%" if err is not None else "-"))
    width = [max(len(r[k]) for r in rows) for k in range(5)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, width)).rstrip() for r in rows]
    lines += [f"{os.path.basename(r.file)}: {r.error}" for r in summary.files if r.error]
    return lines


def chunks(first, last, workers):
    """The frame range cut into chunks ``[(a, b)]``: one per worker, but none shorter than
    MIN_FRAMES_PER_CHUNK frames (see it)."""
    frames = last - first + 1
    count = max(1, min(int(workers), frames // MIN_FRAMES_PER_CHUNK))
    size = math.ceil(frames / count)
    return [(a, min(a + size - 1, last)) for a in range(first, last + 1, size)]


def bake_animation(src, out, first, last, options, workers=None, scheduler=None, log=print):
    """Bake frames ``first..last`` of ``src`` in chunks on Dask: the cache ``OUT.cubegi/``
    and ``OUT.blend`` as one machine writes them (the first chunk writes the .blend). Returns
    a :class:`ClusterAnimation`. A chunk whose
    frames are all in the cache already (a second run) is not baked again, while the cache's
    key (:data:`.animation.KEY_FILE`: the input's content, the options, the version) is this
    run's; with another key every frame is baked again."""
    from .animation import KEY_FILE, cache_folder, frame_path

    cache = cache_folder(out)
    os.makedirs(cache, exist_ok=True)
    key, key_path = job_key(src, options), os.path.join(cache, KEY_FILE)
    try:
        with open(key_path) as fh:
            same = json.load(fh) == key
    except (OSError, ValueError):
        same = False
    parts = chunks(first, last, workers or 2)
    todo = [(a, b) for a, b in parts
            if not same or not all(os.path.isfile(frame_path(cache, f)) for f in range(a, b + 1))
            or (a == first and not os.path.isfile(out))]
    if todo and os.path.exists(key_path):
        os.remove(key_path)  # frames of two keys may mix until every chunk is done: no key meanwhile
    t0 = time.perf_counter()
    scratch = tempfile.mkdtemp(prefix=".cubegi-chunks-", dir=os.path.dirname(out))
    results, stopped = [], None
    try:
        if todo:
            client, cluster = _client(workers, scheduler)
            try:
                futures, reports = [], []
                for k, (a, b) in enumerate(todo):
                    blend = out if a == first else os.path.join(scratch, f"chunk_{k}.blend")
                    reports.append(os.path.join(scratch, f"chunk_{k}.json"))
                    futures.append(_submit(client, ["bake-animation", src, "-o", blend, "--frames", str(a), str(b),
                                                    "--cache-dir", cache, "--report", reports[-1], *options]))
                finished = {}

                def chunk_finished(k, future):
                    status, error = _outcome(future)
                    frames: tuple[FrameRecord, ...] = ()
                    if status == BatchStatus.DONE:
                        with open(reports[k]) as fh:
                            frames = tuple(FrameRecord.from_dict(f) for f in json.load(fh)["frames"])
                    finished[k] = ChunkRecord(todo[k][0], todo[k][1], status, error, frames)

                stopped = _wait(client, futures, lambda m: log(f"bake-animation: {m}"), chunk_finished)
                results = [finished[k] for k in sorted(finished)]
            finally:
                stopped = _close(client, cluster) or stopped
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    if stopped is not None:
        wrote = "was written" if any(r.first == first and r.status == BatchStatus.DONE for r in results) else "was not written"
        raise Interrupted.keeping(stopped, f"the frames baked so far are kept in {cache} (each frame whole); {out} {wrote}; "
                                           "a run again bakes every frame")
    failed = [r for r in results if r.status != BatchStatus.DONE]
    if failed:
        raise BakeError(f"frames {failed[0].first}-{failed[0].last} failed: {failed[0].error or failed[0].status}")
    if todo or not same:
        text = json.dumps(key, indent=2)
        files.write_all([(key_path, files.text(text))])
    frames = tuple(sorted((f for r in results for f in r.frames), key=lambda f: f.frame))
    return ClusterAnimation(frames, tuple(results), round(time.perf_counter() - t0, 3), cache, not todo)
