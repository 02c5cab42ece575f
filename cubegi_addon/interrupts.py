"""Ctrl-C and SIGTERM in the command line: the action stops where it stands and says what it
keeps; every clean-up runs (a plain SIGTERM would end the process mid-save and leave the
save's temporary folder).

Pure Python (no bpy). Under :func:`interruptible` a signal raises :class:`Interrupted` in the
main thread, except where an exception would be lost or would break "all or none":
- inside a function Blender calls (a handler, marked with :func:`blender_callback`), which
  prints and drops any exception it raises;
- while :func:`.files.write_all` renames a job's files into place (:func:`deferred`).
There the signal waits: it is raised at the end of the deferred block, or at the next
:func:`check` (each progress step, each write).
"""

import contextlib
import signal
import threading

from ..cubegi_engine.errors import Interrupted

__all__ = ["interruptible", "deferred", "check", "blender_callback"]

_state = {"deferred": 0, "pending": None}
# The code of the functions Blender calls (see blender_callback).
_CALLBACKS = set()


def blender_callback(fn):
    """Mark ``fn`` as called by Blender (an app handler): an interrupt in it waits for the
    next :func:`check`, since Blender would print the exception and go on."""
    _CALLBACKS.add(getattr(fn, "__wrapped__", fn).__code__)
    return fn


def _in_callback(frame):
    while frame is not None:
        if frame.f_code in _CALLBACKS:
            return True
        frame = frame.f_back
    return False


def check():
    """Raise the interrupt that waited (see the module docstring), if any."""
    signum, _state["pending"] = _state["pending"], None
    if signum is not None:
        raise Interrupted(signum)


@contextlib.contextmanager
def deferred(written=()):
    """An interrupt during the block waits for its end, then is raised as an Interrupted
    whose ``written`` is ``written`` (the files the block put in place)."""
    _state["deferred"] += 1
    try:
        yield
    finally:
        _state["deferred"] -= 1
    signum, _state["pending"] = _state["pending"], None
    if signum is not None:
        raise Interrupted(signum, written=written)


@contextlib.contextmanager
def interruptible():
    """While it runs, Ctrl-C (SIGINT) and SIGTERM raise :class:`Interrupted` (as the module
    docstring says); the previous handlers come back after. The command line runs in it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        if _state["deferred"] or _in_callback(frame):
            _state["pending"] = signum
        else:
            raise Interrupted(signum)

    previous = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    _state["pending"] = None
    try:
        yield
    finally:
        _state["pending"] = None
        for s, handler in previous.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)
