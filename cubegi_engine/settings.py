"""How a bake runs: every setting declared once, with every default and every check. Pure
Python; no bpy.

Each field of :class:`BakeSettings` that users set is declared with :func:`option`: its
label, its help, its command-line flag, its range, and whether a kept capture depends on it.
The scene's and the operator's properties (``cubegi_addon/props.py``), the panel, the
command line's options and the options forwarded to a cluster's bakes
(``cubegi_addon/cli.py``), the report's settings and the kept capture's key are all made
from :data:`OPTIONS`; :meth:`BakeSettings.validate` checks every value.
"""

import math
from dataclasses import dataclass, field, fields
from typing import ClassVar, get_args

from .errors import BakeError

__all__ = ["BakeSettings", "MIN_CUBE_SIZE", "MAX_CUBE_SIZE", "MAX_BOUNCES", "OPTIONS", "Option", "QUALITY", "SECTIONS"]

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
MAX_SHADOW_SIZE = 16384

# The panel's headings, in order; each option names the one it is drawn under.
SECTIONS = ("Capture", "Shadows", "Bounces")


@dataclass(frozen=True)
class Option:
    """One bake setting as users see it: a scene property saved in the file (drawn in the
    panel under ``section``), an operator property and a command-line option. Made by
    :func:`option` on a :class:`BakeSettings` field; :data:`OPTIONS` holds them all."""

    name: str  # the BakeSettings field, the scene's and the operator's property
    kind: type  # bool, int or float
    default: object
    label: str
    help: str  # the tooltip, and the command line's help
    # ``--name`` with a value; for a switch (a bool), the word that sets the opposite of its
    # default (``--no-near-field``).
    flag: str
    section: str | None  # None: the command line and the operator only, not the file
    # The valid range (None: open). Scene properties are held to it; the operator's slider
    # is soft, so that a script's out-of-range value is refused by validate with the reason.
    minimum: float | None = None
    maximum: float | None = None
    soft_maximum: float | None = None  # the slider's end, where the range is wider than useful
    none_as_zero: bool = False  # None (the field's "off") is 0 in a property and on the command line
    capture: bool = False  # a kept capture applies only to the value it was taken with
    subtype: str = "NONE"  # the property's subtype (PIXEL, DISTANCE, FACTOR)
    metavar: str | None = None

    @property
    def switch(self) -> bool:
        return self.kind is bool

    def stored(self, value):
        """``value`` as a property holds it (None as 0 where :attr:`none_as_zero`)."""
        return 0 if value is None and self.none_as_zero else value

    def given(self, value):
        """A property's or the command line's ``value`` as the setting takes it."""
        return None if self.none_as_zero and value == 0 else value

    def words(self, value) -> list[str]:
        """``value`` given on the command line, as its words ([] where it is the default's
        switch)."""
        if self.switch:
            return [self.flag] if bool(value) != bool(self.default) else []
        return [self.flag, str(self.stored(value))]


def option(default, label, help, *, flag=None, section="Capture", **meta):
    """A :class:`BakeSettings` field declared as an :class:`Option` (see there for ``meta``)."""
    return field(default=default, metadata={"option": dict(label=label, help=help, flag=flag, section=section, **meta)})


