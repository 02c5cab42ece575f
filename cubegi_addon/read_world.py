"""The world as CubeGI reads it: the Background's mean radiance and, for an equirectangular
environment image, its pattern over the sphere.

Part of the scene reader (:mod:`.scene_data`).
"""

import numpy as np

from .read_materials import image_pixels, socket_strength

__all__ = ["world_sky", "SKY_MAP_WIDTH"]


def world_sky(scene, notes):
    """The world's Background: ``(mean radiance (3,), pattern or None)``.

    A colour input fed by an Environment Texture with an image gives its mean over the
    sphere (each pixel weighted by its solid angle) and its pattern (the image over that
    mean, reduced to at most SKY_MAP_WIDTH pixels across): the probes see the sky's
    directions. Fed by anything else (a Sky Texture, a gradient, ...) the world's viewport
    colour stands in as a uniform sky, with a note.
    """
    pattern = []
    colour = _world_colour(scene, notes, pattern)
    return colour, (pattern[0] if pattern else None)


def _world_colour(scene, notes, pattern):
    world = scene.world
    if world is None:
        return np.zeros(3)
    visibility = getattr(world, "cycles_visibility", None)
    if visibility is not None and not visibility.diffuse:  # Cycles' diffuse rays do not see it: it lights no surface
        return np.zeros(3)
    tree = world.node_tree
    if tree is not None:
        out = next((n for n in tree.nodes if n.type == "OUTPUT_WORLD" and n.is_active_output), None)
        out = out or next((n for n in tree.nodes if n.type == "OUTPUT_WORLD"), None)
        if out is not None:
            surface = out.inputs.get("Surface")
            if surface is None or not surface.is_linked:
                return np.zeros(3)
            node = surface.links[0].from_node
            if node.type == "BACKGROUND":
                problems = []
                strength = socket_strength(node.inputs["Strength"], problems)
                notes.extend(f"world {world.name!r}: Background Strength {p}; using {strength:g}" for p in problems)
                return _background_colour(world, node.inputs["Color"], notes, pattern) * strength
            notes.append(f"world {world.name!r}: its surface is a {node.bl_label} node, not a Background; using its viewport colour")
    return np.asarray(world.color[:3], dtype=np.float64)


# An environment image is reduced to at most this many pixels across (box filter) before
# the probes' texels look it up: 9 SH coefficients keep only its broad directions.
SKY_MAP_WIDTH = 128


def _background_colour(world, socket, notes, pattern):
    if not socket.is_linked:
        return np.asarray(socket.default_value[:3], dtype=np.float64)
    node = socket.links[0].from_node
    if node.type == "RGB":  # a Color node: its colour, as a material's Base Color reads it
        return np.asarray(node.outputs[0].default_value[:3], dtype=np.float64)
    if node.type == "TEX_ENVIRONMENT" and node.image is not None:
        rgb = image_pixels(node.image)
        if rgb is not None:
            bad = ~np.isfinite(rgb).all(axis=2)
            if bad.any():
                notes.append(f"world {world.name!r}: the environment image {node.image.name!r} has {int(bad.sum())} pixels "
                             "that are NaN or infinite; they count as black")
                rgb = np.where(bad[..., None], 0.0, rgb)
            rgb = _box_reduce(np.maximum(rgb, 0.0), SKY_MAP_WIDTH)
            h = rgb.shape[0]
            # Equirectangular rows: solid angle proportional to sin(polar angle) at the row centre.
            weight = np.sin(np.pi * (np.arange(h) + 0.5) / h)[:, None]
            mean = (rgb * weight[:, :, None]).sum(axis=(0, 1)) / (weight.sum() * rgb.shape[1])
            if node.projection == "EQUIRECTANGULAR" and not _mapped(node):
                pattern.append((rgb / np.where(mean > 0, mean, 1.0)).astype(np.float32))
            else:
                notes.append(f"world {world.name!r}: the environment image {node.image.name!r} is mapped (a Mapping node or "
                             "a mirror ball); CubeGI averages it to a uniform sky")
            return mean
    notes.append(
        f"world {world.name!r}: Background Color fed by a {node.bl_label} node, which CubeGI does not read; "
        f"using the world's viewport colour {tuple(round(c, 3) for c in world.color[:3])}"
    )
    return np.asarray(world.color[:3], dtype=np.float64)


def _box_reduce(rgb, width):
    """``rgb (h, w, 3)`` averaged over blocks so that it is at most ``width`` pixels across."""
    h, w, _ = rgb.shape
    f = max(1, -(-w // width))
    if f == 1:
        return rgb
    h2, w2 = max(1, h // f), w // f
    return rgb[: h2 * f, : w2 * f].reshape(h2, f, w2, f, 3).mean(axis=(1, 3))


def _mapped(node):
    """Whether an Environment Texture's vector input is driven (rotated, scaled)."""
    vector = node.inputs.get("Vector")
    return vector is not None and vector.is_linked
