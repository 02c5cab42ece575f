"""Long steps of a bake, handed back to whoever drives it every WORKING_SECONDS or so.

A bake is a generator of :class:`~cubegi_engine.records.Progress`; the add-on's modal operator
advances it one step per timer event, so Blender redraws and Esc cancels between steps. A
step that would run for seconds (drawing hundreds of probes, building the tables, shadowing
many lights) is cut: GPU work into batches of about WORKING_SECONDS each (the GPU context is
the main thread's), numpy-only work run in a thread of its own while the generator yields
*working* steps (``Progress.working``) every WORKING_SECONDS. A working step carries no light;
:func:`~cubegi_engine.bake.run` does not report it. A generator driven through
:class:`Driven` (as :func:`run` and the add-on's operators drive it) stops the threads its
steps started when it is closed (a cancel) or fails: each ends at its next piece of work
(:func:`checkpoint`, raising :class:`Cancelled` there), and its result is dropped.
"""

import ctypes
import os
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor

__all__ = ["WORKING_SECONDS", "CAPTURE_DRAWS_PER_STEP", "WORKERS", "run", "in_background", "in_batches", "start", "wait",
           "give_back_memory", "in_parallel", "made_once", "once", "result", "Driven", "Cancelled", "checkpoint", "on_main",
           "NotServed", "serve_waiting", "abandon"]

# Seconds between the steps a long piece of work hands back.
WORKING_SECONDS = 0.1
# Triangles drawn (six cube faces of each probe, each face every drawn triangle) per batch of
# the capture: about WORKING_SECONDS on llvmpipe (measured on The Breakfast Room: 42 ms a probe
# of 190K triangles, 37 ns a triangle drawn); a GPU draws a batch in far less.
CAPTURE_DRAWS_PER_STEP = 2_500_000
# Threads that share numpy work cut into independent pieces (numpy lets go of the GIL in its
# loops, so they run on as many cores): the machine's cores, at most 8, or CUBEGI_WORKERS (each
# thread's pieces are in memory at once: at 95K vertices the bake's peak was 1.2 GB with 2
# threads and 1.6 GB with 8).
def _workers():
    try:
        asked = int(os.environ.get("CUBEGI_WORKERS", "0"))
    except ValueError:
        asked = 0
    return max(1, asked if asked > 0 else min(os.cpu_count() or 1, 8))


WORKERS = _workers()


class Cancelled(BaseException):
    """Raised in a thread at its next piece of work (:func:`checkpoint`) once the generator
    it works for was closed or failed (see :class:`Driven`). Not an Exception: no fallback
    that catches those runs in its place."""


# What the current thread works for: ``.stop``, the Event of the driven generator whose step
# started it (None: nothing that stops).
_work = threading.local()


def checkpoint():
    """Raise :class:`Cancelled` where the generator this thread works for has stopped:
    called between pieces of work (each of :func:`in_parallel`'s, each batch of rays)."""
    stop = getattr(_work, "stop", None)
    if stop is not None and stop.is_set():
        raise Cancelled()


class _Stop:
    """A driven generator's stop, set by it or by the one it runs inside (a nested
    :func:`run` in a thread of a bake's)."""

    def __init__(self, parent=None):
        self.event, self.parent = threading.Event(), parent

    def set(self):
        self.event.set()

    def is_set(self):
        return self.event.is_set() or (self.parent is not None and self.parent.is_set())


class Driven:
    """A generator of Progress stepped with :meth:`next`: the threads its steps start (and
    theirs) work for it, and stop at their next piece once it is closed (:meth:`close`, a
    cancel) or raised an error (its tables, its simplification: at a million vertices tens
    of seconds and gigabytes that a bake started next would wait on)."""

    def __init__(self, steps):
        self.steps, self.stop, self.done = steps, _Stop(getattr(_work, "stop", None)), False

    def next(self):
        before = getattr(_work, "stop", None)
        _work.stop = self.stop
        try:
            return next(self.steps)
        except StopIteration:
            self.done = True  # (work it left running on purpose goes on)
            raise
        except BaseException:
            self.stop.set()
            raise
        finally:
            _work.stop = before

    def close(self):
        if not self.done:
            self.stop.set()
        self.steps.close()


class Job:
    """``fn(*args, **kwargs)`` running in a thread of its own (see :func:`start`), for what
    the starting thread works for (see :class:`Driven`)."""

    def __init__(self, fn, args, kwargs):
        self.out, self.finished = {}, threading.Event()
        # Its own stop (see abandon), under what the starting thread works for.
        self.stop = stop = _Stop(getattr(_work, "stop", None))

        def work():
            _work.stop = stop
            try:
                self.out["value"] = fn(*args, **kwargs)
            except BaseException as exc:  # handed to the generator's caller
                self.out["error"] = exc
            finally:
                self.finished.set()
                _notify()  # (a main thread serving calls while it waits for this one)

        self.thread = threading.Thread(target=work, name="cubegi-work", daemon=True)
        self.thread.start()


