"""A bake's report: a typed record, its JSON (strict: no NaN or Inf) and a few lines of text
for the command line and the panel. Pure Python; must not import bpy.

The JSON layout (``to_dict``) is the report file's documented format (docs/report-format.md).
"""

import json
import math
from dataclasses import asdict, dataclass, field

from . import __version__
from .records import BounceRecord, LeftOut, Record, TailReport

__all__ = ["BakeReport", "GridReport", "ReferenceReport", "NearFieldReport", "CaptureGeometryReport"]


@dataclass(frozen=True)
class GridReport(Record):
    """The probe grid: the first grid's ``resolution``, ``lo``, ``hi``; ``probes`` in all;
    ``grids``: each grid's ``{"resolution", "lo", "hi", "probes"}``; how many probes sit
    inside geometry, were captured, were moved out of geometry or left inside it; the
    grid's ``source`` (the grid objects, or the automatic box)."""

    resolution: list
    probes: int
    lo: list | None = None
    hi: list | None = None
    grids: list = field(default_factory=list)
    probes_inside_geometry: int = 0
    probes_captured: int | None = None
    source: str = ""
    probes_moved: int | None = None
    probes_left_inside: int | None = None

    def to_dict(self) -> dict:
        d = asdict(self)
        first = {k: d.pop(k) for k in ("resolution", "lo", "hi", "probes", "grids")}  # the report's order
        return {**first, **{k: v for k, v in d.items() if v is not None or k not in ("probes_moved", "probes_left_inside")}}


@dataclass(frozen=True)
class ReferenceReport(Record):
    """The Cycles reference: its ``samples`` and ``seconds``, CubeGI's ``cubegi_seconds``, the
    ``attributes`` it wrote and ``errors`` (``metrics.compare``: per part, the error measures)."""

    samples: int
    seconds: float
    cubegi_seconds: float
    attributes: list
    errors: dict
    renderer: str = "cycles"
    objects: list = field(default_factory=list)  # the objects furthest off (metrics.furthest_off)

    def to_dict(self) -> dict:
        return {"renderer": self.renderer, "samples": self.samples, "seconds": self.seconds,
                "cubegi_seconds": self.cubegi_seconds, "attributes": self.attributes, "errors": self.errors,
                "objects": self.objects}


@dataclass(frozen=True)
class NearFieldReport(Record):
    """The near field: the ``points`` that gathered, their ray ``hits``, the (point, triangle)
    ``pairs`` tested, the ``crowded`` points left out, the rays' ``reach``, its ``seconds``, and
    why it was ``skipped`` as a whole ("" where it was not)."""

    points: int
    hits: int
    pairs: int
    crowded: int
    reach: float
    seconds: float
    skipped: str = ""


@dataclass(frozen=True)
class CaptureGeometryReport(Record):
    """The probes' simplified geometry: the ``triangles`` they drew ``of`` the scene's, in
    ``clusters``, none more than ``max_offset`` from where it is."""

    triangles: int
    of: int
    clusters: int
    max_offset: float


def _part(cls, d):
    return None if d is None else cls.from_dict(d)


