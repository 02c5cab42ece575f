"""Public scenes authored outside CubeGI, built into Blender for the benchmarks.

- *The Breakfast Room* by Wig42, converted by Benedikt Bitterli (CC BY 3.0): its Mitsuba 0.5
  ``scene.xml`` (one OBJ a shape, with its ``toWorld`` matrix and BSDF), lit as the scene
  folder's notes say: a sun through the blinds of the window wall (+X) and a uniform sky.
- McGuire's Cornell box (public domain): ``CornellBox-Original.obj``, whose light is an
  emissive quad 1 cm under the ceiling (its ``Ke``, which Blender's OBJ importer turns into
  Principled emission).

The scenes are read from ``CUBEGI_PUBLIC_SCENES``, or else from ``shared/scenes`` beside the
project's folder. The diffuse comparison takes each BSDF's diffuse reflectance (a plastic's
diffuse part) and gives metals a grey diffuse, as the scene notes advise.
"""

import os
import xml.etree.ElementTree as ET

import bpy
import numpy as np
from mathutils import Matrix, Vector

from .scenes import material, mesh_object, set_world

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CREDIT = {
    "breakfast_room": "The Breakfast Room by Wig42, converted by Benedikt Bitterli (CC BY 3.0)",
    "cornell_original": "Cornell box by Morgan McGuire's Computer Graphics Archive (public domain)",
}
METAL_GREY = 0.5
# Mitsuba is Y up, Blender Z up: (x, y, z) -> (x, -z, y), as the OBJ importer's defaults do.
Y_UP = Matrix(((1, 0, 0, 0), (0, 0, -1, 0), (0, 1, 0, 0), (0, 0, 0, 1)))


def scenes_dir():
    """The folder of the public scenes, or None where this checkout has none."""
    for path in (os.environ.get("CUBEGI_PUBLIC_SCENES"), os.path.join(ROOT, "..", "shared", "scenes")):
        if path and os.path.isdir(path):
            return os.path.abspath(path)
    return None


def _folder(name):
    base = scenes_dir()
    path = base and os.path.join(base, name)
    if not path or not os.path.isdir(path):
        raise FileNotFoundError(f"the public scene {name!r} is not here: set CUBEGI_PUBLIC_SCENES to the folder of shared/scenes")
    return path


def _empty():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def _import_obj(path):
    """The objects the OBJ at ``path`` adds, Y up turned to Z up."""
    before = set(bpy.data.objects)
    bpy.ops.wm.obj_import(filepath=path, forward_axis="NEGATIVE_Z", up_axis="Y")
    return [ob for ob in bpy.data.objects if ob not in before]


def _flat(ob):
    """Flat shading, the OBJ's own normals dropped (a Mitsuba shape with ``faceNormals``)."""
    with bpy.context.temp_override(object=ob, active_object=ob, selected_objects=[ob]):
        if ob.data.has_custom_normals:
            bpy.ops.mesh.customdata_custom_splitnormals_clear()
    ob.data.shade_flat()


def _floats(text):
    return [float(x) for x in text.replace(",", " ").split()]


def _mitsuba_material(bsdf, folder):
    """A Blender material for a Mitsuba BSDF: its diffuse reflectance, colour or texture."""
    name = bsdf.get("id", "material")
    inner = bsdf.find("bsdf") if bsdf.get("type") == "twosided" else bsdf
    colour, image = (METAL_GREY,) * 3, None
    for child in inner:
        if child.get("name") in ("reflectance", "diffuseReflectance"):
            if child.tag == "rgb":
                colour = tuple(_floats(child.get("value"))[:3])
            elif child.tag == "texture":
                image = os.path.join(folder, child.find("string[@name='filename']").get("value"))
    mat = material(name, colour)
    if image is not None:
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = bpy.data.images.load(image, check_existing=True)
        bsdf_node = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")
        links.new(tex.outputs["Color"], bsdf_node.inputs["Base Color"])
    return mat


def _matrix(shape):
    m = shape.find("transform[@name='toWorld']/matrix")
    rows = np.array(_floats(m.get("value"))).reshape(4, 4) if m is not None else np.eye(4)
    return Y_UP @ Matrix(rows.tolist())


def _sun(direction, strength, colour, angle_deg):
    data = bpy.data.lights.new("Sun", "SUN")
    data.energy, data.color, data.angle = strength, colour, np.radians(angle_deg)
    ob = bpy.data.objects.new("Sun", data)
    ob.rotation_euler = Vector(direction).normalized().to_track_quat("-Z", "Y").to_euler()
    bpy.context.scene.collection.objects.link(ob)
    return ob


