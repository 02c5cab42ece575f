"""Dynamic objects in Blender: their attribute layers, lit from the kept bake's probe field
(the engine side is :mod:`cubegi_engine.moving`)."""

from ..cubegi_engine.moving import light_moving
from . import attributes, session
from .gpu_capture import GpuRenderer


def moving_layers(obj, target, field, lights, shadows, settings, lit):
    """The attribute layers of one dynamic object lit from ``field`` (see
    :func:`cubegi_engine.moving.light_moving`)."""
    direct, indirect = light_moving(obj, lights, shadows, field, GpuRenderer(obj.points, obj.triangles), settings)
    layers = {attributes.DIRECT: direct, attributes.INDIRECT: indirect, attributes.TOTAL: direct + indirect}
    if lit:
        layers[attributes.LIT] = obj.albedo * (indirect if lit == "INDIRECT" else direct + indirect)
    return {name: attributes.vertex_values(target, values) for name, values in layers.items()}


def write_moving(context, kept):
    """Light and write every dynamic object from the kept probe field."""
    moving = kept.moving or []
    for (obj, target), mesh in zip(moving, session.target_meshes([t for _, t in moving])):
        if mesh is None:
            continue
        for name, values in moving_layers(obj, target, kept.result.field, kept.arrays.lights, kept.result.shadows,
                                          kept.settings, kept.lit).items():
            attributes.put(mesh, name, values)
        mesh.update()
