"""Animation bakes: every frame's light, each by the cheapest valid path, into a cache folder
that other tools can read, and applied to the attributes when the frame changes.

Cache format (documented in docs/user-guide.md#dynamic-scenes): for ``OUT.blend`` the folder
``OUT.cubegi/`` holds one ``frame_NNNN.npz`` per frame (four digits, zero-padded), with, for
every baked object, the arrays ``"<object name>:direct"`` and ``"<object name>:indirect"``:
float32, shape ``(vertices, 3)``, in vertex order, the values the attributes
``CubeGI_direct`` and ``CubeGI`` take at that frame (diffuse light, irradiance / pi).

Per frame, after ``scene.frame_set``: the first frame is a full bake; later frames update on
the kept capture (:func:`cubegi_addon.live.update`: lights, the world, materials, dynamic
objects; :mod:`cubegi_addon.updates` decides the route), and a frame whose static geometry
changed is baked in full again ("full"; the capture is redrawn).
"""

import os
import time

import bpy
import numpy as np

from ..cubegi_engine.errors import BakeError, Interrupted
from ..cubegi_engine.records import AnimationResult, FrameRecord, Progress, Route, Stage
from . import attributes, files, interrupts, live, pipeline, session

FRAME_FILE = "frame_{:04d}.npz"
# In a cache folder baked on a cluster: what its frames were baked from (the input's content,
# the options, the version), for a re-run to skip. Any other bake into the folder removes it.
KEY_FILE = "cubegi_cache.json"
# Scene.cubegi.animation_cache holds the cache folder (relative to the .blend, "//...").


def cache_folder(blend_path):
    """The cache folder of the baked file ``blend_path``: ``OUT.cubegi`` beside ``OUT.blend``."""
    root, _ = os.path.splitext(blend_path)
    return root + ".cubegi"


def cache_link(folder):
    """What ``Scene.cubegi.animation_cache`` holds for ``folder``: its path beside the .blend,
    relative (``//OUT.cubegi``), so that the file and its cache move together."""
    return "//" + os.path.basename(os.path.normpath(folder))


def check_cache_folder(folder, advice):
    """Refuse (BakeError, with ``advice``) a cache folder that is a file."""
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise BakeError(f"the cache folder {folder!r} is a file; {advice}")


def frame_path(folder, frame):
    return os.path.join(folder, FRAME_FILE.format(int(frame)))


def _baked_objects(scene):
    """Every mesh object of the scene whose mesh holds CubeGI's light, by name."""
    return sorted(
        (ob for ob in scene.objects if ob.type == "MESH" and {attributes.DIRECT, attributes.INDIRECT} <= attributes.owned(ob.data)),
        key=lambda ob: ob.name,
    )


def frame_arrays(scene):
    """``{"<object>:direct": (v, 3) float32, "<object>:indirect": ...}`` as the attributes hold now."""
    out = {}
    for ob in _baked_objects(scene):
        for part, name in (("direct", attributes.DIRECT), ("indirect", attributes.INDIRECT)):
            out[f"{ob.name}:{part}"] = attributes.read(ob.data, name).astype(np.float32)
    return out


def _mean(arrays):
    direct = [v for k, v in arrays.items() if k.endswith(":direct")]
    indirect = [v for k, v in arrays.items() if k.endswith(":indirect")]

    def mean(values):
        return np.concatenate(values).mean(axis=0).tolist() if values else [0.0, 0.0, 0.0]

    return mean(direct), mean(indirect)


# Scenes (session_uid) an animation bake is running on: their frame changes are the bake's own
# and show no cache.
_baking = set()


def bake_animation_steps(context, settings, frames, folder, resolution=None, lit=None, only=None):
    """Bake frames ``frames`` (an iterable of ints) into ``folder``; a generator of Progress
    (one per frame), returning an :class:`~cubegi_engine.records.AnimationResult`. The
    scene's cache link is the caller's to set: a bake refused or failed leaves it as it was."""
    scene = context.scene
    frames = [int(f) for f in frames]
    if not frames:
        raise BakeError("no frames to bake")
    _baking.add(scene.session_uid)
    try:
        return (yield from _bake_frames(context, settings, frames, folder, resolution, lit, only))
    finally:
        _baking.discard(scene.session_uid)


