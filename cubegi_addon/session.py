"""What outlives a bake inside Blender: per scene, the last bake as it was made
(:class:`BakeSnapshot`: its arrays, capture, light and probe field) and its light as updates
left it (:class:`LiveState`), together a :class:`Kept`, so that the next bake of an unchanged geometry reuses the
capture, and later updates (light edits, moving objects) start from them.

Kept in this module's memory only (never in the file): keyed by the scene's
``session_uid``, freed when a file is loaded, when the add-on is unregistered, by
:func:`forget`, and after an undo or redo that leaves the file without this bake's light
(:func:`after_undo`: the file's ``bake_id`` is another bake's, or a baked mesh is gone).
Blender data are found again by ``session_uid``, which names, undo and redo keep. Bounded: at most
:data:`MAX_KEPT_SCENES` scenes and :func:`budget` bytes in all, the least recently baked
dropped first; a bake larger than the budget alone is not kept.
"""

import atexit
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

import bpy
import numpy as np

from ..cubegi_engine.bake import physical_memory
from ..cubegi_engine.gather import kept_nbytes
from . import interrupts
from .attributes import LitMode

MAX_KEPT_SCENES = 4
# At most this share of the machine's memory, and never more than MAX_KEPT_BYTES.
KEPT_SHARE = 0.125
MAX_KEPT_BYTES = 2 << 30


@dataclass(frozen=True)
class BakeSnapshot:
    """What a bake made, as it made it (no update changes it): ``arrays`` (the SceneArrays),
    ``targets`` (MeshTargets), ``result`` (the engine's BakeResult: capture, direct light per
    source, solution, field), ``settings`` and ``lit`` (how it was baked), ``placements``
    (object name -> world matrix, :func:`placements`), ``shapes`` (session_uid -> (name,
    digest) of the static geometry: ``scene_data.static_shapes``), ``bake_id`` (the scene's
    ``cubegi.bake_id`` it wrote), ``resolution`` (the grid resolution asked for, None: the
    scene's), ``only`` (the session_uid of the objects it wrote light into, if it was asked
    for some: Bake Selected)."""

    arrays: Any
    targets: list
    result: Any
    settings: Any
    lit: LitMode = LitMode.NONE
    placements: dict = field(default_factory=dict)
    shapes: dict = field(default_factory=dict)
    bake_id: str = ""
    resolution: tuple | None = None
    only: frozenset | None = None


@dataclass
class LiveState:
    """The light now, as updates left it (:mod:`.live`), on a :class:`BakeSnapshot`:
    ``lights``, ``sky``, ``albedo``, ``emission`` (what the light was last made with),
    ``field`` (the probe field now), ``shadows`` (the shadow maps now, by
    ``Light.shadow_key``, for dynamic objects: a copy of the bake's, redrawn lights
    replaced), ``moving`` (``[(SceneArrays, MeshTarget)]`` of the
    dynamic objects as last lit), ``groups`` (the view layer's LightGroups, or None: no group
    layers); made on first use: ``light`` (the engine's SceneLight, per source) and
    ``renderer`` (for shadow maps). ``unsettled``: an instant update left the balance and
    the bounce layers behind."""

    lights: list
    sky: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    field: Any
    shadows: dict | None = None
    moving: list = field(default_factory=list)
    groups: Any = None
    light: Any = None
    renderer: Any = None
    unsettled: bool = False
    sent: np.ndarray | None = None  # what the surfaces send on now, where a material edit changed it (else the bake's)

    @classmethod
    def of(cls, snapshot: BakeSnapshot, moving=(), groups=None, light=None, renderer=None, shadows=None) -> "LiveState":
        """The live state of a bake just made: its lights, sky, materials, field and (a copy
        of) its shadow maps, unless ``shadows`` (that copy) is given."""
        arrays = snapshot.arrays
        if shadows is None:
            shadows = dict(snapshot.result.shadows)
        return cls(list(arrays.lights), np.asarray(arrays.sky, dtype=np.float64), arrays.albedo, arrays.emission,
                   snapshot.result.field, shadows, list(moving), groups, light, renderer)


