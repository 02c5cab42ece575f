"""The one error type for refusals. Pure Python; must not import bpy.

A :class:`BakeError` is advice for the user (bad input, bad settings, a file that cannot be
written): the operator shows its text as one line, the command line prints it and exits
with status 2. Anything else that escapes a bake is a defect of CubeGI and is reported as
one, never as advice. An :class:`Interrupted` is Ctrl-C or SIGTERM: it says what the
stopped action keeps.
"""

import signal

__all__ = ["BakeError", "Interrupted", "ERROR_PREFIX"]

# How a refusal (or a failure) starts on the command line's stderr: one line, which a
# cluster's task reads back as the reason a file failed.
ERROR_PREFIX = "cubegi: error: "


class BakeError(ValueError):
    """A bake refused, with the reason and what to do, in one line.

    ``setting``: the :class:`~cubegi_engine.settings.BakeSettings` field at fault, if any
    (the command line names its option).
    """

    def __init__(self, message: str, setting: str | None = None):
        super().__init__(message)
        self.setting = setting


class Interrupted(KeyboardInterrupt):
    """An action stopped by a signal (Ctrl-C's SIGINT, or SIGTERM); ``kept``: one line on what
    it leaves (None: nothing was written); ``written``: the files it had just put in place,
    when it came as they were renamed. The command line exits with 128 + ``signum``."""

    def __init__(self, signum: int = signal.SIGINT, kept: str | None = None, written=()):
        super().__init__(signum, kept)
        self.signum, self.kept, self.written = int(signum), kept, list(written)

    @classmethod
    def keeping(cls, exc: KeyboardInterrupt, kept: str | None):
        """``exc`` (a plain Ctrl-C, or an Interrupted) again, saying what is kept."""
        return cls(getattr(exc, "signum", signal.SIGINT), kept)
