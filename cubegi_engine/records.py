"""What a bake tells as it runs and when it ends: progress, one record per bounce, the tail.

Pure Python and numpy; must not import bpy. These are the engine's own types; JSON appears
only at the edges (:meth:`cubegi_engine.report.BakeReport.to_json`).
"""

from dataclasses import asdict, dataclass, field, fields
from enum import Enum, StrEnum

import numpy as np

__all__ = ["Stage", "Progress", "Route", "LeftOut", "LeftOutKind", "plural", "BounceRecord", "TailReport", "FrameRecord", "AnimationResult"]


class Stage(str, Enum):
    CAPTURE = "capture"
    DIRECT = "direct"
    BOUNCE = "bounce"
    TAIL = "tail"
    REFERENCE = "reference"


@dataclass
class Progress:
    """One step of a bake. ``light``: the light so far (direct + bounces) ``(s, 3)``, when it
    changed; ``new_light``: what this step added: the direct light (stage DIRECT), bounce
    ``bounce``'s light (BOUNCE), or the tail (TAIL). ``working``: a step that only hands
    control back in the middle of long work (:mod:`cubegi_engine.working`)."""

    stage: Stage
    done: int
    total: int
    message: str
    light: np.ndarray | None = None
    new_light: np.ndarray | None = None
    bounce: int | None = None
    working: bool = False


class LeftOutKind(StrEnum):
    """What a bake left out: a light, probes, the near field of some vertices, geometry the
    probes did not draw."""

    LIGHT = "light"
    PROBES = "probes"
    NEAR_FIELD = "near field"
    CAPTURE_GEOMETRY = "capture geometry"
    OTHER = "other"  # a line of another version's report, kept as it reads


def plural(count: int, one: str, many: str) -> str:
    """``one`` for a count of 1, else ``many``."""
    return one if count == 1 else many


@dataclass(frozen=True)
class LeftOut:
    """One thing a bake left out: its ``kind``, how many (``count``, of ``names`` where it
    names them) and, in words, what and why (``text``, after the kind)."""

    kind: LeftOutKind
    text: str
    count: int = 1
    names: tuple = ()

    def line(self) -> str:
        """``light <name>: why``; ``<kind>: text`` for the others (the text alone for OTHER)."""
        if self.kind == LeftOutKind.OTHER:
            return self.text
        return f"{self.kind}{' ' if self.kind == LeftOutKind.LIGHT else ': '}{self.text}"

    def to_dict(self) -> dict:
        return {"kind": str(self.kind), "count": self.count, "names": list(self.names), "text": self.text}

    @classmethod
    def from_dict(cls, d: dict) -> "LeftOut":
        kind = str(d.get("kind", ""))
        known = kind in {k.value for k in LeftOutKind}
        return cls(LeftOutKind(kind) if known else LeftOutKind.OTHER, d["text"] if known else f"{kind}: {d['text']}",
                   int(d.get("count", 1)), tuple(d.get("names", ())))

    @classmethod
    def from_line(cls, line: str) -> "LeftOut":
        """A record from the text of :meth:`line` (a report that holds lines alone)."""
        for kind in LeftOutKind:
            for sep in (": ", " "):
                if kind != LeftOutKind.OTHER and line.startswith(f"{kind}{sep}"):
                    return cls(kind, line[len(kind) + len(sep):])
        return cls(LeftOutKind.OTHER, line)


class Route(StrEnum):
    """How an update, or an animation's frame, brought the light up to date (cheapest
    first): nothing changed; a weighted sum of the kept sources (power, colour); a light
    drawn again; the materials' colours or emission; the energy balance and the bounce
    layers an instant update left behind; dynamic objects alone lit again; a bake that
    re-captured the probes moved geometry concerns; a full bake."""

    NONE = "none"
    WEIGHTS = "weights"
    LIGHTS = "lights"
    MATERIALS = "materials"
    SETTLE = "settle"
    DYNAMIC = "dynamic"
    RECAPTURE = "recapture"
    FULL = "full"


class Record:
    """What the report's records share: ``to_dict`` (their fields) and ``from_dict`` (the
    entries that are fields; a report of another version may hold more)."""

    def to_dict(self) -> dict:
        return asdict(self)  # type: ignore[call-overload]

    @classmethod
    def from_dict(cls, d: dict):
        names = {f.name for f in fields(cls)}  # type: ignore[arg-type]
        return cls(**{k: v for k, v in d.items() if k in names})


@dataclass
class BounceRecord(Record):
    bounce: int
    seconds: float
    gather_seconds: float  # gathering and projecting the light the probes see
    interpolate_seconds: float
    mean_light: list  # (3,) area-weighted mean light of this bounce
    mean: float
    ratio: list  # (3,) per channel, of the bounce before
    ratio_mean: float
    estimated_remaining: float  # estimated share of the indirect light still missing after it
    energy_factor: list  # (3,) see series.conserve_energy
    attribute: str = ""


@dataclass
class TailReport(Record):
    """The light after the last bounce: how it was found and whether it was added."""

    estimated_remaining: float
    method: str = "none"  # "none", "geometric" or "solved"
    added: bool = False
    warning: str | None = None
    iterations: int | None = None
    relative_residual: float | None = None
    mean_light: list | None = None
    share_of_indirect: float | None = None

    def to_dict(self) -> dict:
        d = asdict(self)
        if self.method != "solved":
            d.pop("iterations")
            d.pop("relative_residual")
        if self.mean_light is None:
            d.pop("mean_light")
            d.pop("share_of_indirect")
        return d



@dataclass(frozen=True)
class FrameRecord:
    """One frame of an animation bake: ``route``, how its light was brought up to date
    ("full", "recapture", or an update's route: "lights", "materials", ...), its time and
    its area-weighted mean light; ``detail``: what that route reports (the probes, whether
    the capture was reused, what changed)."""

    frame: int
    seconds: float
    route: "Route"
    mean_direct: list
    mean_indirect: list
    detail: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"frame": self.frame, "seconds": self.seconds, "path": str(self.route), **self.detail,
                "mean_direct": self.mean_direct, "mean_indirect": self.mean_indirect}

    @classmethod
    def from_dict(cls, d: dict) -> "FrameRecord":
        """A record from :meth:`to_dict` (what the route reported is its detail again)."""
        known = ("frame", "seconds", "path", "mean_direct", "mean_indirect")
        return cls(int(d["frame"]), float(d["seconds"]), Route(d["path"]), list(d["mean_direct"]), list(d["mean_indirect"]),
                   {k: v for k, v in d.items() if k not in known})


@dataclass(frozen=True)
class AnimationResult:
    """An animation bake: its frames in order, its time and its cache folder."""

    frames: tuple[FrameRecord, ...]
    seconds: float
    cache: str

    def paths(self) -> dict[str, int]:
        """How many frames took each path, in the order first met."""
        count: dict[str, int] = {}
        for f in self.frames:
            count[str(f.route)] = count.get(str(f.route), 0) + 1
        return count

    def to_dict(self) -> dict:
        """The report's form (JSON)."""
        return {"frames": [f.to_dict() for f in self.frames], "seconds": self.seconds, "cache": self.cache}


def direct_step(step, message) -> "Progress":
    """``step(message)``, a working Progress; one of the direct stage's where no ``step`` is
    given."""
    return step(message) if step is not None else Progress(Stage.DIRECT, 1, 1, message, working=True)