@dataclass
class BakeSettings:
    """Everything that sets how a bake runs (not what it bakes)."""

    MAX_BOUNCES: ClassVar[int] = MAX_BOUNCES

    cells: int = option(8, "Grid Cells", "Cells along the longest side of the grid fitted to the scene (when it has "
                        "no probe grid object)", minimum=1, maximum=MAX_CELLS)
    probe_spacing: float | None = option(
        None, "Probe Spacing", "Instead of Grid Cells: the distance between the probes of the grid fitted to the scene, "
        "in scene units (0: Grid Cells sets it)", none_as_zero=True, minimum=0.0, soft_maximum=10.0,
        subtype="DISTANCE", metavar="DISTANCE")
    cube_size: int = option(16, "Cube-Map Size", "Edge length in texels of each probe's cube-map faces",
                            minimum=MIN_CUBE_SIZE, maximum=MAX_CUBE_SIZE, capture=True)
    visibility: bool = option(True, "Probe Visibility", "Leave out, per vertex, the probes that cannot see it (stops "
                              "light leaking through thin walls; off: plain trilinear interpolation)", capture=True)
    # The probes draw a simplified copy of the scene with at most about this many triangles
    # (:mod:`cubegi_engine.proxy`; None: always the full scene). Direct light, shadows and the
    # shading points always use the full scene. 100K -> 50K: the Breakfast Room's capture
    # 2.67 -> 1.65 s (125,692 -> 71,795 triangles drawn), the bake 18.4 -> 17.8 s, its errors
    # the same; the Room subdivided to 95K vertices, indirect 24.9 -> 18.9% off Cycles (see
    # docs/accuracy.md).
    capture_triangles: int | None = option(
        50_000, "Capture Triangles", "The probes draw a simplified copy of the scene with at most about this many "
        "triangles (0: the full scene). Direct light, shadows and the baked vertices always use every triangle",
        none_as_zero=True, minimum=0, soft_maximum=1_000_000, metavar="N", capture=True)
    # Gather each point's near field (surfaces within a quarter of a cell) by rays, as a
    # final gather of every bounce (:mod:`cubegi_engine.nearfield`).
    near_field: bool = option(True, "Near Field", "Gather each vertex's near surroundings (surfaces within a quarter of "
                              "a cell: where walls meet, under furniture) by rays, instead of the probes' view of them "
                              "from up to a cell away (see docs/accuracy.md)", capture=True)
    # Probes found inside geometry before the capture are moved out of it where their cell
    # allows, else left out (:mod:`cubegi_engine.placement`); False: every probe stays at
    # its cell centre (the capture still leaves out the ones inside). Like Grid Cells and
    # Probe Spacing, it sets where the probes are, which the grid a capture is kept with
    # holds: not part of the capture's key.
    move_probes: bool = option(True, "Move Probes Out", "Move probes found inside geometry (walls, furniture) out of it, "
                               "within their cells, before the capture; a probe with no way out is left out. Off: every "
                               "probe stays at its cell centre", flag="--keep-probes-in-place")
    # The sky's direct light per vertex, along SKY_PER_VERTEX_DIRECTIONS lines of sight of
    # its own (:func:`cubegi_engine.sky.sky_direct`), instead of through the probes.
    sky_per_vertex: bool = option(False, "Sky per Vertex", "Shadow the sky at every vertex along 256 lines of sight of "
                                  "its own, instead of through the probes: the sky's contact shadows and open edges exact "
                                  "to a few per cent, at several times a small bake's time (it grows with vertices x "
                                  "directions; see docs/accuracy.md)")
    shadow_size: int = option(512, "Point and Spot Shadows", "Shadow cube-map face size of point and spot lights, in "
                              "texels", section="Shadows", minimum=16, maximum=MAX_SHADOW_SIZE, soft_maximum=4096,
                              subtype="PIXEL")
    sun_shadow_size: int = option(1024, "Sun Shadows", "Shadow map size of sun lights, in texels", section="Shadows",
                                  minimum=16, maximum=MAX_SHADOW_SIZE, soft_maximum=8192, subtype="PIXEL")
    area_shadow_size: int = option(128, "Area Shadows", "Shadow map size of each sample point of an area light, in "
                                   "texels", section="Shadows", minimum=16, maximum=MAX_SHADOW_SIZE, soft_maximum=2048,
                                   subtype="PIXEL")
    bounces: int = option(5, "Bounces", f"Indirect bounces to compute (at most, {MAX_BOUNCES}; Tolerance can stop "
                          "earlier)", section="Bounces", minimum=0, maximum=MAX_BOUNCES)
    # Stop once the estimated missing share of the indirect light is below this (None: run
    # all ``bounces``); ``bounces`` stays the cap.
    tolerance: float | None = option(
        None, "Tolerance", "Stop once the estimated missing share of the indirect light is below this (e.g. 0.01); "
        "Bounces stays the cap (0: run all bounces)", section="Bounces", none_as_zero=True, minimum=0.0, maximum=0.5,
        subtype="FACTOR")
    add_tail: bool = option(True, "Add Tail", "Add the estimated light after the last bounce to CubeGI (the total)",
                            section="Bounces", flag="--no-tail")
    # Scale each bounce (and the light from emitters) so that the power the surfaces receive
    # equals the power they send that lands on surfaces (see :func:`solve.conserve_energy`).
    conserve_energy: bool = option(True, "Energy Conservation", "Scale each bounce so that the power the surfaces "
                                   "receive equals the power they send that lands on surfaces (off: each bounce's total "
                                   "as interpolated, for comparison; see docs/accuracy.md)", section=None,
                                   flag="--no-energy-conservation")
    solve_tolerance: float = 1e-5  # the tail solve's (not a user's setting)

    def validate(self) -> "BakeSettings":
        """Raise a :class:`BakeError` naming the first setting out of range; else self."""
        for o in OPTIONS:
            value = getattr(self, o.name)
            if (o.kind is int and value is not None and o.minimum is not None and o.maximum is not None
                    and not o.minimum <= int(value) <= o.maximum):
                raise BakeError(f"{o.label.lower()} must be between {o.minimum} and {o.maximum}, got {value}", o.name)
        if self.probe_spacing is not None and not (math.isfinite(float(self.probe_spacing)) and float(self.probe_spacing) > 0):
            raise BakeError(f"probe spacing must be a distance above 0, got {self.probe_spacing}", "probe_spacing")
        if self.tolerance is not None and not 0.0 < float(self.tolerance) < 1.0:
            raise BakeError(f"tolerance must be between 0 and 1 (a share of the light), got {self.tolerance}", "tolerance")
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
        """The settings a report records: every option's value."""
        return {**{o.name: getattr(self, o.name) for o in OPTIONS}, **extra}

    def capture_key(self) -> tuple:
        """The values a kept capture depends on (the options declared ``capture``)."""
        return tuple((o.name, getattr(self, o.name)) for o in OPTIONS if o.capture)


def _options() -> tuple[Option, ...]:
    found = []
    for f in fields(BakeSettings):
        if "option" not in f.metadata:
            continue
        meta = dict(f.metadata["option"])
        kind = type(f.default) if f.default is not None else next(t for t in get_args(f.type) if t is not type(None))
        if meta["flag"] is None:
            word = f.name.replace("_", "-")
            meta["flag"] = f"--no-{word}" if kind is bool and f.default else f"--{word}"
        found.append(Option(f.name, kind, f.default, **meta))
    return tuple(found)


OPTIONS: tuple[Option, ...] = _options()
