"""What changed since a kept bake, decided in one place: :func:`plan` reads the scene and
returns an :class:`UpdatePlan` (its :class:`~cubegi_engine.records.Route`, what changed, and
the edits to apply), without changing anything. Update Light, Live and an animation's frames
all take their plan here (:func:`cubegi_addon.live.update` applies it); whether the static
geometry moved is :func:`geometry_changes` for all of them.

| what changed | route |
|---|---|
| nothing | none |
| a light's power or colour, the world's colour, a light removed | weights |
| a light moved, turned, resized, its cone or shadow setting; a new light | lights (that light drawn again) |
| a material's colour or emission (asked for: reading the materials reads every mesh) | materials |
| only what an instant update left behind (the balance, the bounce layers) | settle |
| only dynamic objects moved | dynamic |
| the static geometry, the environment image or the light groups | refused, naming what changed |
"""

from dataclasses import dataclass, field, replace

import bpy
import numpy as np

from ..cubegi_engine import emitters
from ..cubegi_engine.errors import BakeError
from ..cubegi_engine.lights import light_keys
from ..cubegi_engine.records import Route
from ..cubegi_engine.scene import same_sky_map
from . import light_groups, scene_data

# Light fields whose change needs the light's direct light drawn again (not its colour).
PLACEMENT = ("kind", "position", "direction", "radius", "spot_size", "spot_blend", "polygon", "area", "casts_shadow", "samples",
             "shadow_size", "angle")


def same_place(a, b):
    """True if lights ``a`` and ``b`` cast the same direct light up to its colour."""
    for name in PLACEMENT:
        x, y = getattr(a, name), getattr(b, name)
        if (x is None) != (y is None):
            return False
        if x is not None and not np.array_equal(np.asarray(x), np.asarray(y)):
            return False
    return True


@dataclass(frozen=True)
class LightEdits:
    """How the lights and the sky differ from the light now: ``removed`` (keys), ``weights``
    (key -> colour: power or colour edits), ``drawn`` (key -> Light: placed, moved or
    reshaped), ``lights`` (key -> Light: every light wanted), ``sky`` (the new sky's
    radiance, None if unchanged)."""

    removed: tuple = ()
    weights: dict = field(default_factory=dict)
    drawn: dict = field(default_factory=dict)
    lights: dict = field(default_factory=dict)
    sky: np.ndarray | None = None

    @property
    def any(self):
        return bool(self.removed or self.weights or self.drawn or self.sky is not None)


@dataclass(frozen=True)
class MaterialEdits:
    """New albedo ``(s, 3)`` with what the surfaces send on (``sent``, ``SceneArrays.sent_on``),
    and emission ``(s, 3)``, each None if unchanged."""

    albedo: np.ndarray | None = None
    emission: np.ndarray | None = None
    sent: np.ndarray | None = None


@dataclass
class UpdatePlan:
    """What an update is to do: ``route``; ``changed``, one phrase per change (for the
    user); ``lights`` and ``sky`` read now; the edits; ``groups`` (the view layer's light
    groups now, when they differ); ``moving`` (the dynamic objects now, when any) and
    ``moved`` (their names, where they moved); ``instant``: a weighted sum alone (no balance,
    no bounce layers)."""

    route: Route
    changed: list
    lights: list
    sky: np.ndarray
    edits: LightEdits
    materials: MaterialEdits | None = None
    groups: object = None
    regroup: bool = False
    moving: list | None = None
    moved: list = field(default_factory=list)
    instant: bool = False

    @property
    def needs_light(self):
        """True if the plan edits the per-source light (the SceneLight is needed)."""
        return self.edits.any or self.materials is not None


def geometry_changes(view_layer, depsgraph, kept, only=None):
    """How the static geometry differs from the kept bake's, one phrase per object ("Block
    moved or edited", "Table deleted", "Chair added"); empty if alike. With ``only`` (a set
    of ``session_uid``) only those objects' shapes are compared (and every object's
    membership). The one test of "did the static geometry move" (Update Light, Live and
    animation frames)."""
    now = scene_data.static_shapes(view_layer, depsgraph, only)
    before = kept.bake.shapes or {}
    changes = [f"{name} deleted or hidden from renders" for uid, (name, _) in before.items() if uid not in now]
    changes += [f"{name} added" for uid, (name, _) in now.items() if uid not in before]
    changes += [f"{name} moved or edited" for uid, (name, digest) in now.items()
                if uid in before and digest is not None and digest != before[uid][1]]
    return changes