def start(fn, *args, **kwargs):
    """Start ``fn(*args, **kwargs)`` in a thread; :func:`wait` for its result. Between the
    two the caller can do work of its own (the GPU's, which is the main thread's)."""
    return Job(fn, args, kwargs)


def abandon(job):
    """Stop ``job`` (its next piece of work raises :class:`Cancelled`) and wait for its thread
    to end: a failed step's work that nothing will take (nothing of it outlives the step). On
    the main thread, the calls it hands over meanwhile are served (it would wait for them)."""
    job.stop.set()
    if sys.is_finalizing():  # (a generator closed as the interpreter exits: its threads are stopped for good)
        return
    if threading.current_thread() is threading.main_thread():
        _serve_until(job.finished.is_set, float("inf"))
    job.thread.join()  # (after its last call: at once)


def wait(job, working):
    """A generator yielding ``working`` (a Progress) every WORKING_SECONDS until ``job``
    ends, returning its result (or raising its exception)."""
    while True:
        _serve_while(job, WORKING_SECONDS)
        if job.finished.is_set():
            break
        yield working
    give_back_memory()
    if "error" in job.out:
        raise job.out["error"]
    return job.out["value"]


class NotServed(Exception):
    """:func:`on_main` from a thread while the main thread serves no calls (it waits for no
    work of a bake's, nor draws batches of its own): the caller does the work its own way."""


class _Call:
    def __init__(self, fn, args):
        self.fn, self.args, self.done, self.out = fn, args, threading.Event(), {}

    def serve(self):
        try:
            self.out["value"] = self.fn(*self.args)
        except BaseException as exc:  # handed to the thread that asked, without this thread's frames
            self.out["error"] = exc.with_traceback(None)  # (their GPU objects are freed here, on the main thread)
        self.done.set()


# Calls handed to the main thread (on_main), waiting for it to take them (in wait()).
_calls = threading.Condition()
_waiting_calls: list = []
# How long on_main waits for the main thread to take a call before doing without it: long
# enough for a modal operator's next timer step, short enough where it never comes.
TAKE_CALL_SECONDS = 2.0


def on_main(fn, *args):
    """``fn(*args)`` on the main thread, whose alone the GPU context is: at once where this is
    the main thread, else handed to it, which runs it while it waits for a bake's work
    (:func:`wait`, :func:`result`, :func:`in_parallel`) or between its own batches of work
    (:func:`in_batches`), and this thread waits for the answer (stopping where the work it
    is for stops: :func:`checkpoint`). Raises :class:`NotServed` where the main thread takes
    no call within TAKE_CALL_SECONDS (it waits for nothing of a bake's: a thread of one's
    own, or a main thread itself waiting on this one)."""
    if threading.current_thread() is threading.main_thread():
        return fn(*args)
    call = _Call(fn, args)
    with _calls:
        _waiting_calls.append(call)
        _calls.notify_all()
        taken = _calls.wait_for(lambda: call not in _waiting_calls, TAKE_CALL_SECONDS)
        if not taken:
            _waiting_calls.remove(call)
            raise NotServed(getattr(fn, "__name__", "a call"))
    while not call.done.wait(WORKING_SECONDS):  # (taken: a main thread stopped since never ends it)
        checkpoint()
    if "error" in call.out:
        raise call.out["error"]
    return call.out["value"]


def _serve_while(job, seconds):
    """Wait up to ``seconds`` for ``job`` to end; on the main thread, run the calls other
    threads hand it (:func:`on_main`) meanwhile."""
    if threading.current_thread() is not threading.main_thread():
        job.finished.wait(seconds)
        return
    _serve_until(job.finished.is_set, seconds)


def _serve_until(done, seconds):
    """Run the calls handed to the main thread until ``done()`` (checked whenever a call or
    the end of some work wakes it) or ``seconds`` pass."""
    deadline = time.monotonic() + seconds
    while not done():
        with _calls:
            left = deadline - time.monotonic()
            if not _waiting_calls and left > 0 and not done():  # (the end's notice comes under this lock)
                _calls.wait(min(left, WORKING_SECONDS))
            call = _waiting_calls.pop(0) if _waiting_calls else None
            if call is not None:
                _calls.notify_all()  # (taken)
        if call is not None:
            call.serve()
        if time.monotonic() >= deadline:
            return


def serve_waiting():
    """On the main thread, run the calls handed to it (:func:`on_main`) that wait now, for
    WORKING_SECONDS at most; elsewhere nothing."""
    if threading.current_thread() is threading.main_thread():
        _serve_until(lambda: not _waiting_calls, WORKING_SECONDS)


def _notify(_future=None):
    with _calls:
        _calls.notify_all()


def result(job):
    """:func:`wait` for ``job`` where there is no step to yield (in a thread of the work's own;
    on the main thread, serving the calls handed to it meanwhile)."""
    return run(wait(job, None))


def _trim():
    """glibc's ``malloc_trim`` among the process's own symbols, or None where there is none
    (macOS, Windows, musl)."""
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError, TypeError):
        return None
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return trim


