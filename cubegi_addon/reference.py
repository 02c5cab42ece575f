"""A path-traced reference: Cycles' Diffuse bake to vertex colours, per pass.

Cycles writes, with the colour pass off, the diffuse light a white surface reflects
(irradiance / pi), the same quantity as CubeGI's attributes. Every render and bake setting,
the selection and active colour attributes are put back afterwards.
"""

import contextlib
import os
import sys
import time

import bpy

from ..cubegi_engine.errors import BakeError
from . import attributes

REF_NAMES = {"DIRECT": attributes.REF_DIRECT, "INDIRECT": attributes.REF_INDIRECT}
_TMP = "CubeGI_ref_tmp"
MIN_SAMPLES, MAX_SAMPLES = 1, 1 << 20
# Cycles' defaults stop diffuse paths after 4 bounces, clamp bright indirect samples and
# skip faint lights: each biases a reference. Paths run until Russian roulette ends them.
# Every setting named here is saved and put back; samples and seed are then set per call.
_CYCLES_SETTINGS = {
    "samples": 128,
    "seed": 0,
    "device": "CPU",
    "max_bounces": 1024,
    "diffuse_bounces": 1024,
    "sample_clamp_direct": 0.0,
    "sample_clamp_indirect": 0.0,
    "light_sampling_threshold": 0.0,
    "use_adaptive_sampling": False,
    "use_denoising": False,
}


@contextlib.contextmanager
def _status_lines_muted():
    """Standard output (the process's, not Python's alone) closed to Cycles' status lines
    while it bakes without a window: Blender 4.5 prints one "Fra:1 Mem:..." line per object
    and step, some two hundred for a small room. Its errors go to standard error and the
    operator's reports, which stay."""
    if not bpy.app.background:
        yield
        return
    sys.stdout.flush()
    kept = os.dup(1)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
        yield
    finally:
        os.dup2(kept, 1)
        os.close(kept)


def reference_layers(context, targets, samples, seed=0):
    """Cycles' direct and indirect diffuse light for each bake target, as attribute layers.

    Returns ``(layers per target, seconds)``; writes nothing (the caller writes all of a
    bake's layers at once).
    """
    if not MIN_SAMPLES <= int(samples) <= MAX_SAMPLES:
        raise BakeError(f"reference samples must be between {MIN_SAMPLES} and {MAX_SAMPLES}, got {samples}")
    objects = [bpy.data.objects[t.object_name] for t in targets]
    t0 = time.perf_counter()
    baked, _ = bake_reference(context, objects, samples=int(samples), seed=seed)
    seconds = time.perf_counter() - t0
    layers = [{REF_NAMES[p]: baked[p][t.object_name] for p in baked} for t in targets]
    return layers, seconds


def bake_reference(context, meshes, passes=("DIRECT", "INDIRECT"), samples=128, seed=0):
    """Bake Cycles' ``passes`` for the mesh objects ``meshes``, per vertex.

    Returns ``({pass: {object name: (v, 3) array}}, {pass: seconds})``; the meshes keep no
    trace of it.
    """
    scene = context.scene
    view_layer = context.view_layer
    saved = {
        "engine": scene.render.engine,
        **{name: getattr(scene.cycles, name) for name in _CYCLES_SETTINGS},
        "use_pass_color": scene.render.bake.use_pass_color,
        "target": scene.render.bake.target,
        "selected": [o for o in view_layer.objects if o.select_get()],
        "active": view_layer.objects.active,
        "colour_names": {o.name: attributes.colour_names(o.data) for o in meshes},
    }
    out = {p: {} for p in passes}
    seconds = {}
    shown = _show(view_layer, meshes)
    try:
        scene.render.engine = "CYCLES"
        for name, value in _CYCLES_SETTINGS.items():
            setattr(scene.cycles, name, value)
        scene.cycles.samples = samples
        scene.cycles.seed = seed
        scene.render.bake.use_pass_color = False
        scene.render.bake.target = "VERTEX_COLORS"
        for o in view_layer.objects:
            o.select_set(False)
        for o in meshes:
            attr = o.data.color_attributes.new(_TMP, "FLOAT_COLOR", "POINT")
            o.data.color_attributes.active_color = attr
            o.select_set(True)
        view_layer.objects.active = meshes[0]
        for p in passes:
            t = time.perf_counter()
            with _status_lines_muted():
                bpy.ops.object.bake(type="DIFFUSE", pass_filter={p}, target="VERTEX_COLORS", use_clear=True)
            seconds[p] = time.perf_counter() - t
            for o in meshes:
                out[p][o.name] = attributes.read(o.data, _TMP)
    finally:
        for o in meshes:
            tmp = o.data.color_attributes.get(_TMP)
            if tmp is not None:
                o.data.color_attributes.remove(tmp)
            attributes.put_colour_names(o.data, saved["colour_names"][o.name])
        scene.render.engine = saved["engine"]
        for name in _CYCLES_SETTINGS:
            setattr(scene.cycles, name, saved[name])
        scene.render.bake.use_pass_color = saved["use_pass_color"]
        scene.render.bake.target = saved["target"]
        _unshow(shown)
        for o in view_layer.objects:
            o.select_set(o in saved["selected"])
        view_layer.objects.active = saved["active"]
    return out, seconds


def _show(view_layer, meshes):
    """Make ``meshes`` selectable for the bake where the viewport hides them (H, the monitor
    toggle, a hidden collection: they still render, so Cycles must bake them); returns what
    :func:`_unshow` puts back."""
    changed = []

    def layer_collections(lc):
        yield lc
        for child in lc.children:
            yield from layer_collections(child)

    for ob in meshes:
        for owner, name in ((ob, "hide_viewport"), (ob, "hide_select")):
            if getattr(owner, name):
                changed.append((owner, name, True))
                setattr(owner, name, False)
        if ob.hide_get(view_layer=view_layer):
            changed.append((ob, "hide_set", True))
            ob.hide_set(False, view_layer=view_layer)
        if not ob.visible_get(view_layer=view_layer):
            for lc in layer_collections(view_layer.layer_collection):
                if ob.name in lc.collection.objects:
                    for owner, name in ((lc, "hide_viewport"), (lc.collection, "hide_viewport"), (lc.collection, "hide_select")):
                        if getattr(owner, name):
                            changed.append((owner, name, True))
                            setattr(owner, name, False)
    return changed


def _unshow(changed):
    for owner, name, value in reversed(changed):
        if name == "hide_set":
            owner.hide_set(value)
        else:
            setattr(owner, name, value)
