"""Objects that move, lit without a capture: from the kept probe field and the static
scene's kept shadow maps. Pure numpy; must not import bpy.

A moving (dynamic) object is left out of the capture. At every update its vertices, with
its current transform and deformation, get

* direct light from each light: the light's formula, times the visibility through the
  static scene (the light's depth maps of the static scene, drawn at the bake and kept),
  times the object's own self-shadowing (a small depth map of the object alone);
* the sky's and emitters' light and the indirect light from the probe field
  (:class:`cubegi_engine.field.ProbeField`), interpolated at its vertices, leaving out
  probes behind each vertex's surface (a probe inside the object must not light it).

What the probe field cannot give it: light the object reflects onto itself (its own
interreflection), and light that reaches it through a gap smaller than a probe cell
(the field has no depth test for points the capture never saw). It does not shadow or
light the static scene (as EEVEE's and Unity's probe-lit objects).
"""

from dataclasses import replace

import numpy as np

from . import lights as lights_mod
from .direct import draw_shadow, visibility

__all__ = ["light_moving", "SELF_SHADOW_SIZE"]

# Edge of an object's own depth maps: it fills a small part of a light's view, so far fewer
# texels than the static scene's maps carry its self-shadowing (cube faces; a sun's box is
# fitted to the object).
SELF_SHADOW_SIZE = 128


def light_moving(obj, lights, shadows, field, renderer, settings):
    """``(direct, indirect)``, each ``(s, 3)``, for a moving object ``obj`` (SceneArrays of
    the object alone, world space). ``shadows``: a light's ``shadow_key`` -> the static scene's
    :class:`~cubegi_engine.direct.Shadow`; ``renderer`` draws the object alone."""
    s = len(obj.points)
    direct = np.zeros((s, 3))
    outside = np.full(s, -1, dtype=np.int64)  # the object's points are none of the static scene's
    for light in lights:
        value = lights_mod.unshadowed(light, obj.points, obj.normals)
        lit = np.any(value > 0, axis=1)
        if light.casts_shadow and lit.any():
            pts, nrm = obj.points[lit], obj.normals[lit]
            vis = np.ones(len(pts))
            static = shadows.get(light.shadow_key)
            if static is not None:
                vis *= visibility(static, pts, nrm, outside[lit])
            # Its own shadow from the light's centre alone (one small map, every update).
            own_light = replace(light, samples=light.position[None], radius=0.0)
            own = draw_shadow(obj, renderer, settings, own_light, size=SELF_SHADOW_SIZE)
            vis *= visibility(own, pts, nrm, np.arange(s)[lit])
            value[lit] *= vis[:, None]
        direct += value
    seen, indirect = field.light_parts(obj.points, obj.normals, ("direct", "indirect"), one_sided=True)
    return direct + seen, indirect
