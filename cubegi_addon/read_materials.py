"""A material as CubeGI reads it: per face corner, the albedo and the emission of its surface
shader (Principled BSDF, Diffuse BSDF, Emission), with notes for what it cannot read. A
Principled BSDF's albedo is what it sends on: its Base Color and what its specular layer
reflects (:mod:`~cubegi_engine.specular`).

Part of the scene reader (:mod:`.scene_data`); bulk data through ``foreach_get``.
"""

import numpy as np

from ..cubegi_engine.cubemap import sample_image
from ..cubegi_engine.specular import facing_reflectance, layer, sent_on
from . import attributes

__all__ = ["material_corners", "image_pixels", "socket_strength", "DEFAULT_ALBEDO", "WIRING_NODE"]

# Albedo for a material CubeGI cannot read (no nodes, or a surface shader it does not
# know): the material's viewport display colour; for a face with no material, this grey
# (Blender's default surface).
DEFAULT_ALBEDO = (0.8, 0.8, 0.8)


def _srgb_to_linear(c):
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


_BYTE_TO_LINEAR = _srgb_to_linear(np.arange(256) / 255.0)


def _srgb_bytes_to_linear(px):
    """``_srgb_to_linear`` of pixels, by table where they are bytes (k / 255, as Blender
    hands over an 8-bit image); the same numbers, without a power per channel."""
    k = np.rint(px * np.float32(255.0))
    if np.all(np.abs(px * np.float32(255.0) - k) < 1e-3):
        return _BYTE_TO_LINEAR[np.clip(k, 0, 255).astype(np.uint8)]
    return _srgb_to_linear(px)


def image_pixels(image):
    w, h = image.size
    if w == 0 or h == 0:
        return None
    px = np.empty(w * h * image.channels, dtype=np.float32)
    image.pixels.foreach_get(px)
    px = px.reshape(h, w, image.channels)
    if image.channels < 3:
        px = np.repeat(px[..., :1], 3, axis=2)
    rgb = px[..., :3]
    if not image.is_float and image.colorspace_settings.name == "sRGB":
        return _srgb_bytes_to_linear(rgb)
    return rgb.astype(np.float64)


# The Add Shader that Show in Renders (materials.wire) puts between a material's own shader
# and its output; reading a material looks through it to the material's own shader.
WIRING_NODE = "CubeGI Add"


def _surface_shader(material):
    """The shader node feeding the material's active output (through CubeGI's own wiring),
    or None."""
    if material is None or material.node_tree is None:
        return None
    tree = material.node_tree
    outputs = [n for n in tree.nodes if n.type == "OUTPUT_MATERIAL"]
    if not outputs:
        return None
    active = [n for n in outputs if n.is_active_output] or outputs
    out = next((n for n in active if n.target in {"ALL", "CYCLES"}), active[0])
    surface = out.inputs.get("Surface")
    if surface is None or not surface.is_linked:
        return None
    node = surface.links[0].from_node
    if node.name == WIRING_NODE:
        own = node.inputs[0]
        return own.links[0].from_node if own.is_linked else None
    return node


def _filled(colour, k):
    """``(k, 3)`` rows of one colour (a read-only broadcast: no copy per corner)."""
    return np.broadcast_to(np.asarray(colour, dtype=np.float64), (k, 3))


def _scaled(colours, factor):
    """``colours * factor``, kept a broadcast where it is one (one colour on every corner)."""
    if colours.ndim == 2 and colours.strides[0] == 0:
        return _filled(colours[0] * factor, len(colours))
    return colours * factor


