"""The light a Principled BSDF's specular layer sends on, as a share of a diffuse reflectance.

Pure numpy; must not import bpy.

CubeGI bakes every surface as diffuse: a point's light is what arrives at it, and what it
sends on is that light times its albedo. A Principled BSDF (Blender's default material) is a
diffuse base under a dielectric specular layer: even at Roughness 1 the layer reflects some of
the light that reaches it (more at grazing angles), and Cycles counts that light in every
other surface's indirect light. Baked with its Base Color alone, a dark surface sends on too
little: a floor of base colour 0.2 sends on 8% more in Cycles, one of 0.05 40% more.

So the albedo a Principled BSDF sends on is ``base + share (1 - base)`` (:func:`sent_on`):
the diffuse base loses what the layer reflects, and the layer's reflection, spread evenly,
is added. ``share`` (:func:`specular_share`) is measured in Cycles: a floor of base colour 0.05
and 0.2 under a uniform sky, the light it sends a receiver above it, a Principled BSDF against a
Diffuse BSDF of the same colour (1024 samples, bpy 5.3.0; both colours give the share to within
0.01), by Roughness, at Specular IOR Level 0.5 and IOR 1.5 (a facing reflectance F0 of 0.04).
Another facing reflectance scales it by ``(F0 / 0.04) ** F0_POWER`` (measured: Specular IOR
Level 1 and 0.25, IOR 1.33). The layer's light goes on as a diffuse surface's would, not as a
mirror's: its energy is right, its direction is spread.
"""

import numpy as np

__all__ = ["facing_reflectance", "specular_share", "sent_on", "ROUGHNESS", "SHARE_AT_F0", "F0_MEASURED", "F0_POWER"]

ROUGHNESS = (0.0, 0.25, 0.5, 0.75, 1.0)
SHARE_AT_F0 = (0.035, 0.036, 0.040, 0.037, 0.020)
F0_MEASURED, F0_POWER = 0.04, 0.75


def facing_reflectance(ior, level) -> float:
    """F0 of a dielectric of index ``ior``, scaled by the Specular IOR Level ``level`` as
    Cycles scales it (0.5: as the IOR gives it; 0: none; 1: twice)."""
    ior = max(float(ior), 1.0)
    return ((ior - 1.0) / (ior + 1.0)) ** 2 * 2.0 * max(float(level), 0.0)


def specular_share(f0, roughness) -> np.ndarray:
    """The share of the light reaching a Principled BSDF that its specular layer sends on,
    for facing reflectance ``f0`` (a number or per channel ``(3,)``: the Specular Tint's
    colour times F0) and ``roughness``; in [0, 1]."""
    at_f0 = np.interp(float(np.clip(roughness, 0.0, 1.0)), ROUGHNESS, SHARE_AT_F0)
    f0 = np.clip(np.asarray(f0, dtype=np.float64), 0.0, 1.0)
    return np.clip(at_f0 * (f0 / F0_MEASURED) ** F0_POWER, 0.0, 1.0)


def sent_on(base, share) -> np.ndarray:
    """What a surface of diffuse colour ``base (k, 3)`` in [0, 1] sends on, with its specular
    layer's ``share`` (a number or ``(3,)``): ``base + share (1 - base)`` (a black base sends on
    its layer's share alone, as black plastic reflects)."""
    base = np.asarray(base, dtype=np.float64)
    return base + np.asarray(share, dtype=np.float64) * (1.0 - base)