def breakfast_room():
    """The Breakfast Room: 52 OBJ shapes and a rectangle, a sun through the blinds, a sky."""
    folder = _folder("breakfast-room")
    scene = _empty()
    root = ET.parse(os.path.join(folder, "scene.xml")).getroot()
    materials = {b.get("id"): _mitsuba_material(b, folder) for b in root.findall("bsdf")}
    for k, shape in enumerate(root.findall("shape")):
        mat = materials[shape.find("ref").get("id")]
        if shape.get("type") == "rectangle":  # Mitsuba's [-1, 1]^2 at z = 0, facing +z
            ob = mesh_object(f"Rectangle{k:03d}", [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [(0, 1, 2, 3)], mat)
            ob.matrix_world = _matrix(shape)
            continue
        filename = shape.find("string[@name='filename']").get("value")
        for ob in _import_obj(os.path.join(folder, filename)):
            ob.name = os.path.splitext(os.path.basename(filename))[0]
            # The importer applied Y up -> Z up; a shape's own toWorld (identity here) is Mitsuba's.
            ob.matrix_world = _matrix(shape) @ Y_UP.inverted() @ ob.matrix_world
            ob.data.materials.clear()
            ob.data.materials.append(mat)
            face_normals = shape.find("boolean[@name='faceNormals']")
            if face_normals is not None and face_normals.get("value") == "true":
                _flat(ob)
    _sun((-1.0, 0.45, -0.55), 4.0, (1.0, 0.93, 0.82), 0.53)
    set_world((0.40, 0.50, 0.65), 2.0)
    return scene


def breakfast_camera():
    """The scene's own camera (its ``sensor``: 60 degrees across, 16:9) as the Blender scene's
    camera, for pictures. Mitsuba's camera looks along its local +z with +y up; Blender's
    along -z: x and z are turned round."""
    root = ET.parse(os.path.join(_folder("breakfast-room"), "scene.xml")).getroot()
    sensor = root.find("sensor")
    m = np.array(_floats(sensor.find("transform/matrix").get("value"))).reshape(4, 4)
    data = bpy.data.cameras.new("Camera")
    data.sensor_fit = "HORIZONTAL"
    data.angle = np.radians(float(sensor.find("float[@name='fov']").get("value")))
    ob = bpy.data.objects.new("Camera", data)
    ob.matrix_world = Y_UP @ Matrix(m.tolist()) @ Matrix.Diagonal((-1.0, 1.0, -1.0, 1.0))
    bpy.context.scene.collection.objects.link(ob)
    bpy.context.scene.camera = ob
    return ob


def cornell_original(cuts=16):
    """McGuire's Cornell box, each quad cut into ``cuts`` x ``cuts`` so that per-vertex light
    has vertices to land on (the file's walls are single quads)."""
    import shutil
    import tempfile

    scene = _empty()
    folder = _folder("cornell-box")
    with tempfile.TemporaryDirectory(prefix="cubegi-cornell-") as tmp:
        # The OBJ names its MTL as "scenes/CornellBox-Original.mtl" (its old repository's
        # layout); the copy names the MTL beside it.
        with open(os.path.join(folder, "CornellBox-Original.obj")) as fh:
            text = fh.read().replace("mtllib scenes/CornellBox-Original.mtl", "mtllib CornellBox-Original.mtl")
        with open(os.path.join(tmp, "CornellBox-Original.obj"), "w") as fh:
            fh.write(text)
        shutil.copy(os.path.join(folder, "CornellBox-Original.mtl"), tmp)
        objects = _import_obj(os.path.join(tmp, "CornellBox-Original.obj"))
    for ob in objects:
        for part in _by_material(ob):
            _subdivide(part, cuts)
    return scene


def _by_material(ob):
    """One object per material of ``ob``, named after it (the file's groups and materials do
    not line up: its boxes' faces fall in the walls' groups), in place of ``ob``."""
    import bmesh

    parts = []
    for k, mat in enumerate(ob.data.materials):
        bm = bmesh.new()
        bm.from_mesh(ob.data)
        bmesh.ops.delete(bm, geom=[f for f in bm.faces if f.material_index != k], context="FACES")
        if not bm.faces:
            bm.free()
            continue
        for f in bm.faces:
            f.material_index = 0
        mesh = bpy.data.meshes.new(mat.name)
        bm.to_mesh(mesh)
        bm.free()
        mesh.materials.append(mat)
        part = bpy.data.objects.new(mat.name, mesh)
        part.matrix_world = ob.matrix_world
        bpy.context.scene.collection.objects.link(part)
        parts.append(part)
    bpy.data.objects.remove(ob)
    bpy.context.view_layer.update()  # else the view layer still lists the removed object
    return parts


def _subdivide(ob, cuts):
    import bmesh

    bm = bmesh.new()
    bm.from_mesh(ob.data)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=cuts - 1, use_grid_fill=True)
    bm.to_mesh(ob.data)
    bm.free()
    ob.data.update()


def corner_count():
    """Vertices over the meshes of the scene (a figure for the benchmarks' tables)."""
    return sum(len(ob.data.vertices) for ob in bpy.context.scene.objects if ob.type == "MESH")
