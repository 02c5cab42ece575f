"""Small test scenes built in code."""

import bpy
import numpy as np


def material(name, colour, emission=None, strength=1.0):
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*colour, 1.0)
    if mat.node_tree is None:
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


def set_world(colour):
    world = bpy.data.worlds.new("World")
    bpy.context.scene.world = world
    world.color = colour
    if world.node_tree is not None:
        bg = next((n for n in world.node_tree.nodes if n.type == "BACKGROUND"), None)
        if bg is not None:
            bg.inputs["Color"].default_value = (*colour, 1.0)
            bg.inputs["Strength"].default_value = 1.0
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
    v, f = box_mesh((-h, -h, -h), (h, h, h), (cells, cells, cells), inward=True)
    mat = material(name, (albedo,) * 3, emission, strength)
    return mesh_object(name, v, f, mat)


def box_mesh(lo, hi, cells, inward):
    import importlib

    demo = importlib.import_module("cubegi.cubegi_addon.demo")
    return demo.box(lo, hi, cells, inward=inward)


def grid_patch(origin, eu, ev, nu, nv):
    import importlib

    demo = importlib.import_module("cubegi.cubegi_addon.demo")
    return demo.grid_patch(origin, eu, ev, nu, nv)
