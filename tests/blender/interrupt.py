"""Interrupting the command line as a terminal does: Ctrl-C sends SIGINT to every process of
the foreground group (the command, its Dask workers and their bakes)."""

import os
import signal
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def interrupt_cli(args, ready, sig=signal.SIGINT, timeout=300):
    """Run ``python -m cubegi_engine *args`` in a process group of its own, send ``sig`` to
    the group once ``ready()`` is true, and return ``(returncode, stdout, stderr)``. Fails if
    the command ends before ``ready()``."""
    p = subprocess.Popen([sys.executable, "-m", "cubegi_engine", *map(str, args)], cwd=ROOT, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + timeout
    try:
        while not ready():
            assert p.poll() is None, f"it ended before the interrupt: {p.communicate()}"
            assert time.monotonic() < deadline, "never ready to interrupt"
            time.sleep(0.02)
        os.killpg(p.pid, sig)
        out, err = p.communicate(timeout=timeout)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    return p.returncode, out, err


def still_running(needle):
    """Processes whose command line holds ``needle`` (a path of the test's own)."""
    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as fh:
                if needle.encode() in fh.read():
                    found.append(int(pid))
        except OSError:
            pass
    return found
