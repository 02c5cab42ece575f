"""The probe grids in the 3D viewport: a dot per probe, and after a bake a small sphere per
probe shaded with its light (stored on the grid object, see :mod:`.grid_objects`).

Probes inside geometry are drawn red and get no sphere. What to draw is cached as arrays
per object (keyed by its ``session_uid``, so a rename keeps nothing stale), rebuilt when a
grid's transform, resolution or light changes; GPU batches are made at draw time (see
:func:`_geometry`).
"""

import bpy
import gpu
import numpy as np
from gpu_extras.batch import batch_for_shader

from ..cubegi_engine.spheres import probe_spheres
from . import grid_objects, interrupts, prefs

PROBE_COLOUR = (0.9, 0.75, 0.2, 1.0)
INSIDE_COLOUR = (0.9, 0.15, 0.1, 1.0)

_handle = None
_cache = {}


def forget_drawing(ob=None):
    """Drop what is cached for drawing ``ob`` (every grid object's, without ``ob``)."""
    if ob is None:
        _cache.clear()
    else:
        _cache.pop(ob.session_uid, None)


def sphere_radius(grid, scale):
    """Sphere radius: ``scale`` (a preference) times the grid's smallest cell edge."""
    return scale * float(np.min(grid.cell_size))


def _geometry(ob):
    """What to draw for a grid object, as arrays: ``[(kind, arrays, indices, colour)]``, cached.

    Only numpy arrays are cached; GPU batches are made at draw time, in the context that
    draws them (a batch's vertex arrays belong to the GPU context it was first drawn in).
    """
    key = (tuple(tuple(r) for r in ob.matrix_world), tuple(ob.cubegi.resolution), ob.empty_display_size,
           ob.cubegi.show_irradiance, prefs.get().sphere_scale)
    cached = _cache.get(ob.session_uid)
    if cached is not None and cached[0] == key:
        return cached[1]
    stored = grid_objects.stored_probe_light(ob)
    grid = grid_objects.probe_grid(ob)
    positions = grid.positions() + grid_objects.stored_probe_offsets(ob)  # where the bake's probes stood
    valid = stored[1] if stored is not None else np.ones(len(positions), dtype=bool)
    parts = []
    for mask, colour in ((valid, PROBE_COLOUR), (~valid, INSIDE_COLOUR)):
        if mask.any():
            parts.append(("POINTS", {"pos": positions[mask].astype(np.float32)}, None, colour))
    if stored is not None and ob.cubegi.show_irradiance and valid.any():
        verts, colours, tris = probe_spheres(positions[valid], stored[0][valid], sphere_radius(grid, prefs.get().sphere_scale))
        rgba = np.concatenate([np.minimum(colours, 1.0), np.ones((len(colours), 1), np.float32)], axis=1)
        parts.append(("TRIS", {"pos": verts, "color": rgba}, tris, None))
    _cache[ob.session_uid] = (key, parts)
    return parts


def draw(scene=None):
    """Draw every visible probe grid of the scene (the viewport's draw handler)."""
    scene = scene or bpy.context.scene
    if scene is None:
        return
    gpu.state.depth_test_set("LESS_EQUAL")
    gpu.state.depth_mask_set(True)
    gpu.state.point_size_set(6.0)
    point_shader = gpu.shader.from_builtin("POINT_UNIFORM_COLOR")
    sphere_shader = gpu.shader.from_builtin("SMOOTH_COLOR")
    for ob in grid_objects.probe_grid_objects(scene):
        if not ob.visible_get() or not ob.cubegi.show_probes:
            continue
        for kind, arrays, indices, colour in _geometry(ob):
            shader = point_shader if kind == "POINTS" else sphere_shader
            batch = batch_for_shader(shader, kind, arrays, indices=indices)
            shader.bind()
            if colour is not None:
                shader.uniform_float("color", colour)
            batch.draw(shader)
    gpu.state.point_size_set(1.0)
    gpu.state.depth_mask_set(False)
    gpu.state.depth_test_set("NONE")


@bpy.app.handlers.persistent
@interrupts.blender_callback
def _forget_all(*_):
    """Undo, redo and loading a file can change the stored light behind the cache's back."""
    _cache.clear()


_HANDLER_LISTS = ("undo_post", "redo_post", "load_post")


def register():
    global _handle
    _handle = bpy.types.SpaceView3D.draw_handler_add(draw, (), "WINDOW", "POST_VIEW")
    for name in _HANDLER_LISTS:
        getattr(bpy.app.handlers, name).append(_forget_all)


def unregister():
    global _handle
    if _handle is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_handle, "WINDOW")
        _handle = None
    for name in _HANDLER_LISTS:
        handlers = getattr(bpy.app.handlers, name)
        if _forget_all in handlers:
            handlers.remove(_forget_all)
    _cache.clear()