def _corner_colour(socket, mesh, loop_ids, loop_vertex, fallback, problems):
    """Per-corner linear colour ``(k, 3)`` from a colour input socket.

    Understands a plain value, an RGB node, an Image Texture (at the UV map given by a UV
    Map node or the mesh's active render UV map) and a Color Attribute / Attribute node.
    Anything else gives ``fallback``, and why is appended to ``problems``.
    """
    k = len(loop_ids)
    if socket is None:
        return _filled(fallback, k)
    if not socket.is_linked:
        return _filled(np.asarray(socket.default_value[:3], dtype=np.float64), k)
    node = socket.links[0].from_node
    if node.type == "RGB":
        return _filled(np.asarray(node.outputs[0].default_value[:3], dtype=np.float64), k)
    if node.type == "TEX_IMAGE" and node.image is not None:
        rgb = image_pixels(node.image)
        uv_layer, mapped = None, None
        vec = node.inputs.get("Vector")
        if vec is not None and vec.is_linked:
            link = vec.links[0]
            if link.from_node.type == "UVMAP":
                uv_layer = mesh.uv_layers.get(link.from_node.uv_map)
            elif not (link.from_node.type == "TEX_COORD" and link.from_socket.name == "UV"):
                mapped = f"{link.from_socket.name} output of a {link.from_node.bl_label} node"
        if uv_layer is None:
            uv_layer = next((u for u in mesh.uv_layers if u.active_render), None)
        if rgb is None:
            problems.append(f"image {node.image.name!r} has no pixels (missing file?)")
            return _filled(fallback, k)
        if uv_layer is None:  # Cycles reads a UV map the mesh lacks as (0, 0): one colour
            problems.append((f"image {node.image.name!r} is on mesh {mesh.name!r}, which has no UV map",
                             "read at UV (0, 0) as Cycles reads it: one colour for the whole surface"))
            return _filled(sample_image(rgb, np.zeros((1, 2)))[0], k)
        if mapped:  # (what is wrong, what the bake does instead)
            problems.append((f"image {node.image.name!r} is mapped by the {mapped}, which CubeGI does not read",
                             f"sampled at the UV map {uv_layer.name!r} instead"))
        uv = np.empty(len(mesh.loops) * 2, dtype=np.float32)
        uv_layer.data.foreach_get("uv", uv)
        return sample_image(rgb, uv.reshape(-1, 2)[loop_ids].astype(np.float64))
    if node.type in {"VERTEX_COLOR", "ATTRIBUTE"}:
        name = node.layer_name if node.type == "VERTEX_COLOR" else node.attribute_name
        # A Color Attribute node with no name reads the render colour attribute (the one
        # marked for renders), not the active one (which a bake's display changes).
        colours = mesh.color_attributes
        attr = colours.get(name) if name else colours.get(colours.default_color_name)
        if attr is not None and not name and attributes.is_any(attr.name):
            problems.append(f"reads the render colour attribute of mesh {mesh.name!r}, which is CubeGI's own light "
                            f"({attr.name!r}); mark one of your own for renders")
            return _filled(fallback, k)
        if attr is None:
            problems.append(f"colour attribute {name!r} not on mesh {mesh.name!r}")
            return _filled(fallback, k)
        data = np.empty(len(attr.data) * 4, dtype=np.float32)
        attr.data.foreach_get("color", data)
        data = data.reshape(-1, 4)[:, :3].astype(np.float64)
        return data[loop_ids] if attr.domain == "CORNER" else data[loop_vertex[loop_ids]]
    problems.append(f"fed by a {node.bl_label or node.type} node, which CubeGI does not read" if node.type != "TEX_IMAGE"
                    else "an Image Texture with no image")
    return _filled(fallback, k)


def socket_strength(socket, problems):
    """A strength input's value: its own, or a Value node's; else its own and a problem."""
    if not socket.is_linked:
        return float(socket.default_value)
    node = socket.links[0].from_node
    if node.type == "VALUE":
        return float(node.outputs[0].default_value)
    problems.append(f"fed by a {node.bl_label or node.type} node, which CubeGI does not read")
    return float(socket.default_value)


def _colour_and_notes(material, label, socket, mesh, loop_ids, loop_vertex, fallback, what, notes):
    problems = []
    colour = _corner_colour(socket, mesh, loop_ids, loop_vertex, fallback, problems)
    for p in problems:
        problem, instead = p if isinstance(p, tuple) else (p, f"using {what}")
        notes.append(f"material {material.name!r}: {label} {problem}; {instead}")
    return colour


# Shaders that reflect light without diffusing it: baked as a diffuse reflection of their
# Color (the light they send on stays in the scene, though spread evenly, not as a mirror's).
GLOSSY_SHADERS = {"BSDF_GLOSSY", "BSDF_ANISOTROPIC", "BSDF_SHEEN"}
# Principled BSDF inputs CubeGI's diffuse model leaves out: above these it says so.
NOT_DIFFUSE = (("Metallic", "metallic"), ("Transmission Weight", "transmissive"), ("Subsurface Weight", "subsurface-scattering"))


def material_corners(material, mesh, loop_ids, loop_vertex, notes):
    """Albedo, emission and what the surface sends on (:attr:`SceneArrays.reflectance`),
    ``(k, 3)`` each, for the corners ``loop_ids`` of one material."""
    k = len(loop_ids)
    if material is None:
        return _diffuse(_filled(DEFAULT_ALBEDO, k))
    fallback = np.asarray(material.diffuse_color[:3], dtype=np.float64)
    shader = _surface_shader(material)
    if shader is None:
        notes.append(f"material {material.name!r}: no node surface, using its viewport colour")
        return _diffuse(_filled(fallback, k))
    return _shader_corners(material, shader, (mesh, loop_ids, loop_vertex), fallback, notes)


