"""How a bake runs: one place for every default and every check. Pure Python; no bpy.

The add-on's properties, the operator and the command line take their defaults and limits
from :class:`BakeSettings` and validate through :meth:`BakeSettings.validate`.
"""

import math
from dataclasses import dataclass
from typing import ClassVar

from .errors import BakeError

__all__ = ["BakeSettings", "MIN_CUBE_SIZE", "MAX_CUBE_SIZE", "MAX_BOUNCES", "QUALITY"]

MIN_CUBE_SIZE, MAX_CUBE_SIZE = 4, 512
MIN_CAPTURE_TRIANGLES = 1000
MAX_CELLS = 64

# Quality presets: cells along the longest side of a fitted grid, cube-map size and bounces
# (the tail adds the rest). From the benchmark's error-time front (docs/accuracy.md, *Error against
# run time*): 16^2 faces are on the front in every scene, 32^2 cost twice the capture for a
# point or two of error; 4 cells give the best speed-up over Cycles, 12 the lowest error.
# BALANCED is BakeSettings' default.
QUALITY = {
    "DRAFT": {"cells": 4, "cube_size": 16, "bounces": 3},
    "BALANCED": {"cells": 8, "cube_size": 16, "bounces": 5},
    "FINAL": {"cells": 12, "cube_size": 32, "bounces": 5},
}
# A bounce cap far past any scene's need: a closed room of albedo 0.95 converges to 1e-4 in
# about 123 bounces, and the tail solve adds the rest in one go. More only writes
# attributes of zero light.
MAX_BOUNCES = 200


@dataclass
class BakeSettings:
    """Everything that sets how a bake runs (not what it bakes)."""

    MAX_BOUNCES: ClassVar[int] = MAX_BOUNCES

    cube_size: int = 16
    bounces: int = 5
    # Cells along the longest side of a grid fitted to the scene (no probe grid object).
    cells: int = 8
    # Instead of ``cells``: the distance between a fitted grid's probes, in scene units (None:
    # ``cells`` sets it).
    probe_spacing: float | None = None
    visibility: bool = True
    shadow_size: int = 512
    sun_shadow_size: int = 1024
    area_shadow_size: int = 128
    # Stop once the estimated missing share of the indirect light is below this (None: run
    # all ``bounces``); ``bounces`` stays the cap.
    tolerance: float | None = None
    add_tail: bool = True  # add the light after the last bounce (estimated) to the total
    solve_tolerance: float = 1e-5
    # Scale each bounce (and the light from emitters) so that the power the surfaces receive
    # equals the power they send that lands on surfaces (see :func:`solve.conserve_energy`).
    conserve_energy: bool = True
    # The probes draw a simplified copy of the scene with at most about this many triangles
    # (:mod:`cubegi_engine.proxy`; None: always the full scene). Direct light, shadows and the
    # shading points always use the full scene.
    capture_triangles: int | None = 100_000
    # Gather each point's near field (surfaces within a quarter of a cell) by rays, as a
    # final gather of every bounce (:mod:`cubegi_engine.nearfield`).
    near_field: bool = True
    # Probes found inside geometry before the capture are moved out of it where their cell
    # allows, else left out (:mod:`cubegi_engine.placement`); False: every probe stays at
    # its cell centre (the capture still leaves out the ones inside).
    move_probes: bool = True
    # The sky's direct light per vertex, along SKY_PER_VERTEX_DIRECTIONS lines of sight of
    # its own (:func:`cubegi_engine.direct.sky_direct`), instead of through the probes: the
    # sky's shadows exact to within a few per cent, at a cost that grows with vertices x
    # directions (see docs/accuracy.md#accuracy-against-cycles).
    sky_per_vertex: bool = False

    def validate(self) -> "BakeSettings":
        """Raise a :class:`BakeError` naming the first setting out of range; else self."""
        if not MIN_CUBE_SIZE <= int(self.cube_size) <= MAX_CUBE_SIZE:
            raise BakeError(f"cube-map size must be between {MIN_CUBE_SIZE} and {MAX_CUBE_SIZE}, got {self.cube_size}", "cube_size")
        if not 1 <= int(self.cells) <= MAX_CELLS:
            raise BakeError(f"grid cells must be between 1 and {MAX_CELLS}, got {self.cells}", "cells")
        if self.probe_spacing is not None and not (math.isfinite(float(self.probe_spacing)) and float(self.probe_spacing) > 0):
            raise BakeError(f"probe spacing must be a distance above 0, got {self.probe_spacing}", "probe_spacing")
        if not 0 <= int(self.bounces) <= MAX_BOUNCES:
            raise BakeError(f"bounces must be between 0 and {MAX_BOUNCES}, got {self.bounces}", "bounces")
        if self.tolerance is not None and not 0.0 < float(self.tolerance) < 1.0:
            raise BakeError(f"tolerance must be between 0 and 1 (a share of the light), got {self.tolerance}", "tolerance")
        for name in ("shadow_size", "sun_shadow_size", "area_shadow_size"):
            if not 1 <= int(getattr(self, name)) <= 16384:
                raise BakeError(f"{name.replace('_', ' ')} must be between 1 and 16384, got {getattr(self, name)}", name)
        if self.capture_triangles is not None and int(self.capture_triangles) < MIN_CAPTURE_TRIANGLES:
            raise BakeError(
                f"capture triangles must be at least {MIN_CAPTURE_TRIANGLES} (or none: the full scene), got {self.capture_triangles}",
                "capture_triangles",
            )
        return self

    @classmethod
    def preset(cls, quality: str, **overrides) -> "BakeSettings":
        """The settings of a quality preset (``QUALITY``), with ``overrides``."""
        key = str(quality).upper()
        if key not in QUALITY:
            raise BakeError(f"quality must be one of {', '.join(q.lower() for q in QUALITY)}, got {quality!r}", "quality")
        return cls(**{**QUALITY[key], **overrides})

    def as_dict(self, **extra) -> dict:
        """The settings a report records."""
        return {
            "cube_size": self.cube_size, "bounces": self.bounces, "cells": self.cells, "probe_spacing": self.probe_spacing,
            "visibility": self.visibility,
            "shadow_size": self.shadow_size, "tolerance": self.tolerance, "add_tail": self.add_tail,
            "conserve_energy": self.conserve_energy, "capture_triangles": self.capture_triangles,
            "near_field": self.near_field, "move_probes": self.move_probes, "sky_per_vertex": self.sky_per_vertex,
            **extra,
        }