def render_geometry_changes(context, kept):
    """For an animation's frames: the static objects that can deform (modifiers, shape keys,
    animated mesh data) as a render evaluates them, against the bake's, one phrase per object
    that differs; empty when none can deform. (:func:`geometry_changes` reads the viewport's
    evaluation, which a modifier enabled for renders alone does not reach.)"""
    names = kept.bake.arrays.object_names
    if not any(_can_deform(bpy.data.objects.get(name)) for name in names):
        return []
    changed = scene_data.collect(context, grid=kept.bake.result.grid.whole()).arrays.fingerprint().changed(kept.bake.arrays.fingerprint())
    return [f"{name} deformed as rendered" for name in sorted(changed)]


def _can_deform(ob):
    if ob is None:
        return False
    data = ob.data
    return bool(len(ob.modifiers)) or getattr(data, "shape_keys", None) is not None or getattr(data, "animation_data", None) is not None


def effective_albedo(arrays, albedo):
    """``albedo (s, 3)`` as light sees it: zero at the snapshot's dark points."""
    return np.where(arrays.dark[:, None], 0.0, albedo) if arrays.dark is not None else albedo


def plan(context, kept, materials=False, geometry=True, settle=True, rendered=False):
    """The :class:`UpdatePlan` that brings ``kept``'s light up to the scene now. Refuses
    (BakeError) what an update cannot do: the static geometry changed (``geometry=False``:
    not checked; Live checks each edit as it comes instead; ``rendered``: also as a render
    evaluates it, :func:`render_geometry_changes`, for an animation's frames), another
    environment image, other light groups. ``materials``: read the materials too."""
    bake, live = kept.bake, kept.live
    if geometry:
        changes = geometry_changes(context.view_layer, context.evaluated_depsgraph_get(), kept)
        if rendered and not changes:
            changes = render_geometry_changes(context, kept)
        if changes:
            raise BakeError(f"the geometry changed since the bake ({', '.join(changes)}): Bake again (an update keeps "
                            "the capture, which only a bake redraws)")
    lights, sky, pattern, _ = scene_data.scene_lights(context)
    if not same_sky_map(bake.arrays.sky_map, pattern):
        raise BakeError("the world's environment image changed: Bake again (the probes' tables hold its directions)")
    changed = []
    groups = light_groups.read(context, replace(bake.arrays, lights=lights), [])
    if (groups and groups.names) != (live.groups and live.groups.names):
        raise BakeError("the view layer's light groups changed since the bake: Bake again (each group is a layer of its own)")
    regroup = groups != live.groups
    if regroup:
        changed.append("light groups")
    edits = _light_edits(live.lights, live.sky, lights, sky, changed)
    material_edits = _material_edits(context, kept, changed) if materials else None
    moving, moved = _moved_objects(context, kept) if live.moving else (None, [])
    out = UpdatePlan(Route.NONE, changed, lights, np.asarray(sky, dtype=np.float64), edits, material_edits, groups, regroup,
                     moving, moved)
    out.route = _route(out, live.unsettled, settle)
    out.instant = not settle and out.route == Route.WEIGHTS
    out.changed += [f"{name} moved" for name in moved]
    return out


def _route(p, unsettled, settle):
    if not (p.changed or (settle and unsettled) or p.moved):
        return Route.NONE
    if p.moved and not (p.changed or unsettled):
        return Route.DYNAMIC
    if p.materials is not None and any(c.startswith("material") for c in p.changed):
        return Route.MATERIALS
    if p.edits.drawn:
        return Route.LIGHTS
    return Route.WEIGHTS if p.changed else Route.SETTLE


