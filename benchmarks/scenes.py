"""Scenes built in code, for the benchmark and the tests: a Cornell box, a sunlit courtyard
under a blue sky, a closed white box of albedo 0.95 lit by an emissive panel in its
ceiling, and two rooms
with a thin wall between them (the Room of the demo is in :mod:`tools.demo`).

Every builder starts from an empty file and returns the scene. Lights and blocks sit off
the geometry's vertex lattice, so no shadow edge runs exactly through a row of vertices.
"""

import bpy
import numpy as np

from tools.demo import box, grid_patch


def material(name, colour, emission=None, strength=1.0):
    """A rough Principled BSDF of base colour ``colour`` (and emission, if given)."""
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*colour, 1.0)
    if mat.node_tree is None:  # Blender < 5 creates node trees on request
        mat.use_nodes = True
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Roughness"].default_value = 1.0
    if emission is not None:
        bsdf.inputs["Emission Color"].default_value = (*emission, 1.0)
        bsdf.inputs["Emission Strength"].default_value = strength
    return mat


def mesh_object(name, verts, faces, mat=None, collection=None, smooth=False):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(np.asarray(verts, dtype=float).tolist(), [], np.asarray(faces).tolist())
    mesh.update()
    if smooth:
        mesh.shade_smooth()
    if mat is not None:
        mesh.materials.append(mat)
    ob = bpy.data.objects.new(name, mesh)
    (collection or bpy.context.scene.collection).objects.link(ob)
    return ob


def set_world(colour, strength=1.0):
    """A uniform world of radiance ``colour x strength``."""
    world = bpy.data.worlds.new("World")
    bpy.context.scene.world = world
    world.color = colour
    if world.node_tree is None:  # Blender < 5 creates node trees on request
        world.use_nodes = True
    if world.node_tree is not None:
        bg = next((n for n in world.node_tree.nodes if n.type == "BACKGROUND"), None)
        if bg is not None:
            bg.inputs["Color"].default_value = (*colour, 1.0)
            bg.inputs["Strength"].default_value = strength
    return world


def add_light(kind, location, energy, rotation=(0.0, 0.0, 0.0), **props):
    data = bpy.data.lights.new(kind.lower(), kind)
    data.energy = energy
    for k, v in props.items():
        setattr(data, k, v)
    ob = bpy.data.objects.new(kind.lower(), data)
    ob.location = location
    ob.rotation_euler = rotation
    bpy.context.scene.collection.objects.link(ob)
    return ob


def closed_box(size=2.0, cells=8, albedo=0.5, emission=None, strength=1.0, name="Box"):
    """A closed cube of edge ``size`` centred at the origin, normals inward."""
    h = size / 2.0
    v, f = box((-h, -h, -h), (h, h, h), (cells, cells, cells), inward=True)
    return mesh_object(name, v, f, material(name, (albedo,) * 3, emission, strength))


def _empty():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def cornell(light=True):
    """2 m box open at the front (-Y), red left and green right wall, two blocks standing a
    little above the floor; with ``light``, a 0.6 m square area light under the ceiling."""
    scene = _empty()
    white = material("White", (0.75, 0.75, 0.75))
    red = material("Red", (0.65, 0.06, 0.05))
    green = material("Green", (0.12, 0.45, 0.09))
    n = 10
    pieces = [
        ("Floor", (-1, -1, 0), (2, 0, 0), (0, 2, 0), white),
        ("Ceiling", (-1, -1, 2), (0, 2, 0), (2, 0, 0), white),
        ("Back", (-1, 1, 0), (2, 0, 0), (0, 0, 2), white),
        ("Left", (-1, -1, 0), (0, 2, 0), (0, 0, 2), red),
        ("Right", (1, -1, 0), (0, 0, 2), (0, 2, 0), green),
    ]
    for name, o, u, v, mat in pieces:
        verts, faces = grid_patch(o, u, v, n, n)
        mesh_object(name, verts, faces, mat)
    for name, lo, hi in (("Tall", (-0.67, 0.03, 0.02), (-0.13, 0.57, 1.17)), ("Short", (0.17, -0.57, 0.02), (0.73, -0.03, 0.57))):
        verts, faces = box(lo, hi, (3, 3, 3), inward=False)
        mesh_object(name, verts, faces, white)
    set_world((0.0, 0.0, 0.0))
    if light:
        add_light("AREA", (0, 0, 1.98), 80.0, shape="SQUARE", size=0.6)
    return scene


def courtyard():
    """A 12 x 12 m yard with 4 m walls and a block, open to a blue sky, under a low sun."""
    scene = _empty()
    ground = material("Ground", (0.55, 0.5, 0.42))
    wall = material("Wall", (0.8, 0.78, 0.72))
    v, f = grid_patch((-6, -6, 0), (12, 0, 0), (0, 12, 0), 24, 24)
    mesh_object("Ground", v, f, ground)
    walls = [((-6, -6, 0), (0, 12, 0), (0, 0, 4)), ((6, -6, 0), (0, 0, 4), (0, 12, 0)),
             ((-6, 6, 0), (12, 0, 0), (0, 0, 4)), ((-6, -6, 0), (0, 0, 4), (12, 0, 0))]
    for k, (o, u, v_) in enumerate(walls):
        verts, faces = grid_patch(o, u, v_, 24 if u[2] == 0 else 8, 8 if u[2] == 0 else 24)
        mesh_object(f"Wall {k}", verts, faces, wall)
    verts, faces = box((-1.37, -0.83, 0.0), (1.21, 1.44, 2.13), (5, 5, 4))
    mesh_object("Block", verts, faces, wall)
    set_world((0.35, 0.5, 0.8), strength=1.0)
    add_light("SUN", (0, 0, 10), 3.0, rotation=(np.radians(55), 0.0, np.radians(35)), angle=0.0)
    return scene