def _diffuse(albedo):
    """A diffuse surface's ``(albedo, emission, sent on)``: no emission, and it sends on its
    albedo."""
    return albedo, _filled(0.0, len(albedo)), albedo


def _specular_layer(material, ins, notes):
    """A Principled BSDF's specular layer's ``(loss, gain)`` (:mod:`~cubegi_engine.specular`), from
    its Roughness, IOR, Specular IOR Level and Specular Tint (a linked one: its own value, and
    a note)."""
    values = {}
    for name, default in (("Roughness", 0.5), ("IOR", 1.5), ("Specular IOR Level", 0.5)):
        sock = ins.get(name)
        problems = []
        values[name] = socket_strength(sock, problems) if sock is not None else default
        notes += [f"material {material.name!r}: {name} {p}; using {values[name]:g}" for p in problems]
    tint = ins.get("Specular Tint")
    colour = np.ones(3)
    if tint is not None and tint.type == "RGBA":
        colour = np.asarray(tint.default_value[:3], dtype=np.float64)
        if tint.is_linked:
            notes.append(f"material {material.name!r}: Specular Tint is fed by a node, which CubeGI does not read; "
                         "using its own colour")
    f0 = facing_reflectance(values["IOR"], values["Specular IOR Level"]) * colour
    loss, gain = layer(f0, values["Roughness"])
    # A metallic or transmissive share has no dielectric layer over a diffuse base (it is baked
    # as diffuse, with a note): the layer weighs what is left.
    weight = 1.0
    for name in ("Metallic", "Transmission Weight"):
        sock = ins.get(name)
        if sock is not None and not sock.is_linked:
            weight *= 1.0 - float(np.clip(sock.default_value, 0.0, 1.0))
    return loss * weight, gain * weight


# Shaders inside Mix and Add Shader nodes are read to this depth.
MAX_SHADER_DEPTH = 16


def _linked_shader(socket):
    return socket.links[0].from_node if socket.is_linked else None


def _shader_corners(material, shader, args, fallback, notes, depth=0):
    """Albedo, emission and what is sent on, ``(k, 3)`` each, of one shader node (Mix and Add
    Shader: of what they mix or add; Cycles mixes and adds their closures, and diffuse light
    is linear in them)."""
    k = len(args[1])
    zeros = _filled(0.0, k)
    if shader is None:  # an unlinked shader socket: no closure, nothing reflected or emitted
        return zeros, zeros, zeros
    if shader.type in {"MIX_SHADER", "ADD_SHADER"} and depth < MAX_SHADER_DEPTH:
        sockets = [s for s in shader.inputs if s.type == "SHADER"]
        a = _shader_corners(material, _linked_shader(sockets[0]), args, fallback, notes, depth + 1)
        b = _shader_corners(material, _linked_shader(sockets[1]), args, fallback, notes, depth + 1)
        if shader.type == "ADD_SHADER":
            return tuple(x + y for x, y in zip(a, b))
        problems = []
        f = float(np.clip(socket_strength(shader.inputs["Fac"], problems), 0.0, 1.0))
        notes += [f"material {material.name!r}: a Mix Shader's Factor {p}; using {f:g}" for p in problems]
        return tuple((1.0 - f) * x + f * y for x, y in zip(a, b))
    if shader.type == "BSDF_PRINCIPLED":
        ins = shader.inputs
        albedo = _colour_and_notes(material, "Base Color", ins["Base Color"], *args, fallback, "its viewport colour", notes)
        problems = []
        strength = socket_strength(ins["Emission Strength"], problems)
        notes += [f"material {material.name!r}: Emission Strength {p}; using {strength:g}" for p in problems]
        emission = _colour_and_notes(material, "Emission Color", ins["Emission Color"], *args, np.zeros(3), "no emission", notes)
        alpha = ins.get("Alpha")
        if alpha is not None and (alpha.is_linked or float(alpha.default_value) < 1.0):
            notes.append(f"material {material.name!r}: Alpha is not read; baked as an opaque surface, which blocks "
                         "light and casts shadow")
        for name, adjective in NOT_DIFFUSE:
            sock = ins.get(name)
            if sock is not None and (sock.is_linked or float(sock.default_value) > 0.0):
                notes.append(f"material {material.name!r}: {name} is set; CubeGI bakes it as a diffuse surface, "
                             f"which a {adjective} surface is not")
        loss, gain = _specular_layer(material, ins, notes)
        if albedo.strides[0] == 0:  # one colour: kept a broadcast
            return albedo, _scaled(emission, strength), _filled(sent_on(np.clip(albedo[0], 0.0, 1.0), loss, gain), k)
        return albedo, _scaled(emission, strength), sent_on(np.clip(albedo, 0.0, 1.0), loss, gain)
    if shader.type == "BSDF_DIFFUSE":
        return _diffuse(_colour_and_notes(material, "Color", shader.inputs["Color"], *args, fallback, "its viewport colour", notes))
    if shader.type == "EMISSION":
        problems = []
        strength = socket_strength(shader.inputs["Strength"], problems)
        notes += [f"material {material.name!r}: Strength {p}; using {strength:g}" for p in problems]
        emission = _scaled(_colour_and_notes(material, "Color", shader.inputs["Color"], *args, np.ones(3), "white", notes), strength)
        return zeros, emission, zeros
    if shader.type in GLOSSY_SHADERS and "Color" in shader.inputs:
        notes.append(f"material {material.name!r}: its {shader.bl_label} shader is baked as a diffuse reflection of its "
                     "Color (Cycles reflects that light as a mirror or a sheen would)")
        return _diffuse(_colour_and_notes(material, "Color", shader.inputs["Color"], *args, fallback, "its viewport colour", notes))
    if shader.type == "GROUP":
        notes.append(f"material {material.name!r}: its surface is a node group, which CubeGI does not read; baked with "
                     "its viewport colour and no emission (any light it emits is lost)")
    else:
        notes.append(f"material {material.name!r}: shader {shader.bl_idname} not understood, using its viewport colour")
    return _diffuse(_filled(fallback, k))