@dataclass
class Kept:
    """A scene's last bake (``bake``, frozen) and its light now (``live``)."""

    bake: BakeSnapshot
    live: LiveState

    @property
    def nbytes(self):
        bake, field = self.bake, self.bake.result.field
        a = bake.arrays
        arrays = (a.points, a.normals, a.albedo, a.emission, a.triangles,
                  *(x for x in (a.reflectance, self.live.sent) if x is not None))
        light = [bake.result.solution.direct, *bake.result.solution.bounces, *bake.result.direct_parts.parts.values()]
        extra = self.live.light.op.nbytes if self.live.light is not None else 0
        extra += kept_nbytes(a)  # the gathered vertices' ray caster and rays
        if self.live.field is not field:
            extra += self.live.field.coeffs.nbytes
        return bake.result.capture.nbytes + field.nbytes + extra + sum(x.nbytes for x in (*arrays, *light))


_kept = OrderedDict()


def budget():
    total = physical_memory() or 8 << 30
    return int(min(MAX_KEPT_BYTES, KEPT_SHARE * total))


def keep(scene, kept):
    """Keep ``kept`` as ``scene``'s last bake; returns False if it is too large to keep."""
    _kept.pop(scene.session_uid, None)
    limit = budget()
    if kept.nbytes > limit:
        return False
    _kept[scene.session_uid] = kept
    while len(_kept) > MAX_KEPT_SCENES or sum(k.nbytes for k in _kept.values()) > limit:
        _kept.popitem(last=False)
    return True


def kept(scene):
    """The scene's last kept bake, or None."""
    return _kept.get(scene.session_uid)


def forget(scene=None):
    """Drop the kept bake of ``scene`` (of every scene without one)."""
    if scene is None:
        _kept.clear()
    else:
        _kept.pop(scene.session_uid, None)


# A kept bake may hold GPU batches (a renderer for shadow maps): they must go while the GPU
# context still exists, before the interpreter's own teardown (else a crash at exit).
atexit.register(lambda: forget())


def placement(ob):
    """An object's world matrix, as a hashable key."""
    return tuple(round(v, 9) for row in ob.matrix_world for v in row)


def placements(names):
    """Each named object's world matrix now, to tell a moved object from our own writes."""
    return {name: placement(bpy.data.objects[name]) for name in names if name in bpy.data.objects}


def kept_bytes():
    return sum(k.nbytes for k in _kept.values())


def target_meshes(targets):
    """The mesh of each target (a MeshTarget) now, found by its object's ``session_uid``
    (a renamed object or mesh is still found), or None where the object is gone or its mesh
    no longer has the target's vertices."""
    by_uid = {ob.session_uid: ob for ob in bpy.data.objects}
    out = []
    for target in targets:
        ob = by_uid.get(target.object_uid)
        mesh = ob.data if ob is not None and ob.type == "MESH" else None
        out.append(mesh if mesh is not None and len(mesh.vertices) == target.vertex_count else None)
    return out


def after_undo():
    """After an undo or redo: drop each kept bake whose light the file no longer holds (the
    scene is gone, its ``bake_id`` is another bake's, or a baked mesh is gone); the others
    are marked unsettled (the restored attributes may hold an earlier update's light: the
    next update writes them all). Returns ``[(scene, kept)]`` of those kept."""
    scenes = {scene.session_uid: scene for scene in bpy.data.scenes}
    out = []
    for uid, kept in list(_kept.items()):
        scene = scenes.get(uid)
        if scene is None or scene.cubegi.bake_id != kept.bake.bake_id or None in target_meshes(kept.bake.targets):
            _kept.pop(uid)
            continue
        kept.live.unsettled = True
        out.append((scene, kept))
    return out


@bpy.app.handlers.persistent
@interrupts.blender_callback
def _forget_all(*_):
    forget()


HANDLER_LISTS = ("load_pre",)


def register():
    for name in HANDLER_LISTS:
        getattr(bpy.app.handlers, name).append(_forget_all)


def unregister():
    for name in HANDLER_LISTS:
        handlers = getattr(bpy.app.handlers, name)
        if _forget_all in handlers:
            handlers.remove(_forget_all)
    forget()
