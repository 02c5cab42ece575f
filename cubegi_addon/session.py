"""What outlives a bake inside Blender: per scene, the last bake's snapshot, capture, light
and probe field (:class:`Kept`), so that the next bake of an unchanged geometry reuses the
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
import os
from collections import OrderedDict
from dataclasses import dataclass

import bpy

from . import interrupts

MAX_KEPT_SCENES = 4
# At most this share of the machine's memory, and never more than MAX_KEPT_BYTES.
KEPT_SHARE = 0.125
MAX_KEPT_BYTES = 2 << 30


@dataclass
class Kept:
    """A bake's parts: ``arrays`` (the SceneArrays snapshot), ``targets`` (MeshTargets),
    ``result`` (the engine's BakeResult: capture, direct light per source, solution, field),
    ``settings`` and ``lit`` (how it was baked); made on first use by :mod:`.live`:
    ``light`` (the engine's SceneLight, per source) and ``renderer`` (for shadow maps)."""

    arrays: object
    targets: list
    result: object
    settings: object = None
    lit: object = None
    light: object = None
    renderer: object = None
    unsettled: bool = False  # an instant update left the balance and bounce layers behind
    placements: dict = None  # object name -> world matrix at the bake (see live.placements)
    shapes: dict = None  # session_uid -> (name, digest): the static geometry at the bake (scene_data.static_shapes)
    bake_id: str = ""  # the scene's cubegi.bake_id this bake wrote
    moving: list = None  # [(SceneArrays, MeshTarget)] of the dynamic objects as last lit
    resolution: tuple = None  # the grid resolution the bake was asked for (None: the scene's)
    only: frozenset = None  # the session_uid of the objects the bake wrote light into, if it was asked for some (Bake Selected)
    groups: object = None  # the view layer's LightGroups at the bake (light_groups.read), or None: no group layers

    @property
    def nbytes(self):
        field = self.result.field
        arrays = (self.arrays.points, self.arrays.normals, self.arrays.albedo, self.arrays.emission, self.arrays.triangles)
        light = [self.result.solution.direct, *self.result.solution.bounces, *self.result.direct_parts.parts.values()]
        extra = self.light.op.nbytes if self.light is not None else 0
        return self.result.capture.nbytes + field.nbytes + extra + sum(a.nbytes for a in (*arrays, *light))


_kept = OrderedDict()


def budget():
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        total = 8 << 30
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
        if scene is None or scene.cubegi.bake_id != kept.bake_id or None in target_meshes(kept.targets):
            _kept.pop(uid)
            continue
        kept.unsettled = True
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