@dataclass
class BakeReport:
    settings: dict
    grid: GridReport
    points: int
    triangles: int
    lights: int
    sky: list
    meshes_baked: list
    notes: list
    direct_seconds: float
    direct_mean_light: list
    emitter_energy_factor: list
    bounces: list  # BounceRecord per bounce
    indirect_mean_light: list
    tail: TailReport
    timings: dict
    attributes: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    reference: ReferenceReport | None = None
    capture_reused: bool = False
    probes_recaptured: int | None = None
    left_out: list = field(default_factory=list)  # LeftOut: what the bake left out, each with why
    capture_geometry: CaptureGeometryReport | None = None  # None: the probes drew every triangle
    near_field: NearFieldReport | None = None  # None: off
    input: str | None = None
    output: str | None = None
    version: str = __version__

    @property
    def total_seconds(self) -> float:
        return float(self.timings.get("total", 0.0))

    @property
    def estimated_remaining_error(self) -> float:
        """The share of the full indirect light the computed bounces miss (estimated from the
        observed rate); with ``tail.added`` it is in CubeGI as the tail."""
        return float(self.tail.estimated_remaining)

    def to_dict(self) -> dict:
        d = {
            "cubegi_version": self.version,
            "settings": self.settings,
            "grid": self.grid.to_dict(),
            "scene": {
                "points": self.points, "triangles": self.triangles, "lights": self.lights, "sky": self.sky,
                "meshes_baked": self.meshes_baked, "notes": self.notes,
            },
            "direct": {
                "seconds": self.direct_seconds, "mean_light": self.direct_mean_light, "attribute": "CubeGI_direct",
                "emitter_energy_factor": self.emitter_energy_factor,
            },
            "bounces": [b.to_dict() for b in self.bounces],
            "indirect": {"mean_light": self.indirect_mean_light, "attribute": "CubeGI"},
            "tail": self.tail.to_dict(),
            "estimated_remaining_error": self.estimated_remaining_error,
            "capture_reused": self.capture_reused,
            "probes_recaptured": self.probes_recaptured,
            "left_out": [x.line() for x in self.left_out],
            "left_out_items": [x.to_dict() for x in self.left_out],
            "capture_geometry": self.capture_geometry and self.capture_geometry.to_dict(),
            "near_field": self.near_field and self.near_field.to_dict(),
            "timings": self.timings,
            "total_seconds": self.total_seconds,
            "reference": self.reference and self.reference.to_dict(),
            "attributes": self.attributes,
            "warnings": self.warnings,
        }
        if self.input is not None:
            d["input"], d["output"] = self.input, self.output
        return d

    def to_json(self, indent=2) -> str:
        """Strict JSON: a NaN or Inf anywhere (a defect) is written as null."""
        return json.dumps(_finite(self.to_dict()), indent=indent, allow_nan=False)

    @classmethod
    def from_dict(cls, d: dict) -> "BakeReport":
        scene, direct = d["scene"], d["direct"]
        timings = dict(d.get("timings", {}))
        timings.setdefault("total", d.get("total_seconds", 0.0))
        return cls(
            settings=d["settings"], grid=GridReport.from_dict(d["grid"]), points=scene["points"], triangles=scene["triangles"],
            lights=scene["lights"], sky=scene["sky"], meshes_baked=scene["meshes_baked"], notes=scene["notes"],
            direct_seconds=direct["seconds"], direct_mean_light=direct["mean_light"],
            emitter_energy_factor=direct.get("emitter_energy_factor", [1.0, 1.0, 1.0]),
            bounces=[BounceRecord.from_dict(b) for b in d["bounces"]], indirect_mean_light=d["indirect"]["mean_light"],
            tail=TailReport.from_dict(d["tail"]), timings=timings, attributes=d.get("attributes", []),
            warnings=d.get("warnings", []), reference=_part(ReferenceReport, d.get("reference")), capture_reused=d.get("capture_reused", False),
            probes_recaptured=d.get("probes_recaptured"), left_out=_left_out(d),
            capture_geometry=_part(CaptureGeometryReport, d.get("capture_geometry")),
            near_field=_part(NearFieldReport, d.get("near_field")),
            input=d.get("input"), output=d.get("output"), version=d.get("cubegi_version", __version__),
        )

    @classmethod
    def from_json(cls, text: str) -> "BakeReport":
        return cls.from_dict(json.loads(text))

    def summary_lines(self) -> list:
        """The report in a few lines of text (the CLI prints them; the add-on shows them)."""
        reused = ", capture reused" if self.capture_reused else (
            "" if self.probes_recaptured is None else f", {self.probes_recaptured} re-captured" if self.probes_recaptured
            else ", capture kept, tables built again")
        lines = [
            f"baked {len(self.meshes_baked)} meshes, {self.grid.probes} probes{reused}, "
            f"{len(self.bounces)} bounces in {self.total_seconds:.3f} s"
        ]
        for rec in self.bounces:
            lines.append(
                f"  bounce {rec.bounce}: {rec.seconds * 1e3:.1f} ms, mean light {rec.mean:.4g}, "
                f"x{rec.ratio_mean:.3f} of the one before"
            )
        missing = f"estimated missing indirect light after bounce {len(self.bounces)}: {100 * self.estimated_remaining_error:.3g}%"
        if self.tail.added:
            missing += f" ({self.tail.method}, added to CubeGI)"
        elif self.tail.method != "none":
            missing += " (not added)"
        lines.append(missing)
        ref = self.reference
        if ref:
            lines.append(f"Cycles reference, {ref.samples} samples: {ref.seconds:.2f} s against CubeGI's {ref.cubegi_seconds:.2f} s")
            for part in ("direct", "indirect", "total"):
                e = ref.errors[part]
                lines.append(
                    f"  {part:8s} rel. RMSE {100 * e['rel_rmse']:6.2f}%  bias {100 * e['rel_bias']:+6.2f}%  p95 {100 * e['p95_rel']:6.2f}%"
                )
            lines += [f"  {o['name']}: {100 * o['error_share']:.0f}% of the error; mean direct {_percent(o['direct_bias'])}, "
                      f"indirect {_percent(o['indirect_bias'])} against Cycles" for o in ref.objects]
        if self.grid.probes_moved:
            lines.append(f"probes: {self.grid.probes_moved} found inside geometry were moved out of it, within their cells")
        near = self.near_field
        if near and near.points:
            lines.append(
                f"near field: {near.points:,} points gathered their surroundings within {near.reach:.3g} by rays "
                f"({near.hits:,} hits, {near.seconds:.2f} s)"
            )
        lines += [f"left out: {x.line()}" for x in self.left_out]
        lines += [f"warning: {w}" for w in self.warnings]
        lines += [f"note: {n}" for n in self.notes]
        return lines


def _left_out(d):
    """The report's LeftOut records (from their items; a report that holds lines alone: from them)."""
    if "left_out_items" in d:
        return [LeftOut.from_dict(x) for x in d["left_out_items"]]
    return [LeftOut.from_line(x) for x in d.get("left_out", [])]


def _finite(value):
    """``value`` with every non-finite float replaced by None (JSON has no NaN or Inf)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def _percent(bias):
    return "n/a (next to none in Cycles)" if bias is None else f"{100 * bias:+.1f}%"
