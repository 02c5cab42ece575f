"""Lights as CubeGI reads them: each light object (and each instance of one) as an engine
:class:`~cubegi_engine.lights.Light` with its identity, power and colour as Cycles reads
them (Exposure, Temperature, Normalize, the node tree), and notes for what it cannot read.

Part of the scene reader (:mod:`.scene_data`).
"""

import numpy as np

from ..cubegi_engine.blackbody import ACCURATE_FROM as BLACKBODY_ACCURATE_FROM
from ..cubegi_engine.blackbody import blackbody_rgb
from ..cubegi_engine.lights import Light, area_polygon, area_samples
from . import compat

__all__ = ["add_light", "light_key", "AREA_SHADOW_SIDE"]

# Shadow maps per area light: a stratified AREA_SHADOW_SIDE x AREA_SHADOW_SIDE set of points.
# Measured against Cycles on the Cornell box's area lights (direct light, rel. RMSE): 4 x 4
# 3.3-4.5%, 8 x 8 1.6-2.2% (0.1 s more there), 12 x 12 1.2-1.7% (0.3 s more).
AREA_SHADOW_SIDE = 8


def _light(ob_eval, matrix, key, notes):
    data = ob_eval.data
    m = np.array(matrix, dtype=np.float64)
    pos = m[:3, 3].copy()
    direction = -m[:3, 2]
    direction = direction / max(np.linalg.norm(direction), 1e-300)
    # Exposure scales the power by 2^exposure, as Cycles does for every light type.
    colour = np.asarray(data.color[:3], dtype=np.float64) * float(data.energy) * 2.0 ** float(getattr(data, "exposure", 0.0))
    colour = colour * _light_node_factor(ob_eval.name, data, notes)
    if getattr(data, "use_temperature", False):  # Blender 4.5 and later
        colour = colour * blackbody_rgb(data.temperature)
        _note_approximate_temperature(ob_eval.name, data.temperature, notes)
    _note_unread_light_options(ob_eval, data, notes)
    own = getattr(data.original, "cubegi", None)
    common = dict(colour=colour, position=pos, direction=direction, casts_shadow=bool(data.use_shadow), name=ob_eval.name,
                  key=key, shadow_size=int(own.shadow_size) if own is not None else 0,
                  group=str(getattr(ob_eval, "lightgroup", "") or ""))
    if data.type == "POINT":
        return Light("POINT", radius=float(data.shadow_soft_size), **common)
    if data.type == "SPOT":
        return Light("SPOT", radius=float(data.shadow_soft_size), spot_size=float(data.spot_size), spot_blend=float(data.spot_blend), **common)
    if data.type == "SUN":
        return Light("SUN", angle=float(getattr(data, "angle", 0.0)), **common)
    if data.type == "AREA":
        local = area_polygon(data.shape, data.size, data.size_y)
        poly = local @ m[:3, :3].T + pos
        e = np.cross(np.roll(poly, -1, axis=0) - poly[0], poly - poly[0])
        area = 0.5 * float(np.linalg.norm(e.sum(axis=0)))
        samples = area_samples(data.shape, data.size, data.size_y, AREA_SHADOW_SIDE) @ m[:3, :3].T + pos
        if not getattr(data, "normalize", True):
            # Not normalised to its size: its Power is per square metre of its (world) area.
            common["colour"] = common["colour"] * area
        return Light("AREA", polygon=poly, area=area, samples=samples, **common)
    return None


def _light_node_factor(name, data, notes):
    """What a light's node tree multiplies its power and colour by ``(3,)``: an Emission
    node's Color x Strength into the Light Output (ones without nodes), each a constant or
    what Blackbody, RGB, Value and Math nodes make of constants (:func:`_constant`). A tree
    CubeGI cannot read gets a note and ones."""
    tree = compat.light_node_tree(data)
    if tree is None:
        return np.ones(3)
    out = next((n for n in tree.nodes if n.type == "OUTPUT_LIGHT" and n.is_active_output), None)
    out = out or next((n for n in tree.nodes if n.type == "OUTPUT_LIGHT"), None)
    surface = out.inputs.get("Surface") if out is not None else None
    if surface is None or not surface.is_linked:
        return np.ones(3)  # Cycles' default emission
    node = surface.links[0].from_node
    colour, strength = (node.inputs.get(k) for k in ("Color", "Strength")) if node.type == "EMISSION" else (None, None)
    colour, strength = (None if k is None else _constant(k, name, notes) for k in (colour, strength))
    if colour is None or strength is None or np.ndim(strength):
        what = "its Emission node's inputs are linked to nodes it does not read" if node.type == "EMISSION" else (
            f"its output is a {node.bl_label} node")
        notes.append(f"light {name}: its node tree is not read ({what}); baked with its Power and Color alone")
        return np.ones(3)
    return np.broadcast_to(np.asarray(colour, dtype=np.float64), (3,)) * float(strength)


