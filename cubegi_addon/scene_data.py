"""Blender scene to CubeGI arrays: evaluated meshes, materials, lights, world.

The only module that reads the scene's data for a bake. Bulk data moves with
``foreach_get`` into numpy arrays; nothing loops over vertices in Python.

Shading points: CubeGI computes light at one point per distinct (vertex, corner normal,
material) of each mesh, so a flat-shaded corner gets the light of each of its faces (as a
Cycles bake of the face corners does); a vertex's value is the mean over its corners.
"""

from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from ..cubegi_engine.blackbody import ACCURATE_FROM as BLACKBODY_ACCURATE_FROM
from ..cubegi_engine.blackbody import blackbody_rgb
from ..cubegi_engine.cubemap import sample_image
from ..cubegi_engine.errors import BakeError
from ..cubegi_engine.lights import Light, area_polygon, area_samples
from ..cubegi_engine.scene import SceneArrays
from . import attributes, compat

# Albedo for a material CubeGI cannot read (no nodes, or a surface shader it does not
# know): the material's viewport display colour; for a face with no material, this grey
# (Blender's default surface).
DEFAULT_ALBEDO = (0.8, 0.8, 0.8)
# Shadow maps per area light: a stratified AREA_SHADOW_SIDE x AREA_SHADOW_SIDE set of points.
# Measured against Cycles on the Cornell box's area lights (direct light, rel. RMSE): 4 x 4
# 3.3-4.5%, 8 x 8 1.6-2.2% (0.1 s more there), 12 x 12 1.2-1.7% (0.3 s more).
AREA_SHADOW_SIDE = 8


@dataclass
class MeshTarget:
    """Where one object's baked light goes: its original mesh, and how its corners map.

    loop_point: ``(corners,)`` global shading-point index of each corner; loop_vertex:
    ``(corners,)`` the corner's vertex; vertex_count: vertices in the mesh.
    """

    object_name: str
    mesh_name: str
    loop_point: np.ndarray
    loop_vertex: np.ndarray
    vertex_count: int


@dataclass
class CollectedScene:
    arrays: SceneArrays
    targets: list
    notes: list = field(default_factory=list)
    moving: list = field(default_factory=list)  # (SceneArrays of one dynamic object, MeshTarget)


def _render_visible_objects(view_layer):
    """Names of objects in at least one collection that is neither excluded nor hidden
    from render in this view layer."""
    visible = set()

    def walk(layer_coll, parent_hidden):
        hidden = parent_hidden or layer_coll.exclude or layer_coll.collection.hide_render
        if not hidden:
            visible.update(o.name for o in layer_coll.collection.objects)
        for child in layer_coll.children:
            walk(child, hidden)

    walk(view_layer.layer_collection, False)
    return visible


def _srgb_to_linear(c):
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _image_pixels(image):
    w, h = image.size
    if w == 0 or h == 0:
        return None
    px = np.empty(w * h * image.channels, dtype=np.float32)
    image.pixels.foreach_get(px)
    px = px.reshape(h, w, image.channels)
    if image.channels < 3:
        px = np.repeat(px[..., :1], 3, axis=2)
    rgb = px[..., :3].astype(np.float64)
    if not image.is_float and image.colorspace_settings.name == "sRGB":
        rgb = _srgb_to_linear(rgb)
    return rgb


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


