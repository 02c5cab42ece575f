"""What a Principled BSDF sends on of the light reaching it: its diffuse base and its
specular layer, as one diffuse reflectance.

Pure numpy; must not import bpy.

CubeGI bakes every surface as diffuse: a point's light is what arrives at it, and what it
sends on is that light times a reflectance. A Principled BSDF (Blender's default material)
is a diffuse base under a dielectric specular layer: the layer reflects some of the light
that reaches it (more at grazing angles, at any Roughness), and the base gets what the layer
lets through. Cycles counts both in every other surface's indirect light. Baked with its
Base Color alone, a dark surface sends on too little (a base colour of 0.05 at Roughness 1
sends on 0.072 in Cycles), and a smooth white one too much (1.0 at Roughness 0 sends on 0.947).

So a Principled BSDF sends on ``base (1 - loss) + gain`` (:func:`sent_on`), ``loss`` and
``gain`` (:func:`layer`) measured in Cycles as a furnace measures them: a closed box of the
material, every surface emitting 1 and reflecting, whose indirect light ``I`` gives the
reflectance ``I / (1 + I)`` under light from every direction, as a room's bounces see it
(bpy 5.3.0, 256 samples, 256 bounces; a Diffuse BSDF gives its colour to 0.2%). For each
Roughness and facing reflectance F0 (IOR 1.5 at Specular IOR Level 0.25, 0.5 and 1: F0 2, 4
and 8%), the reflectance at base 0.05 and 0.95 gives the line; the base colours 0.2, 0.5 and
0.8 lie on it to within 0.006. Between the measured F0 the table is read linearly; above
8%, the 8% row scaled by ``(F0 / 0.08) ** F0_POWER`` (its growth from 4% to 8%). The
layer's light goes on as a diffuse surface's would, not as a mirror's: its energy is right,
its direction is spread.
"""

import numpy as np

__all__ = ["facing_reflectance", "layer", "sent_on", "ROUGHNESS", "F0", "LOSS", "GAIN", "F0_POWER"]

ROUGHNESS = (0.0, 0.25, 0.5, 0.75, 1.0)
F0 = (0.0, 0.02, 0.04, 0.08)
# Per F0 (rows) and Roughness (columns): the share of the base's reflection the layer takes
# away (LOSS), and the share of the light reaching the surface the layer reflects (GAIN).
LOSS = np.array([
    [0.0, 0.0, 0.0, 0.0, 0.0],
    [0.0717, 0.0636, 0.0435, 0.0243, 0.0134],
    [0.0981, 0.0896, 0.0658, 0.0403, 0.0232],
    [0.1395, 0.1308, 0.1044, 0.0692, 0.0422],
])
GAIN = np.array([
    [0.0, 0.0, 0.0, 0.0, 0.0],
    [0.0279, 0.0281, 0.0284, 0.0232, 0.0131],
    [0.0452, 0.0456, 0.0462, 0.0392, 0.0232],
    [0.0760, 0.0765, 0.0779, 0.0684, 0.0423],
])
F0_POWER = 0.8


def facing_reflectance(ior, level) -> float:
    """F0 of a dielectric of index ``ior``, scaled by the Specular IOR Level ``level`` as
    Cycles scales it (0.5: as the IOR gives it; 0: none; 1: twice)."""
    ior = max(float(ior), 1e-6)  # below 1 (a Value node can set it): as Cycles, |ior - 1| / (ior + 1)
    return ((ior - 1.0) / (ior + 1.0)) ** 2 * 2.0 * max(float(level), 0.0)


def layer(f0, roughness) -> tuple:
    """``(loss, gain)`` of a specular layer of facing reflectance ``f0`` (a number, or per
    channel ``(3,)``: the Specular Tint's colour times F0) at ``roughness``: see the module
    docstring. Each in [0, 1], the gain never above the loss where that would make a white
    base send on more than it gets."""
    r = float(np.clip(roughness, 0.0, 1.0))
    loss_at = np.array([np.interp(r, ROUGHNESS, row) for row in LOSS])
    gain_at = np.array([np.interp(r, ROUGHNESS, row) for row in GAIN])
    f0 = np.clip(np.asarray(f0, dtype=np.float64), 0.0, 1.0)
    scale = np.maximum(f0 / F0[-1], 1.0) ** F0_POWER
    within = np.minimum(f0, F0[-1])
    loss = np.clip(np.interp(within, F0, loss_at) * scale, 0.0, 1.0)
    gain = np.minimum(np.interp(within, F0, gain_at) * scale, loss)
    return loss, gain


def sent_on(base, loss, gain) -> np.ndarray:
    """What a surface of diffuse colour ``base (k, 3)`` in [0, 1] sends on under a specular
    layer's ``loss`` and ``gain`` (numbers or ``(3,)``): ``base (1 - loss) + gain`` (a black
    base sends on its layer's gain alone, as black plastic reflects)."""
    base = np.asarray(base, dtype=np.float64)
    return base * (1.0 - np.asarray(loss, dtype=np.float64)) + np.asarray(gain, dtype=np.float64)
