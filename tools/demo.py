"""The demo scene, after the paper's "Room": white walls, a red-brown carpet, a red table,
Suzanne standing in for the bunny, two lights, about 12,000 triangles.

The paper's grid is 3 x 2 x 7 in a Y-up frame (across, up, along); in Blender's Z-up frame
that is ``DEMO_GRID = (3, 7, 2)``: 3 across (X), 7 along the room (Y), 2 up (Z).
"""

import bpy
import numpy as np

ROOM = (4.0, 9.0, 2.8)  # width (X), length (Y), height (Z) in metres
DEMO_GRID = (3, 7, 2)


def _material(name, colour):
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*colour, 1.0)
    tree = mat.node_tree
    if tree is None:  # Blender < 5 creates node trees on request
        mat.use_nodes = True
        tree = mat.node_tree
    bsdf = next(n for n in tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Roughness"].default_value = 1.0
    return mat


def _object(name, verts, faces, material, collection):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(np.asarray(verts).tolist(), [], np.asarray(faces).tolist())
    mesh.update()
    mesh.materials.append(material)
    ob = bpy.data.objects.new(name, mesh)
    collection.objects.link(ob)
    return ob


def grid_patch(origin, edge_u, edge_v, nu, nv):
    """Vertices and quads of a parallelogram cut into ``nu x nv`` cells; normal u x v."""
    origin, edge_u, edge_v = (np.asarray(a, dtype=np.float64) for a in (origin, edge_u, edge_v))
    i, j = np.meshgrid(np.arange(nu + 1), np.arange(nv + 1), indexing="ij")
    verts = origin + (i.ravel() / nu)[:, None] * edge_u + (j.ravel() / nv)[:, None] * edge_v
    a = (i[:-1, :-1] * (nv + 1) + j[:-1, :-1]).ravel()
    faces = np.stack([a, a + nv + 1, a + nv + 2, a + 1], axis=1)
    return verts, faces


def box(lo, hi, n=(1, 1, 1), inward=False):
    """Vertices and quads of an axis-aligned box with ``n`` cells per axis (separate sides)."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    size = hi - lo
    verts, faces = [], []
    for axis in range(3):
        u, v = (axis + 1) % 3, (axis + 2) % 3
        for side in (0, 1):
            origin = lo.copy()
            origin[axis] = hi[axis] if side else lo[axis]
            eu, ev = np.zeros(3), np.zeros(3)
            eu[u], ev[v] = size[u], size[v]
            outward = side == 1
            if outward == inward:  # flip to make u x v point the wanted way
                origin, eu, ev, nu_, nv_ = origin, ev, eu, n[v], n[u]
            else:
                nu_, nv_ = n[u], n[v]
            pv, pf = grid_patch(origin, eu, ev, nu_, nv_)
            faces.append(pf + sum(len(x) for x in verts))
            verts.append(pv)
    return np.concatenate(verts), np.concatenate(faces)


def build_room(subdivision=1):
    """Reset to an empty file and build the Room. Returns the scene."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    coll = scene.collection
    w, l, h = ROOM
    white = _material("Walls", (0.8, 0.8, 0.8))
    carpet = _material("Carpet", (0.45, 0.12, 0.06))
    red = _material("Table", (0.7, 0.06, 0.05))
    grey = _material("Suzanne", (0.75, 0.75, 0.7))

    v, f = box((-w / 2, -l / 2, 0.0), (w / 2, l / 2, h), n=(20, 45, 14), inward=True)
    _object("Room", v, f, white, coll)
    v, f = grid_patch((-1.5, -3.0, 0.01), (3.0, 0, 0), (0, 5.0, 0), 10, 16)
    _object("Carpet", v, f, carpet, coll)

    parts = [box((-0.7, -1.2, 0.70), (0.7, 0.2, 0.76), n=(4, 4, 1))]
    for x in (-0.62, 0.55):
        for y in (-1.12, 0.05):
            parts.append(box((x, y, 0.01), (x + 0.07, y + 0.07, 0.70), n=(1, 1, 4)))
    verts, faces, off = [], [], 0
    for pv, pf in parts:
        verts.append(pv)
        faces.append(pf + off)
        off += len(pv)
    _object("Table", np.concatenate(verts), np.concatenate(faces), red, coll)

    import bmesh

    bm = bmesh.new()
    bmesh.ops.create_monkey(bm)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=subdivision, use_grid_fill=True, smooth=1.0)
    mesh = bpy.data.meshes.new("Suzanne")
    bm.to_mesh(mesh)
    bm.free()
    mesh.shade_smooth()
    mesh.materials.append(grey)
    suz = bpy.data.objects.new("Suzanne", mesh)
    suz.location = (0.0, -0.5, 1.05)
    suz.rotation_euler = (0.0, 0.0, np.pi)
    suz.scale = (0.3, 0.3, 0.3)
    coll.objects.link(suz)

    for name, loc, power in (("Lamp A", (0.8, -2.5, 2.5), 40.0), ("Lamp B", (-0.9, 2.6, 2.5), 30.0)):
        data = bpy.data.lights.new(name, "POINT")
        data.energy = power
        data.color = (1.0, 0.93, 0.82)
        data.shadow_soft_size = 0.05
        lamp = bpy.data.objects.new(name, data)
        lamp.location = loc
        coll.objects.link(lamp)

    cam_data = bpy.data.cameras.new("Camera")
    cam_data.lens = 18
    cam = bpy.data.objects.new("Camera", cam_data)
    cam.location = (1.6, 4.2, 1.7)
    cam.rotation_euler = (np.radians(80), 0.0, np.radians(160))
    coll.objects.link(cam)
    scene.camera = cam

    from cubegi.cubegi_addon.grid_objects import new_probe_grid

    new_probe_grid(coll, (-w / 2, -l / 2, 0.0), (w / 2, l / 2, h), DEMO_GRID)
    scene.cubegi.cube_size = 32
    scene.cubegi.bounces = 5
    world = bpy.data.worlds.new("World")
    world.color = (0.0, 0.0, 0.0)
    if world.node_tree is not None:  # a new world's Background node defaults to grey
        for node in world.node_tree.nodes:
            if node.type == "BACKGROUND":
                node.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    scene.world = world
    bpy.context.view_layer.update()
    return scene


def render_png(path, attribute="CubeGI_lit", resolution=(960, 540)):
    """Render the scene's camera with Workbench, showing ``attribute`` unlit (as stored)."""
    scene = bpy.context.scene
    for ob in scene.objects:
        if ob.type == "MESH" and attribute in ob.data.color_attributes:
            ob.data.color_attributes.active_color = ob.data.color_attributes[attribute]
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.display.shading.light = "FLAT"
    scene.display.shading.color_type = "VERTEX"
    scene.view_settings.view_transform = "Standard"
    scene.render.resolution_x, scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