_MALLOC_TRIM = _trim()


def give_back_memory():
    """Hand the memory a finished step freed back to the system (glibc's allocator only;
    elsewhere nothing). Each step runs in a thread of its own, and glibc gives each thread
    an arena of its own, which keeps what the thread freed: at a million vertices 0.2-0.5 GB
    of freed arrays stayed in the process between stages (the ``bpy`` module from PyPI, which
    allocates with glibc; a Blender build that links jemalloc returns memory by its own
    rules, and the call changes nothing there)."""
    if _MALLOC_TRIM is not None:
        _MALLOC_TRIM(0)


_pool = None
_pool_lock = threading.Lock()
_in_pool = threading.local()


def _worker(fn, item, stop):
    _in_pool.inside = True
    _work.stop = stop
    checkpoint()
    return fn(item)


def _inline(fn, item):
    checkpoint()
    return fn(item)


def in_parallel(fn, items):
    """``[fn(item) for item in items]``, run on up to WORKERS threads, in order, each piece
    after a :func:`checkpoint`. Each item's result is its own (the pieces must not depend on
    one another), so the numbers are the same on any machine. Called from inside one of
    those threads (a piece cut into pieces), it runs in that thread: the pool never waits on
    itself."""
    global _pool
    items = list(items)
    if WORKERS == 1 or len(items) < 2 or getattr(_in_pool, "inside", False):
        return [_inline(fn, item) for item in items]
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix="cubegi-piece")
    stop = getattr(_work, "stop", None)
    futures = [_pool.submit(_worker, fn, item, stop) for item in items]
    if threading.current_thread() is threading.main_thread():  # its pieces may hand it GPU calls
        for future in futures:
            future.add_done_callback(_notify)
        _serve_until(lambda: all(future.done() for future in futures), float("inf"))
    return [future.result() for future in futures]


_made_lock = threading.RLock()


def made_once(owner, name, make, key=None):
    """``make()``, kept in ``owner.__dict__[name]`` and made again only where ``key`` differs
    from the one it was made for; under one lock, since worker threads ask for it at once (a
    ray caster or a map's filters, made once, not once per thread)."""
    with _made_lock:
        cached = owner.__dict__.get(name)
        if cached is None or cached[0] != key:
            cached = (key, make())
            owner.__dict__[name] = cached
    return cached[1]


_once_locks = threading.Lock()


class once:
    """A cached property made once per object even where worker threads ask for it at once
    (``functools.cached_property`` has no lock since Python 3.12: two pieces of the near
    field's rays each made a subdivided scene's 2.1M triangles' planes, 0.5 s and 200 MB
    twice). The value is kept in the object's ``__dict__``, where later lookups find it
    without this descriptor."""

    def __init__(self, make):
        self.make, self.name, self.__doc__ = make, make.__name__, make.__doc__

    def __set_name__(self, owner, name):
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        lock = obj.__dict__.get("_once_lock")
        if lock is None:
            with _once_locks:  # (a lock of its own: never held while anything is made)
                lock = obj.__dict__.setdefault("_once_lock", threading.RLock())  # reentrant: one property may ask another
        with lock:
            if self.name not in obj.__dict__:
                obj.__dict__[self.name] = self.make(obj)
        return obj.__dict__[self.name]


def in_background(fn, working, *args, **kwargs):
    """``fn(*args, **kwargs)`` in a thread; a generator yielding ``working`` (a Progress) every
    WORKING_SECONDS while it runs, returning its result (or raising its exception)."""
    return (yield from wait(start(fn, *args, **kwargs), working))


def in_batches(count, size, run_batch, working):
    """``run_batch(a, b)`` over ``0..count`` in batches of ``size`` (fixed, not timed: how the
    work is cut can change its numbers, as a GPU's atlas layout does, and a bake must give the
    same numbers every time), yielding ``working(done)`` (a Progress) between them; returns
    the batches' results in order. On the main thread, the calls other threads hand it
    (:func:`on_main`) are run between the batches."""
    results, size = [], max(1, int(size))
    for a in range(0, count, size):
        results.append(run_batch(a, min(count, a + size)))
        serve_waiting()  # (a thread's rays handed to the main thread wait no longer than a batch)
        if a + size < count:
            yield working(a + size)
    return results


def run(steps, progress=None):
    """Drain a generator of Progress, calling ``progress`` on each (but the working steps
    that only hand control back); return its result. The one driver: the operator's modal
    timer steps the same generators, a step at a time. Its threads stop where it fails or
    is interrupted (Ctrl-C: see :class:`Driven`)."""
    driven = Driven(steps)
    try:
        while True:
            try:
                step = driven.next()
            except StopIteration as stop:
                return stop.value
            if progress is not None and not step.working:
                progress(step)
    except BaseException:
        driven.stop.set()
        # Its clean-up (threads stopped, and waited for) now, not when the generator is
        # collected: at the interpreter's exit its threads are stopped for good (a bake's
        # output piped to `head` waited forever for the near field's thread).
        driven.close()
        raise