_MATH = {"ADD": np.add, "SUBTRACT": np.subtract, "MULTIPLY": np.multiply, "DIVIDE": lambda a, b: a / b if b else 0.0,
         "POWER": np.power, "MINIMUM": np.minimum, "MAXIMUM": np.maximum}


def _constant(socket, name, notes, depth=0):
    """The constant a light's node input holds: ``(3,)`` for a colour, a float for a value,
    or None where it is linked to a node other than Blackbody, RGB, Value or a Math node of
    ADD, SUBTRACT, MULTIPLY, DIVIDE, POWER, MINIMUM or MAXIMUM over constants (as Cycles
    evaluates them: a Blackbody node as the light's own Temperature does)."""
    if not socket.is_linked:
        value = socket.default_value
        return float(value) if np.ndim(value) == 0 else np.asarray(value[:3], dtype=np.float64)
    node = socket.links[0].from_node
    if depth > 16:
        return None
    if node.type == "REROUTE":
        return _constant(node.inputs[0], name, notes, depth + 1)
    if node.type in ("RGB", "VALUE"):
        value = node.outputs[0].default_value
        return float(value) if np.ndim(value) == 0 else np.asarray(value[:3], dtype=np.float64)
    if node.type == "BLACKBODY":
        kelvin = _constant(node.inputs["Temperature"], name, notes, depth + 1)
        if kelvin is None or np.ndim(kelvin):
            return None
        _note_approximate_temperature(name, kelvin, notes)
        return blackbody_rgb(kelvin)
    if node.type == "MATH" and node.operation in _MATH:
        a, b = (_constant(node.inputs[k], name, notes, depth + 1) for k in (0, 1))
        if a is None or b is None or np.ndim(a) or np.ndim(b):
            return None
        value = float(_MATH[node.operation](a, b))
        return float(np.clip(value, 0.0, 1.0)) if node.use_clamp else value
    return None


def _note_approximate_temperature(name, kelvin, notes):
    if kelvin < BLACKBODY_ACCURATE_FROM:
        notes.append(f"light {name}: its Temperature ({kelvin:g} K) is approximated; below "
                     f"{BLACKBODY_ACCURATE_FROM:g} K its colour drifts from Cycles' (too much green: 3x at 1000 K)")


def _note_unread_light_options(ob, data, notes):
    """Notes for the light options that change Cycles' light and that CubeGI does not read."""
    if data.type == "AREA" and float(getattr(data, "spread", np.pi)) < np.pi - 1e-6:
        notes.append(f"light {ob.name}: Spread ({np.degrees(data.spread):.0f} degrees) is not read; baked as a "
                     "diffuse (180 degree) area light")
    linking = getattr(ob.original, "light_linking", None)
    if linking is not None and (linking.receiver_collection is not None or linking.blocker_collection is not None):
        notes.append(f"light {ob.name}: light and shadow linking are not read; it lights, and is shadowed by, "
                     "every object")


def _light_problem(light):
    """Why a light cannot be baked (None if it can): a NaN or Inf anywhere in it (one such
    light would darken every point), or negative power (CubeGI bakes no negative light)."""
    values = [light.colour, light.position, light.direction, [light.radius, light.area, light.angle]]
    if light.polygon is not None:
        values.append(np.ravel(light.polygon))
    if not all(np.all(np.isfinite(np.asarray(v, dtype=np.float64))) for v in values):
        return "NaN or Inf in its location, rotation, size or power"
    if np.any(light.colour < 0):
        return "negative power or colour"
    return None



def light_key(inst):
    """A light's identity for as long as the file is open: its object's ``session_uid``
    (names change and can be shared), and for an instance also the instancing object's and
    the instance's place in it (``persistent_id``): a lamp collection instanced four times
    is four lights."""
    key = f"light:{inst.object.original.session_uid}"
    if inst.is_instance and inst.parent is not None:
        path = ".".join(str(i) for i in inst.persistent_id)
        key += f"@{inst.parent.original.session_uid}:{path}"
    return key


def add_light(inst, ob, lights, notes):
    if not ob.original.visible_diffuse:
        notes.append(f"light {ob.name}: its Diffuse ray visibility is off, so it lights no diffuse surface; left out")
        return
    light = _light(ob, inst.matrix_world, light_key(inst), notes)
    problem = _light_problem(light) if light is not None else None
    if problem:
        notes.append(f"light {ob.name}: {problem}; skipped")
    elif light is not None:
        lights.append(light)