# Shaders with no diffuse closure: Cycles' Diffuse bake gives their surfaces no light.
NO_DIFFUSE_SHADERS = {"BSDF_GLASS", "BSDF_REFRACTION", "BSDF_GLOSSY", "BSDF_ANISOTROPIC", "BSDF_TRANSPARENT", "EMISSION",
                      "HOLDOUT", "BSDF_METALLIC"}


def no_diffuse(material, shader=None, depth=0) -> bool:
    """Whether ``material``'s surface has no diffuse closure for Cycles: a glass, glossy,
    refraction, transparent, metallic or emission shader alone, a Principled BSDF at Metallic
    or Transmission Weight 1, a Mix or Add Shader of two such (what CubeGI still bakes as
    diffuse, with a note, but Cycles' Diffuse bake gives no light)."""
    shader = _surface_shader(material) if shader is None else shader
    if shader is None or depth > MAX_SHADER_DEPTH:
        return False
    if shader.type in NO_DIFFUSE_SHADERS:
        return True
    if shader.type == "BSDF_PRINCIPLED":
        ins = shader.inputs
        return any(ins.get(k) is not None and not ins[k].is_linked and float(ins[k].default_value) >= 1.0
                   for k in ("Metallic", "Transmission Weight"))
    if shader.type in {"MIX_SHADER", "ADD_SHADER"}:
        sides = [_linked_shader(i) for i in shader.inputs if i.type == "SHADER"]
        return all(side is not None and no_diffuse(material, side, depth + 1) for side in sides) and bool(sides)
    return False


def no_diffuse_vertices(ob) -> np.ndarray:
    """``(v,)`` bool: the vertices of mesh object ``ob`` whose every face has a material with
    no diffuse closure (:func:`no_diffuse`)."""
    mesh = ob.data
    flags = np.array([no_diffuse(slot.material) for slot in ob.material_slots] or [False])
    if not flags.any() or not len(mesh.polygons):
        return np.zeros(len(mesh.vertices), dtype=bool)
    index, total = np.empty(len(mesh.polygons), dtype=np.int32), np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("material_index", index)
    mesh.polygons.foreach_get("loop_total", total)
    vertex = np.empty(len(mesh.loops), dtype=np.int32)
    mesh.loops.foreach_get("vertex_index", vertex)
    none = np.repeat(flags[np.clip(index, 0, len(flags) - 1)], total)
    count = np.bincount(vertex, minlength=len(mesh.vertices))
    return (count > 0) & (np.bincount(vertex, none, minlength=len(mesh.vertices)) == count)