def _bake_frames(context, settings, frames, folder, resolution, lit, only):
    scene = context.scene
    os.makedirs(folder, exist_ok=True)
    records = []
    t_all = time.perf_counter()
    try:
        for k, frame in enumerate(frames):
            yield Progress(Stage.BOUNCE, k, len(frames), f"frame {frame} ({k + 1}/{len(frames)})")
            t = time.perf_counter()
            scene.frame_set(frame)
            route, detail = _frame(context, settings, resolution, lit, only, first=k == 0)
            arrays = frame_arrays(scene)
            if not records and os.path.exists(os.path.join(folder, KEY_FILE)):
                os.remove(os.path.join(folder, KEY_FILE))  # its frames are about to change
            direct, indirect = _mean(arrays)
            record = FrameRecord(frame, time.perf_counter() - t, route, direct, indirect, detail)
            try:
                files.write_all([(frame_path(folder, frame), _npz(arrays))])
            except KeyboardInterrupt as exc:
                if getattr(exc, "written", None):  # the frame is in place
                    records.append(record)
                raise
            records.append(record)
    except KeyboardInterrupt as exc:
        if not records:
            raise
        span = f"frame {records[0].frame}" if len(records) == 1 else f"frames {records[0].frame}-{records[-1].frame}"
        raise Interrupted.keeping(exc, f"the light of {span} is baked and kept in {folder} (each frame whole)") from None
    yield Progress(Stage.TAIL, len(frames), len(frames), f"baked {len(frames)} frames")
    return AnimationResult(tuple(records), time.perf_counter() - t_all, folder)


def _animated_materials():
    """True if any material (or its node tree) is animated or driven: only then does a frame
    read the materials again (which reads every mesh)."""
    for material in bpy.data.materials:
        for data in (material, material.node_tree):
            anim = getattr(data, "animation_data", None) if data is not None else None
            if anim is not None and (anim.action is not None or len(anim.drivers)):
                return True
    return False


def _frame(context, settings, resolution, lit, only, first):
    """Bring the attributes to the current frame; ``(route, details)``."""
    if not first and session.kept(context.scene) is not None:
        try:  # the update's plan refuses a frame whose static geometry changed (updates.geometry_changes)
            report = live.update(context, materials=_animated_materials(), bounce_layers=False, rendered=True)
            return report.route, {"changed": report.changed}
        except BakeError:  # then a full bake
            pass
    report = pipeline.bake(context, settings, resolution, lit=lit, only=only)
    details = {"probes": report.grid.probes, "capture_reused": report.capture_reused}
    if report.probes_recaptured is not None:
        return Route.RECAPTURE, dict(details, probes_recaptured=report.probes_recaptured)
    return Route.FULL, details


def _npz(arrays):
    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    return write


def apply_frame(scene, folder, frame):
    """Put a cached frame's light on the attributes (direct, indirect, total). Returns None
    if every baked object got its light, else what was missing (one line): no such frame or
    folder, or objects the cache has no light for (renamed or changed since the bake), which
    keep the light they had."""
    path = frame_path(folder, frame)
    if not os.path.isfile(path):
        where = "the cache folder is missing" if not os.path.isdir(folder) else f"frame {frame} is not in it"
        return f"animation cache {folder}: {where}; the light shown is an earlier frame's (Bake Animation again)"
    missing = []
    with np.load(path) as data:
        for ob in _baked_objects(scene):
            direct, indirect = data.get(f"{ob.name}:direct"), data.get(f"{ob.name}:indirect")
            if direct is None or indirect is None or direct.shape != (len(ob.data.vertices), 3):
                missing.append(ob.name)
                continue
            attributes.put(ob.data, attributes.DIRECT, direct)
            attributes.put(ob.data, attributes.INDIRECT, indirect)
            attributes.put(ob.data, attributes.TOTAL, direct + indirect)
            ob.data.update()
    if missing:
        return (f"animation cache, frame {frame}: no light for {', '.join(missing)} (renamed or changed since the "
                "bake); they keep an earlier frame's light (Bake Animation again)")
    return None


def detach_cache(scene):
    """A still bake's light replaces the animation's: the scene stops showing its cache (it
    stays on disk). Returns whether it showed one."""
    attached = bool(scene.cubegi.animation_cache)
    scene.cubegi.animation_cache = ""
    return attached


@bpy.app.handlers.persistent
@interrupts.blender_callback
def on_frame_change(scene, depsgraph=None):
    """The one frame handler: with Live on, the frame's lights are applied
    (:func:`.live.live_frame`); else, with a baked animation cache on the scene, each frame's
    light is shown from it (scrubbing, playback, ``blender -b -a`` renders)."""
    settings = getattr(scene, "cubegi", None)
    if settings is None or scene.session_uid in _baking:
        return
    if settings.live:
        live.live_frame(scene)
        return
    if not settings.animation_cache:
        return
    problem = apply_frame(scene, bpy.path.abspath(settings.animation_cache), scene.frame_current)
    if problem and settings.last_update != problem:
        settings.last_update = problem  # the panel shows it
        print(f"CubeGI: {problem}")
    elif not problem and settings.last_update.startswith("animation cache"):
        settings.last_update = ""


def register():
    bpy.app.handlers.frame_change_post.append(on_frame_change)


def unregister():
    if on_frame_change in bpy.app.handlers.frame_change_post:
        bpy.app.handlers.frame_change_post.remove(on_frame_change)
