"""Blender's light groups in the bake: one light layer per group of the view layer.

A view layer's light groups (View Layer > Light Groups) name sets of lights, the world and
emissive objects (Object > Shading > Light Group); Cycles renders one pass per group. Where
the view layer has any, a bake writes ``CubeGI_group_<name>`` per group: the diffuse light
(direct plus indirect, as ``CubeGI_total``) of that group's sources alone, so that an engine
or a compositor can remix the lights at run time (the export carries each as
``_CUBEGI_LIGHT_<NAME>``). The layers add up to ``CubeGI_total`` less the light of sources in
no group. Light is linear in each source, and each source is bounced with the whole scene's
energy balance (:class:`~cubegi_engine.relight.SceneLight`); each group gets its share of the
total, so the layers sum exactly.

A scene without light groups gets no such layer and pays nothing.
"""

from dataclasses import dataclass

import bpy
import numpy as np

from ..cubegi_engine.relight import EMISSION, SKY

__all__ = ["LightGroups", "read", "layers"]


@dataclass(frozen=True)
class LightGroups:
    """The view layer's light groups, and which one the world and the emitters are in.

    names: the groups, in the view layer's order; sky: the world's group ("" for none);
    emission: the emitters' group ("" for none), or None when emitters of several groups
    (their light then goes into no layer, with a note)."""

    names: tuple
    sky: str = ""
    emission: str | None = ""


def read(context, arrays, notes):
    """The light groups of the context's view layer for a bake of ``arrays``, or None if it
    has none; ``notes`` get what does not fit (a source in a group the view layer lacks,
    emitters in several groups)."""
    view_layer = context.view_layer
    names = tuple(g.name for g in view_layer.lightgroups)
    if not names:
        return None

    def known(group, what):
        if group and group not in names:
            notes.append(f"{what}: its light group {group!r} is not one of view layer {view_layer.name!r}'s; its light "
                         "is in no group layer")
            return ""
        return group

    for light in arrays.lights:
        known(light.group, f"light {light.name}")
    world = context.scene.world
    sky = known(world.lightgroup, f"world {world.name}") if world is not None else ""
    emissive = np.unique(arrays.point_object[np.any(arrays.emission > 0, axis=1)]) if arrays.point_object is not None else []
    by_group = {}
    for k in emissive:
        name = arrays.object_names[k]
        ob = bpy.data.objects.get(name)
        group = known(ob.lightgroup, name) if ob is not None else ""
        by_group.setdefault(group, []).append(name)
    emission = next(iter(by_group)) if len(by_group) == 1 else ("" if not by_group else None)
    if emission is None:
        parts = "; ".join(f"{g or 'no group'}: {', '.join(sorted(n))}" for g, n in sorted(by_group.items()))
        notes.append(f"emissive objects of several light groups ({parts}): CubeGI lights the scene with all their light "
                     "together, which goes into no group layer")
    return LightGroups(names, sky, emission)


def _group(key, src, groups):
    if src.light is not None:
        return src.light.group if src.light.group in groups.names else ""
    if key == SKY:
        return groups.sky
    if key == EMISSION:
        return groups.emission or ""
    return ""


def layers(state, groups, total):
    """``{group: (s, 3)}``: each group's share of ``total (s, 3)`` (the light written as
    ``CubeGI_total``), per point and channel the share its sources have of every source's
    light in the solved :class:`~cubegi_engine.relight.SceneLight` ``state``. The layers then
    add up to ``total`` exactly (less the sources in no group), also where the relit state and
    the bake's own solve differ a little (the emitters' balance: 1.6% of the peak on
    McGuire's Cornell box)."""
    out = {g: np.zeros((len(state.scene.points), 3)) for g in groups.names}
    every = np.zeros((len(state.scene.points), 3))
    for key, src in state.sources.items():
        light = (src.direct + src.indirect) * src.weight
        every += light
        group = _group(key, src, groups)
        if group:
            out[group] += light
    share = np.divide(total, every, out=np.zeros_like(every), where=every > 0)
    return {g: v * share for g, v in out.items()}
