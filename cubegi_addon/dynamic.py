"""Dynamic objects in Blender: their attribute layers, lit from the kept bake's probe field
(the engine side is :mod:`cubegi_engine.moving`)."""

from ..cubegi_engine.moving import light_moving
from . import attributes, session
from .gpu_capture import GpuRenderer


def moving_layers(obj, target, field, lights, shadows, settings, lit):
    """The attribute layers of one dynamic object lit from ``field`` (see
    :func:`cubegi_engine.moving.light_moving`)."""
    direct, indirect = light_moving(obj, lights, shadows, field, GpuRenderer(obj.points, obj.triangles), settings)
    layers = attributes.light_layers(direct, indirect, albedo=obj.albedo, lit=lit)
    return {name: attributes.vertex_values(target, values) for name, values in layers.items()}


def write_moving(kept):
    """Light and write every dynamic object from the probe field now."""
    bake, live = kept.bake, kept.live
    for (obj, target), mesh in zip(live.moving, session.target_meshes([t for _, t in live.moving])):
        if mesh is None:
            continue
        for name, values in moving_layers(obj, target, live.field, live.lights, live.shadows or {}, bake.settings,
                                          bake.lit).items():
            attributes.put(mesh, name, values)
        mesh.update()