def _corner_colour(socket, mesh, loop_ids, loop_vertex, fallback, problems):
    """Per-corner linear colour ``(k, 3)`` from a colour input socket.

    Understands a plain value, an RGB node, an Image Texture (at the UV map given by a UV
    Map node or the mesh's active render UV map) and a Color Attribute / Attribute node.
    Anything else gives ``fallback``, and why is appended to ``problems``.
    """
    k = len(loop_ids)
    if socket is None:
        return np.tile(fallback, (k, 1))
    if not socket.is_linked:
        return np.tile(np.asarray(socket.default_value[:3], dtype=np.float64), (k, 1))
    node = socket.links[0].from_node
    if node.type == "RGB":
        return np.tile(np.asarray(node.outputs[0].default_value[:3], dtype=np.float64), (k, 1))
    if node.type == "TEX_IMAGE" and node.image is not None:
        rgb = _image_pixels(node.image)
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
        if rgb is None or uv_layer is None:
            problems.append(f"image {node.image.name!r} has no pixels (missing file?)" if rgb is None else "no UV map for its image")
            return np.tile(fallback, (k, 1))
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
            return np.tile(fallback, (k, 1))
        if attr is None:
            problems.append(f"colour attribute {name!r} not on mesh {mesh.name!r}")
            return np.tile(fallback, (k, 1))
        data = np.empty(len(attr.data) * 4, dtype=np.float32)
        attr.data.foreach_get("color", data)
        data = data.reshape(-1, 4)[:, :3].astype(np.float64)
        return data[loop_ids] if attr.domain == "CORNER" else data[loop_vertex[loop_ids]]
    problems.append(f"fed by a {node.bl_label or node.type} node, which CubeGI does not read" if node.type != "TEX_IMAGE"
                    else "an Image Texture with no image")
    return np.tile(fallback, (k, 1))


def _strength(socket, problems):
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


# Principled BSDF inputs CubeGI's diffuse model leaves out: above these it says so.
NOT_DIFFUSE = (("Metallic", "metallic"), ("Transmission Weight", "transmissive"))


def _material_corners(material, mesh, loop_ids, loop_vertex, notes):
    """Albedo and emission ``(k, 3)`` each for the corners ``loop_ids`` of one material."""
    k = len(loop_ids)
    if material is None:
        return np.tile(DEFAULT_ALBEDO, (k, 1)), np.zeros((k, 3))
    fallback = np.asarray(material.diffuse_color[:3], dtype=np.float64)
    shader = _surface_shader(material)
    if shader is None:
        notes.append(f"material {material.name!r}: no node surface, using its viewport colour")
        return np.tile(fallback, (k, 1)), np.zeros((k, 3))
    args = (mesh, loop_ids, loop_vertex)
    if shader.type == "BSDF_PRINCIPLED":
        ins = shader.inputs
        albedo = _colour_and_notes(material, "Base Color", ins["Base Color"], *args, fallback, "its viewport colour", notes)
        problems = []
        strength = _strength(ins["Emission Strength"], problems)
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
        return albedo, emission * strength
    if shader.type == "BSDF_DIFFUSE":
        return _colour_and_notes(material, "Color", shader.inputs["Color"], *args, fallback, "its viewport colour", notes), np.zeros((k, 3))
    if shader.type == "EMISSION":
        problems = []
        strength = _strength(shader.inputs["Strength"], problems)
        notes += [f"material {material.name!r}: Strength {p}; using {strength:g}" for p in problems]
        emission = _colour_and_notes(material, "Color", shader.inputs["Color"], *args, np.ones(3), "white", notes) * strength
        return np.zeros((k, 3)), emission
    if shader.type == "GROUP":
        notes.append(f"material {material.name!r}: its surface is a node group, which CubeGI does not read; baked with "
                     "its viewport colour and no emission (any light it emits is lost)")
    else:
        notes.append(f"material {material.name!r}: shader {shader.bl_idname} not understood, using its viewport colour")
    return np.tile(fallback, (k, 1)), np.zeros((k, 3))