def white_box(albedo=0.95):
    """A closed 3 m box of albedo ``albedo`` lit only by a 0.5 m emissive panel set into its
    ceiling (it fills a hole there, so the box stays closed and the panel's back faces out)."""
    scene = _empty()
    v, f = box((-1.5, -1.5, 0.0), (1.5, 1.5, 3.0), (12, 12, 12), inward=True)
    centres = v[f].mean(axis=1)
    hole = (np.abs(centres[:, 2] - 3.0) < 1e-9) & (np.abs(centres[:, 0]) < 0.25) & (np.abs(centres[:, 1]) < 0.25)
    mesh_object("Box", v, f[~hole], material("White", (albedo,) * 3))
    verts, faces = grid_patch((-0.25, -0.25, 3.0), (0, 0.5, 0), (0.5, 0, 0), 2, 2)
    mesh_object("Panel", verts, faces, material("Panel", (0.0, 0.0, 0.0), emission=(1.0, 1.0, 1.0), strength=15.0))
    verts, faces = box((-0.43, -0.61, 0.0), (0.37, 0.19, 0.9), (3, 3, 3))
    mesh_object("Block", verts, faces, material("Grey", (albedo,) * 3))
    set_world((0.0, 0.0, 0.0))
    return scene


def thin_wall():
    """Two 4 x 4 x 2.5 m rooms side by side, sealed from each other by a 2 cm wall; a point
    light in the left room only. No light reaches the right room."""
    scene = _empty()
    white = material("White", (0.8, 0.8, 0.8))
    v, f = box((-4.0, -2.0, 0.0), (4.0, 2.0, 2.5), (16, 8, 5), inward=True)
    mesh_object("Rooms", v, f, white)
    v, f = box((-0.01, -2.0, 0.0), (0.01, 2.0, 2.5), (1, 8, 5))
    mesh_object("Wall", v, f, white)
    add_light("POINT", (-1.93, 0.37, 1.71), 200.0, shadow_soft_size=0.05)
    set_world((0.0, 0.0, 0.0))
    return scene


# The hall's lamps: (x, y) of each 1.2 x 0.5 m panel 10 cm under the 5 m ceiling, two rows
# of six down the hall and one over the stairs; with one lamp, the middle one, as bright as
# all thirteen.
HALL_LAMPS = tuple((x, y) for y in (-1.6, 1.6) for x in (-8.3, -5.1, -1.7, 1.9, 5.3, 8.6)) + ((0.3, 3.1),)


def hall(lamps=13):
    """A 20 x 8 x 5 m hall lit only by ``lamps`` area lights under its ceiling (see
    HALL_LAMPS), with four pillars, a long table and a floating staircase of twelve steps
    along its back wall (each step a slab, 15 cm under the next one's edge: the contact
    shadows under them)."""
    scene = _empty()
    white = material("Plaster", (0.78, 0.76, 0.72))
    wood = material("Wood", (0.45, 0.28, 0.15))
    stone = material("Stone", (0.5, 0.5, 0.52))
    v, f = box((-10.0, -4.0, 0.0), (10.0, 4.0, 5.0), (120, 48, 30), inward=True)
    mesh_object("Hall", v, f, white)
    for k, (x, y) in enumerate(((-6.1, -2.2), (-2.3, 2.1), (2.7, -2.2), (6.4, 2.1))):
        v, f = box((x - 0.3, y - 0.3, 0.0), (x + 0.3, y + 0.3, 5.0), (3, 3, 30))
        mesh_object(f"Pillar {k}", v, f, stone)
    v, f = box((-3.1, -1.13, 0.73), (3.3, 0.07, 0.79), (32, 6, 1))
    mesh_object("Table top", v, f, wood)
    for k, (x, y) in enumerate(((-2.9, -1.0), (3.1, -1.0), (-2.9, -0.06), (3.1, -0.06))):
        v, f = box((x - 0.04, y - 0.04, 0.0), (x + 0.04, y + 0.04, 0.73), (1, 1, 2))
        mesh_object(f"Table leg {k}", v, f, wood)
    for k in range(12):
        x, z = -4.7 + 0.71 * k, 0.37 * (k + 1)
        v, f = box((x, 2.9, z - 0.06), (x + 0.8, 3.97, z), (8, 10, 1))
        mesh_object(f"Step {k}", v, f, wood)
    set_world((0.0, 0.0, 0.0))
    where = HALL_LAMPS if lamps > 1 else ((0.3, -0.1),)
    for x, y in where[:lamps]:
        add_light("AREA", (x, y, 4.9), 260.0 * len(HALL_LAMPS) / min(lamps, len(where)), shape="RECTANGLE", size=1.2, size_y=0.5)
    return scene