def _light_edits(before, before_sky, lights, sky, changed):
    """The :class:`LightEdits` from the lights ``before`` (as the light now was made) to
    ``lights``, one phrase per change added to ``changed``."""
    was = dict(zip(light_keys(before), before))
    wanted = dict(zip(light_keys(lights), lights))
    removed = tuple(k for k in was if k not in wanted)
    changed += [f"{was[k].name} removed" for k in removed]
    weights, drawn = {}, {}
    for key, light in wanted.items():
        old = was.get(key)
        colour = np.asarray(light.colour, dtype=np.float64)
        if old is not None and same_place(old, light):
            if not np.array_equal(np.asarray(old.colour, dtype=np.float64), colour):
                weights[key] = colour
                changed.append(f"{light.name} power or colour")
            elif old.group != light.group:
                changed.append(f"{light.name} light group")
            continue
        drawn[key] = light
        changed.append(f"{light.name} {'placed' if old is None else 'moved or reshaped'}")
    sky = np.asarray(sky, dtype=np.float64)
    new_sky = None
    if not np.array_equal(np.asarray(before_sky, dtype=np.float64), sky):
        new_sky = sky
        changed.append("world colour")
    return LightEdits(removed, weights, drawn, wanted, new_sky)


def _material_edits(context, kept, changed):
    """The materials' colours and emission now, where they differ from the light now's."""
    bake, live = kept.bake, kept.live
    arrays = scene_data.collect(context, only=bake.only, grid=bake.result.grid.whole()).arrays
    if not arrays.fingerprint().same_geometry(bake.arrays.fingerprint()):
        _refuse_new_cuts(arrays, bake.arrays)
        raise BakeError("the geometry changed since the bake: Bake again (an update keeps the capture, which only a bake redraws)")
    albedo = emission = sent = None
    if not (np.array_equal(effective_albedo(arrays, arrays.albedo), effective_albedo(bake.arrays, live.albedo))
            and np.array_equal(arrays.sent_on(), live.sent if live.sent is not None else bake.arrays.sent_on())):
        albedo, sent = arrays.albedo, arrays.sent_on()
        changed.append("material colours")
    if not np.array_equal(arrays.emission, live.emission):
        emission = arrays.emission
        changed.append("material emission")
        _refuse_new_tables(arrays, bake.result.capture.transport.emitters_changed(arrays))
    return MaterialEdits(albedo, emission, sent)


class TablesChanged(BakeError):
    """An edit the kept tables do not hold (:func:`_refuse_new_tables`): a bake takes it,
    reusing the probes' cube maps (Live bakes again by itself)."""


def _refuse_new_tables(arrays, points):
    """Refuse (TablesChanged) an emission edit where ``points`` (from
    :meth:`~cubegi_engine.transport.Transport.emitters_changed`) started or stopped emitting."""
    if len(points):
        names = sorted({arrays.object_names[k] for k in np.unique(arrays.point_object[points])})
        raise TablesChanged(f"{', '.join(names)} started or stopped emitting across a covered gap, which the tables hold: "
                            "Bake again (the probes' cube maps are kept; only the tables are built again)")


def _refuse_new_cuts(arrays, baked):
    """Refuse (TablesChanged) an emission edit that changes how the surfaces by an emitter
    are sampled (:func:`cubegi_engine.refine.refine_near_emitters`: ``arrays``, read now, and
    the bake's ``baked`` differ only in those cuts), naming the objects that started or
    stopped emitting."""
    if arrays.cut_from is None or baked.cut_from is None or not arrays.cut_from.same_geometry(baked.cut_from):
        return
    names = sorted(_emitting_objects(arrays) ^ _emitting_objects(baked)) or ["an emitter"]
    raise TablesChanged(f"{', '.join(names)} started or stopped emitting close in front of a surface, which the bake samples "
                        "finer there: Bake again")


def _emitting_objects(arrays) -> set:
    return {arrays.object_names[k] for k in np.unique(np.asarray(arrays.point_object)[emitters.emitting_points(arrays)])}


def _moved_objects(context, kept):
    """``(the dynamic objects now, the names of those whose vertices moved since they were
    last lit)``."""
    now = scene_data.moving_objects(context, only=kept.bake.only)
    before = {t.object_name: a for a, t in kept.live.moving}
    moved = [t.object_name for a, t in now if t.object_name not in before or not (
        np.array_equal(a.points, before[t.object_name].points) and np.array_equal(a.normals, before[t.object_name].normals))]
    moved += [name for name in before if name not in {t.object_name for _, t in now}]
    return now, moved
