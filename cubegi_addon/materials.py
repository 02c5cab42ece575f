"""Show the baked light in renders: wire it into materials, and take the wiring out again.

Wiring adds four nodes to a material and changes one link, nothing else:

    Attribute "CubeGI" (indirect light) x base colour -> Emission -> Add Shader <- the shader
                                                                   |
                                                            Material Output

The Add Shader sums the material's own shader (lit by the render engine's lights: the
direct light) and the baked indirect light as emission (``albedo x light``: the light a
diffuse surface sends on). The base colour is what feeds the shader's Base Color (or
Color) input: the same texture or value. With no such input the documented fallback
albedo of :mod:`.scene_data` is used. Unwiring removes the nodes (named ``CubeGI ...``)
and puts the shader's link back. For Cycles, set the render's diffuse bounces to 0 so the
indirect light is not counted twice.
"""

import bpy

from ..cubegi_engine.errors import BakeError
from . import attributes
from .read_materials import DEFAULT_ALBEDO, WIRING_NODE

PREFIX = "CubeGI "
ATTRIBUTE, MULTIPLY, EMISSION = (PREFIX + n for n in ("Light", "Albedo x Light", "Emission"))
ADD = WIRING_NODE  # "CubeGI Add": a bake reads the material through it
# Inputs that hold a shader's diffuse colour, in the order they are looked for.
COLOUR_INPUTS = ("Base Color", "Color")


def is_wired(material):
    return material.node_tree is not None and ADD in material.node_tree.nodes


def _output(tree):
    outputs = [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"]
    active = [n for n in outputs if n.is_active_output]
    return (active or outputs or [None])[0]


def wirable(material):
    """None if ``material`` can be wired, else why not (one line)."""
    if material.library is not None:
        return f"material {material.name!r} is linked from a library"
    if material.node_tree is None:
        return f"material {material.name!r} has no nodes"
    if _output(material.node_tree) is None:
        return f"material {material.name!r} has no Material Output node"
    return None


def wire(material, layer=attributes.INDIRECT):
    """Add the baked light ``layer`` to ``material``'s surface (see the module docstring)."""
    if is_wired(material):
        return False
    problem = wirable(material)
    if problem:
        raise BakeError(problem)
    tree = material.node_tree
    nodes, links = tree.nodes, tree.links
    out = _output(tree)
    surface = out.inputs["Surface"]
    shader_link = surface.links[0] if surface.is_linked else None
    x, y = out.location

    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_type = "GEOMETRY"
    attr.attribute_name = layer
    mul = nodes.new("ShaderNodeMix")
    mul.data_type = "RGBA"
    mul.blend_type = "MULTIPLY"
    mul.inputs["Factor"].default_value = 1.0
    emission = nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 1.0
    add = nodes.new("ShaderNodeAddShader")
    for node, name, dx, dy in ((attr, ATTRIBUTE, -600, -300), (mul, MULTIPLY, -400, -300), (emission, EMISSION, -200, -300), (add, ADD, 0, -150)):
        node.name = node.label = name
        node.location = (x + dx, y + dy)
    out.location = (x + 200, y)

    colour = _base_colour(shader_link.from_node if shader_link else None)
    if isinstance(colour, bpy.types.NodeSocket):
        links.new(colour, mul.inputs["A"])
    else:
        mul.inputs["A"].default_value = colour
    links.new(attr.outputs["Color"], mul.inputs["B"])
    links.new(mul.outputs["Result"], emission.inputs["Color"])
    if shader_link is not None:
        links.new(shader_link.from_socket, add.inputs[0])
    links.new(emission.outputs["Emission"], add.inputs[1])
    links.new(add.outputs["Shader"], surface)
    return True


def _base_colour(shader):
    """The socket feeding the shader's colour input, or that input's value (RGBA)."""
    if shader is not None:
        for name in COLOUR_INPUTS:
            sock = shader.inputs.get(name)
            if sock is not None and sock.type == "RGBA":
                return sock.links[0].from_socket if sock.is_linked else tuple(sock.default_value)
    return tuple(DEFAULT_ALBEDO) + (1.0,)


def unwire(material):
    """Remove the wiring :func:`wire` added; returns whether there was any."""
    if not is_wired(material):
        return False
    tree = material.node_tree
    nodes, links = tree.nodes, tree.links
    add = nodes[ADD]
    source = add.inputs[0].links[0].from_socket if add.inputs[0].is_linked else None
    targets = [link.to_socket for link in add.outputs["Shader"].links]
    for name in (ATTRIBUTE, MULTIPLY, EMISSION, ADD):
        if name in nodes:
            nodes.remove(nodes[name])
    out = _output(tree)
    if out is not None:
        out.location = (out.location[0] - 200, out.location[1])
    for socket in targets:
        if source is not None:
            links.new(source, socket)
    return True


def scene_materials(scene):
    """The distinct materials on the scene's mesh objects' slots."""
    found = {}
    for ob in scene.objects:
        if ob.type == "MESH":
            for slot in ob.material_slots:
                if slot.material is not None:
                    found.setdefault(slot.material.name_full, slot.material)
    return list(found.values())
