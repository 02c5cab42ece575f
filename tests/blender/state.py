"""The state of the open file that a cancelled or failed bake must leave as it was."""

import bpy
import numpy as np


def _attribute_bytes(a):
    if a.data_type in {"FLOAT_COLOR", "BYTE_COLOR"}:
        key, width = "color", 4
    elif a.data_type == "FLOAT_VECTOR":
        key, width = "vector", 3
    elif a.data_type in {"FLOAT", "INT", "BOOLEAN"}:
        key, width = "value", 1
    else:
        return None
    dtype = {"INT": np.int32, "BOOLEAN": bool}.get(a.data_type, np.float32)
    data = np.empty(len(a.data) * width, dtype=dtype)
    a.data.foreach_get(key, data)
    return data.tobytes()


def _socket_value(sock):
    value = getattr(sock, "default_value", None)
    try:
        return tuple(value)
    except TypeError:
        return value


def material_state(mat):
    """A material's node tree: every node's name, type, location and input values, and links."""
    if mat.node_tree is None:
        return None
    nodes = sorted(
        (n.name, n.bl_idname, tuple(round(c, 4) for c in n.location), tuple((s.identifier, _socket_value(s)) for s in n.inputs))
        for n in mat.node_tree.nodes
    )
    links = sorted(
        (l.from_node.name, l.from_socket.identifier, l.to_node.name, l.to_socket.identifier) for l in mat.node_tree.links
    )
    return nodes, links


def scene_state():
    """Every mesh attribute (name, type, domain, bytes), each mesh's active and default colour
    attribute, every material's node tree, and the objects' custom properties."""
    state = {}
    for mesh in bpy.data.meshes:
        for a in mesh.attributes:
            state[(mesh.name, a.name)] = (a.data_type, a.domain, _attribute_bytes(a))
        colours = mesh.color_attributes
        state[(mesh.name, "colour attributes")] = (colours.active_color_name, colours.default_color_name)
    for mat in bpy.data.materials:
        state[("material", mat.name)] = material_state(mat)
    # Custom properties; not the storage of registered properties (``Object.cubegi``), which
    # up to 4.5 also appears among them once read (5.0 keeps it apart).
    registered = set(bpy.types.Object.bl_rna.properties.keys())
    for ob in bpy.data.objects:
        state[("object", ob.name)] = sorted(k for k in ob.keys() if k not in registered)
    return state
