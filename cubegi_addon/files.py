"""Files a bake writes (the baked .blend, the report): checked before the bake, written
whole or not at all, never over the user's input.

Pure Python (no bpy): the command line checks its paths before it imports bpy.

Rules, for every path CubeGI writes:
- it is a regular file or a new name in an existing, writable folder; a directory, a device
  node, a FIFO or a socket is refused (writing there would replace the node);
- it is not the same file as any path it must not touch (the input, or another output),
  through symbolic links, hard links or bind mounts alike (compared by device and inode
  where the file exists, by resolved path where it does not);
- it is written to a temporary file of a new name beside it and renamed over the target
  only when every output of the job is complete (:func:`write_all`); the temporary file is
  removed in every case, so nothing half-written and no backup file stays.
"""

import collections
import os
import secrets
import stat

from ..cubegi_engine.errors import BakeError
from . import interrupts

__all__ = ["writable_target", "same_file", "write_all", "text", "written"]

# The last paths :func:`write_all` put in place in this process, in order: the command line
# clears it and names them when it is interrupted after some were written.
written = collections.deque(maxlen=64)


def text(content):
    """A :func:`write_all` writer of the string ``content`` (UTF-8)."""

    def write(tmp):
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(content)

    return write


def same_file(a, b):
    """True if paths ``a`` and ``b`` name the same file (links and bind mounts resolved)."""
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist: compare where they would be
        return os.path.realpath(a) == os.path.realpath(b)


def writable_target(path, what, protected=()):
    """The resolved path to write ``what`` (e.g. "output") to, or a BakeError saying why not.

    ``protected``: ``[(path, name)]`` files this one must not be (e.g. the input).
    """
    if not path:
        raise BakeError(f"no {what} path given")
    real = os.path.realpath(path)
    for other, name in protected:
        if other and same_file(path, other):
            raise BakeError(f"the {what} {path!r} is the {name}; give another path")
    try:
        mode = os.stat(real).st_mode
    except FileNotFoundError:
        mode = None
    except OSError as exc:
        raise BakeError(f"cannot use {path!r} as the {what}: {exc.strerror}") from None
    if mode is not None and stat.S_ISDIR(mode):
        raise BakeError(f"the {what} {path!r} is a folder; give a file name")
    if mode is not None and not stat.S_ISREG(mode):
        raise BakeError(f"the {what} {path!r} is not a regular file (a device, pipe or socket); give a file name")
    folder = os.path.dirname(real)
    if not os.path.isdir(folder):
        raise BakeError(f"the {what} folder does not exist: {os.path.dirname(os.path.abspath(path))}")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise BakeError(f"the {what} folder is not writable: {folder}")
    return real


def write_all(jobs):
    """Write several files, all or none: ``jobs`` is ``[(path, write(tmp_path))]``.

    Each ``write`` fills a temporary file in its target's own folder (a .blend's relative
    paths, to its linked libraries and images, are written relative to where it is saved:
    from a folder of its own they pointed one level too deep); once all have succeeded they
    are renamed over their targets. A failure (a full disk, a write
    error) raises a BakeError and leaves every target as it was; the temporary folders go in
    every case. Under :func:`.interrupts.interruptible`, an interrupt (Ctrl-C, SIGTERM) that
    comes while the files are written waits for the write to end (the save itself is
    Blender's C code, which a signal does not stop either): then it is raised as an
    Interrupted whose ``written`` lists the files put in place.
    """
    interrupts.check()
    staged, done = [], []
    with interrupts.deferred(written=done):
        try:
            for path, write in jobs:
                tmp = _sibling(path)
                staged.append((tmp, path))
                try:
                    write(tmp)
                except (OSError, RuntimeError) as exc:
                    reason = getattr(exc, "strerror", None) or str(exc).strip().splitlines()[-1]
                    raise BakeError(f"could not write {path!r}: {reason}") from None
                if not os.path.isfile(tmp):
                    raise BakeError(f"could not write {path!r}")
            for tmp, path in staged:
                os.replace(tmp, path)
                written.append(path)
                done.append(path)
        finally:
            for tmp, _ in staged:
                if os.path.exists(tmp):
                    os.remove(tmp)


def _sibling(path):
    """A path no file has, in ``path``'s folder: ``.cubegi-<random>-<its name>``."""
    folder, name = os.path.split(path)
    while True:
        tmp = os.path.join(folder, f".cubegi-{secrets.token_hex(6)}-{name}")
        if not os.path.exists(tmp):
            return tmp


