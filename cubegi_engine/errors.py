"""The one error type for refusals. Pure Python; must not import bpy.

A :class:`BakeError` is advice for the user (bad input, bad settings, a file that cannot be
written): the operator shows its text as one line, the command line prints it and exits
with status 2. Anything else that escapes a bake is a defect of CubeGI and is reported as
one, never as advice.
"""

__all__ = ["BakeError"]


class BakeError(ValueError):
    """A bake refused, with the reason and what to do, in one line.

    ``setting``: the :class:`~cubegi_engine.settings.BakeSettings` field at fault, if any
    (the command line names its option).
    """

    def __init__(self, message: str, setting: str | None = None):
        super().__init__(message)
        self.setting = setting