def _mesh_arrays(ob_eval, matrix, notes):
    """World-space corner data of one evaluated object, or None if it has no triangles."""
    mesh = ob_eval.to_mesh()
    try:
        mesh.calc_loop_triangles()
        t = len(mesh.loop_triangles)
        if t == 0:
            return None
        nv, nl = len(mesh.vertices), len(mesh.loops)
        co = np.empty(nv * 3, dtype=np.float64)
        mesh.vertices.foreach_get("co", co)
        tri_loops = np.empty(t * 3, dtype=np.int64)
        mesh.loop_triangles.foreach_get("loops", tri_loops)
        tri_mat = np.empty(t, dtype=np.int64)
        mesh.loop_triangles.foreach_get("material_index", tri_mat)
        loop_vertex = np.empty(nl, dtype=np.int64)
        mesh.loops.foreach_get("vertex_index", loop_vertex)
        cn = np.empty(nl * 3, dtype=np.float64)
        mesh.corner_normals.foreach_get("vector", cn)

        m = np.array(matrix, dtype=np.float64)
        local_co = co.reshape(-1, 3)
        co = local_co @ m[:3, :3].T + m[:3, 3]
        normal_m = np.linalg.inv(m[:3, :3]).T if abs(np.linalg.det(m[:3, :3])) > 1e-300 else m[:3, :3]
        cn = cn.reshape(-1, 3) @ normal_m.T
        cn /= np.maximum(np.linalg.norm(cn, axis=1, keepdims=True), 1e-300)
        tri_loops = tri_loops.reshape(-1, 3)
        if np.linalg.det(m[:3, :3]) < 0:  # mirrored: keep front faces front
            tri_loops = tri_loops[:, ::-1]

        # Material of each corner (a corner's material is its face's).
        loop_mat = np.zeros(nl, dtype=np.int64)
        loop_mat[tri_loops.ravel()] = np.repeat(tri_mat, 3)
        albedo = np.empty((nl, 3))
        emission = np.empty((nl, 3))
        slots = [s.material for s in ob_eval.material_slots] or [None]
        for mi in np.unique(loop_mat):
            ids = np.nonzero(loop_mat == mi)[0]
            mat = slots[mi] if mi < len(slots) else None
            albedo[ids], emission[ids] = _material_corners(mat, mesh, ids, loop_vertex, notes)
        return {
            "co": co,
            "local_co": local_co,
            "loop_vertex": loop_vertex,
            "corner_normal": cn,
            "tri_loops": tri_loops,
            "loop_mat": loop_mat,
            "albedo": np.clip(albedo, 0.0, 1.0),
            "emission": np.maximum(emission, 0.0),
            "vertex_count": nv,
        }
    finally:
        ob_eval.to_mesh_clear()


def _shading_points(data):
    """Merge corners that share vertex, normal and material into shading points."""
    first, inverse = _groups(data["loop_vertex"], np.round(data["corner_normal"] * 1e4).astype(np.int64), data["loop_mat"])
    count = np.bincount(inverse).astype(np.float64)[:, None]

    def mean(values):
        return np.stack([np.bincount(inverse, values[:, c], minlength=len(first)) for c in range(3)], axis=1) / count

    normals = mean(data["corner_normal"])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    return {
        "points": data["co"][data["loop_vertex"][first]],
        "normals": normals,
        "albedo": mean(data["albedo"]),
        "emission": mean(data["emission"]),
        "triangles": inverse[data["tri_loops"]],
        "loop_point": inverse,
    }


def _groups(vertex, normal, material):
    """``np.unique`` of the rows (vertex, normal x, y, z, material) with ``return_index`` and
    ``return_inverse``, in its order, by one stable sort on three integer keys (the normal's
    components, within +-10,000, packed into one): five times faster than sorting rows."""
    packed = ((normal[:, 0] + 16384) << 30) | ((normal[:, 1] + 16384) << 15) | (normal[:, 2] + 16384)
    order = np.lexsort((material, packed, vertex))
    change = np.zeros(len(order), dtype=bool)  # a group starts where any key changes
    change[:1] = True
    for key in (vertex, packed, material):
        k = key[order]
        change[1:] |= k[1:] != k[:-1]
    inverse = np.empty(len(order), dtype=np.int64)
    inverse[order] = np.cumsum(change) - 1
    return order[change], inverse


def _world_sky(scene, notes):
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
                strength = _strength(node.inputs["Strength"], problems)
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
    if node.type == "TEX_ENVIRONMENT" and node.image is not None:
        rgb = _image_pixels(node.image)
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
        if data.temperature < BLACKBODY_ACCURATE_FROM:
            notes.append(f"light {ob_eval.name}: its Temperature ({data.temperature:g} K) is approximated; below "
                         f"{BLACKBODY_ACCURATE_FROM:g} K its colour drifts from Cycles' (too much green: 3x at 1000 K)")
    _note_unread_light_options(ob_eval, data, notes)
    common = dict(colour=colour, position=pos, direction=direction, casts_shadow=bool(data.use_shadow), name=ob_eval.name,
                  key=key)
    if data.type == "POINT":
        return Light("POINT", radius=float(data.shadow_soft_size), **common)
    if data.type == "SPOT":
        return Light("SPOT", radius=float(data.shadow_soft_size), spot_size=float(data.spot_size), spot_blend=float(data.spot_blend), **common)
    if data.type == "SUN":
        return Light("SUN", **common)
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
    node's Color x Strength into the Light Output (ones without nodes). A tree CubeGI cannot
    read gets a note and ones."""
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
    if colour is None or strength is None or colour.is_linked or strength.is_linked:
        what = "its Emission node's inputs are linked" if node.type == "EMISSION" else f"its output is a {node.bl_label} node"
        notes.append(f"light {name}: its node tree is not read ({what}); baked with its Power and Color alone")
        return np.ones(3)
    return np.asarray(colour.default_value[:3], dtype=np.float64) * float(strength.default_value)


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
    values = [light.colour, light.position, light.direction, [light.radius, light.area]]
    if light.polygon is not None:
        values.append(np.ravel(light.polygon))
    if not all(np.all(np.isfinite(np.asarray(v, dtype=np.float64))) for v in values):
        return "NaN or Inf in its location, rotation, size or power"
    if np.any(light.colour < 0):
        return "negative power or colour"
    return None


def _same_vertices(mesh, data):
    """True if the evaluated mesh's vertices are the original mesh's, one for one, so its
    light can be written to them: its corners name the same vertices (modifiers that only
    move vertices), or its vertices stand where the original's do (modifiers that only
    change faces: Triangulate). False if modifiers add, remove or reorder vertices (a Sort
    Elements node keeps the count but not the order)."""
    if data["vertex_count"] != len(mesh.vertices):
        return False
    if len(data["loop_vertex"]) == len(mesh.loops):
        original = np.empty(len(mesh.loops), dtype=np.int64)
        mesh.loops.foreach_get("vertex_index", original)
        if np.array_equal(original, data["loop_vertex"]):
            return True
    co = np.empty(len(mesh.vertices) * 3, dtype=np.float64)
    mesh.vertices.foreach_get("co", co)
    return bool(np.array_equal(co.reshape(-1, 3), data["local_co"]))


NON_MESH_GEOMETRY = {"CURVE", "SURFACE", "FONT", "META", "CURVES", "POINTCLOUD", "VOLUME"}


@contextmanager
def _as_rendered(view_layer):
    """The view layer evaluated as a render evaluates it, for the time of the block: objects
    hidden with H or disabled in viewports, and collections hidden or disabled in viewports,
    render (Cycles' rule is ``hide_render`` and the view layer's exclusion) and so take part
    in the bake; modifiers are on where they are on in renders, subdivision at its render
    levels, particle systems at their render count and their emitters shown as in renders.
    Put back as it was afterwards."""
    undo = []
    visible = _render_visible_objects(view_layer)

    def walk(layer_coll):
        if layer_coll.exclude or layer_coll.collection.hide_render:
            return
        if layer_coll.hide_viewport:
            layer_coll.hide_viewport = False
            undo.append(lambda lc=layer_coll: setattr(lc, "hide_viewport", True))
        if layer_coll.collection.hide_viewport:
            layer_coll.collection.hide_viewport = False
            undo.append(lambda c=layer_coll.collection: setattr(c, "hide_viewport", True))
        for child in layer_coll.children:
            walk(child)

    def render_setting(owner, prop, value):
        before = getattr(owner, prop)
        if before != value:
            setattr(owner, prop, value)
            undo.append(lambda: setattr(owner, prop, before))

    try:
        walk(view_layer.layer_collection)
        for ob in view_layer.objects:
            if ob.hide_render or ob.name not in visible:
                continue
            # Modifiers and particles evaluated as a render evaluates them.
            for mod in ob.modifiers:
                render_setting(mod, "show_viewport", mod.show_render)
                if mod.type in {"SUBSURF", "MULTIRES"}:
                    render_setting(mod, "levels", mod.render_levels)
                if mod.type == "PARTICLE_SYSTEM":
                    render_setting(ob, "show_instancer_for_viewport", ob.show_instancer_for_render)
                    render_setting(mod.particle_system.settings, "display_percentage", 100)
            if ob.hide_viewport:
                ob.hide_viewport = False
                undo.append(lambda o=ob: setattr(o, "hide_viewport", True))
            if ob.hide_get(view_layer=view_layer):
                ob.hide_set(False, view_layer=view_layer)
                undo.append(lambda o=ob: o.hide_set(True, view_layer=view_layer))
        yield
    finally:
        for put_back in reversed(undo):
            put_back()


def collect(context, depsgraph=None):
    """The scene's arrays and the meshes to write back to.

    Every mesh-like object that renders contributes geometry (modifiers applied, world
    transforms, instances), whatever the viewport shows (see :func:`_as_rendered`);
    original, non-instanced mesh objects whose evaluated vertex count matches their mesh
    receive the baked light.
    """
    if depsgraph is not None:
        return _collect(context, depsgraph)
    with _as_rendered(context.view_layer):
        return _collect(context, context.evaluated_depsgraph_get())


def _rendered_instances(context, depsgraph):
    """``(instance, evaluated object, original object, top-level original)`` of every
    instance of the depsgraph that renders."""
    visible = _render_visible_objects(context.view_layer)
    for inst in depsgraph.object_instances:
        ob = inst.object
        original = ob.original
        top = inst.parent.original if inst.is_instance and inst.parent else original
        if top.hide_render or top.name not in visible or original.hide_render:
            continue
        if not inst.show_self:  # an instancer that does not render itself (Show Emitter off)
            continue
        yield inst, ob, original, top


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


def _add_light(inst, ob, lights, notes):
    if not ob.original.visible_diffuse:
        notes.append(f"light {ob.name}: its Diffuse ray visibility is off, so it lights no diffuse surface; left out")
        return
    light = _light(ob, inst.matrix_world, light_key(inst), notes)
    problem = _light_problem(light) if light is not None else None
    if problem:
        notes.append(f"light {ob.name}: {problem}; skipped")
    elif light is not None:
        lights.append(light)


def _note_unread_visibility(ob, notes):
    """Notes for an object's ray visibility that changes Cycles' light and that CubeGI does
    not read."""
    if not ob.visible_shadow:
        notes.append(f"{ob.name}: Visibility > Shadow is off, which CubeGI does not read; it casts shadows")
    if not ob.visible_diffuse:
        notes.append(f"{ob.name}: Visibility > Diffuse is off, which CubeGI does not read; the light it passes on "
                     "is baked")


def _is_dynamic(inst, original):
    settings = getattr(original, "cubegi", None)
    return original.type == "MESH" and not inst.is_instance and settings is not None and settings.dynamic


def _moving_object(ob, inst, original, notes):
    """``(SceneArrays, MeshTarget)`` of one dynamic object as it stands, or None."""
    data = _mesh_arrays(ob, inst.matrix_world, notes)
    if data is None:
        return None
    pts = _shading_points(data)
    mesh = original.data
    if mesh.library is not None or not _same_vertices(mesh, data):
        notes.append(f"{original.name}: dynamic, but its mesh is linked or its modifiers change its vertices; not lit")
        return None
    n = len(pts["points"])
    arrays = SceneArrays(
        pts["points"], pts["normals"], pts["albedo"], pts["emission"], pts["triangles"].astype(np.int64),
        point_object=np.zeros(n, dtype=np.int64), object_names=[original.name],
    )
    return arrays, MeshTarget(original.name, mesh.name, pts["loop_point"], data["loop_vertex"], len(mesh.vertices))


def moving_objects(context):
    """The dynamic objects as they stand now: ``[(SceneArrays, MeshTarget)]`` (reads only
    them: for updates of moving objects, see :mod:`.live`)."""
    notes, out = [], []
    with _as_rendered(context.view_layer):
        for inst, ob, original, _ in _rendered_instances(context, context.evaluated_depsgraph_get()):
            if ob.type == "MESH" and _is_dynamic(inst, original):
                part = _moving_object(ob, inst, original, notes)
                if part is not None:
                    out.append(part)
    return out


def static_object_names(context):
    """The names (as in ``SceneArrays.object_names``) of the static geometry that renders
    now, without reading a mesh: a frame whose set differs from the bake's (an object
    keyframed into or out of renders) needs a full bake."""
    names = set()
    with _as_rendered(context.view_layer):
        for inst, ob, original, _ in _rendered_instances(context, context.evaluated_depsgraph_get()):
            if ob.type == "MESH" and not _is_dynamic(inst, original):
                names.add(original.name)
    return names


def scene_lights(context):
    """The lights and the sky as a bake would see them now, without reading any mesh:
    ``(lights, sky (3,), sky pattern or None, notes)``. For updates of light alone (see
    :mod:`.live`)."""
    notes, lights = [], []
    with _as_rendered(context.view_layer):
        for inst, ob, _, _ in _rendered_instances(context, context.evaluated_depsgraph_get()):
            if ob.type == "LIGHT":
                _add_light(inst, ob, lights, notes)
    sky, pattern = _world_sky(context.scene, notes)
    return lights, sky, pattern, notes


def _collect(context, depsgraph):
    scene = context.scene
    notes = []
    parts, targets, lights, moving = [], [], [], []
    offset = 0
    claimed_meshes = set()
    non_mesh, with_surface = {}, set()
    for inst, ob, original, top in _rendered_instances(context, depsgraph):
        if ob.type == "LIGHT":
            _add_light(inst, ob, lights, notes)
            continue
        if ob.type in NON_MESH_GEOMETRY:
            # Blender evaluates curves, text, surfaces and metaballs to a mesh that it lists
            # as an instance of the same object: that one is used.
            non_mesh.setdefault(original.name, original.type)
            continue
        if ob.type != "MESH":
            continue
        if _is_dynamic(inst, original):
            part = _moving_object(ob, inst, original, notes)
            if part is not None:
                moving.append(part)
            continue
        data = _mesh_arrays(ob, inst.matrix_world, notes)
        if data is None:
            continue
        _note_unread_visibility(original, notes)
        pts = _shading_points(data)
        pts["name"] = original.name
        parts.append(pts)
        loop_point = pts["loop_point"] + offset
        offset += len(pts["points"])
        if original.type != "MESH":
            with_surface.add(original.name)
            continue
        if inst.is_instance:
            notes.append(
                f"{top.name}: its instances of {original.name} light the others but are not baked "
                "(Make Instances Real to bake them)"
            )
            continue
        mesh = original.data
        if mesh.library is not None:
            notes.append(
                f"{original.name}: its mesh is linked from {mesh.library.filepath!r} and cannot be written; "
                "it lights others but is not baked (make it local or a library override to bake it)"
            )
            continue
        if mesh.name in claimed_meshes:
            notes.append(f"{original.name}: shares mesh {mesh.name!r} with an object already baked; not baked again")
            continue
        if not _same_vertices(mesh, data):
            notes.append(
                f"{original.name}: modifiers change its vertex count or order; it lights others but is not baked "
                "(apply them, or bake a copy without them)"
            )
            continue
        claimed_meshes.add(mesh.name)
        targets.append(MeshTarget(original.name, mesh.name, loop_point, data["loop_vertex"], len(mesh.vertices)))

    for name, kind in non_mesh.items():
        if name in with_surface:
            notes.append(f"{name}: {kind.lower()} object lit and lighting others, but not baked")
        else:
            notes.append(f"{name}: {kind.lower()} object has no surface; skipped")
    if scene.background_set is not None:
        notes.append(f"scene {scene.name!r}: its Background Set {scene.background_set.name!r} is not read; its "
                     "objects cast no shadow and pass on no light")
    if not parts:
        raise BakeError("the scene has no visible geometry to bake")
    tri_offsets = np.cumsum([0] + [len(p["points"]) for p in parts[:-1]])
    sky, sky_map = _world_sky(scene, notes)
    arrays = SceneArrays(
        points=np.concatenate([p["points"] for p in parts]),
        normals=np.concatenate([p["normals"] for p in parts]),
        albedo=np.concatenate([p["albedo"] for p in parts]),
        emission=np.concatenate([p["emission"] for p in parts]),
        triangles=np.concatenate([p["triangles"] + o for p, o in zip(parts, tri_offsets)]).astype(np.int64),
        sky=sky,
        sky_map=sky_map,
        lights=lights,
        point_object=np.repeat(np.arange(len(parts)), [len(p["points"]) for p in parts]),
        object_names=[p["name"] for p in parts],
    )
    arrays.dark = _set_aside_non_finite(arrays, parts, notes)
    return CollectedScene(arrays, targets, list(dict.fromkeys(notes)), moving)  # each note once


def _set_aside_non_finite(arrays, parts, notes):
    """Points with NaN or Inf coordinates (or normals) leave the geometry: their triangles
    are dropped and they are parked at a finite point, to get no light. Returns the mask."""
    bad = ~(np.isfinite(arrays.points).all(axis=1) & np.isfinite(arrays.normals).all(axis=1))
    if not bad.any():
        return None
    if bad.all():
        raise BakeError("every vertex of the scene has NaN or Inf coordinates")
    owners = arrays.point_object
    for k in np.unique(owners[bad]):
        count = int((bad & (owners == k)).sum())
        notes.append(f"{parts[k]['name']}: {count} vertices with NaN or Inf coordinates get no light and cast no shadow")
    arrays.triangles = arrays.triangles[~bad[arrays.triangles].any(axis=1)]
    if len(arrays.triangles) == 0:
        raise BakeError("no triangle of the scene has finite coordinates")
    arrays.points[bad] = arrays.points[~bad][0]
    arrays.normals[bad] = (0.0, 0.0, 1.0)
    arrays.albedo[bad] = 0.0
    arrays.emission[bad] = 0.0
    return bad


def vertex_areas(ob):
    """Each vertex's share of the object's world-space surface area, ``(v,)``."""
    mesh = ob.data
    mesh.calc_loop_triangles()
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    m = np.array(ob.matrix_world, dtype=np.float64)
    co = co.reshape(-1, 3) @ m[:3, :3].T
    tri = np.empty(len(mesh.loop_triangles) * 3, dtype=np.int64)
    mesh.loop_triangles.foreach_get("vertices", tri)
    tri = tri.reshape(-1, 3)
    p = co[tri]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    return np.bincount(tri.ravel(), np.repeat(area / 3.0, 3), minlength=len(mesh.vertices))


def scored_areas(targets, arrays):
    """Per target (by object name), each vertex's area (:func:`vertex_areas`), zero where its
    material is black: Cycles' Diffuse bake reports no light there (a black surface has no
    diffuse closure), so comparisons with it leave those vertices out."""
    import bpy

    out = {}
    for target in targets:
        areas = vertex_areas(bpy.data.objects[target.object_name])
        albedo = attributes.vertex_values(target, arrays.albedo)
        out[target.object_name] = np.where(albedo.max(axis=1) > 0.0, areas, 0.0)
    return out
