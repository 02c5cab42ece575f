"""Blender scene to CubeGI arrays: the objects that render, evaluated as a render evaluates
them, and their meshes, lights, materials and world (read by :mod:`.read_meshes`,
:mod:`.read_lights`, :mod:`.read_materials` and :mod:`.read_world`).

The scene reader: with those four, the only code that reads the scene's data for a bake.
Bulk data moves with ``foreach_get`` into numpy arrays; nothing loops over vertices in
Python.
"""

import hashlib
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from ..cubegi_engine import working as working_steps
from ..cubegi_engine.errors import BakeError
from ..cubegi_engine.geometry import cross
from ..cubegi_engine.scene import SceneArrays
from . import attributes, read_lights, read_materials, read_meshes, read_world
from .sampling import sampled


@dataclass
class MeshTarget:
    """Where one object's baked light goes: its original mesh, and how its corners map.

    loop_point: ``(corners,)`` global shading-point index of each corner; loop_vertex:
    ``(corners,)`` the corner's vertex; vertex_count: vertices in the mesh; object_uid: the
    object's ``session_uid``, by which kept bakes find it again (names can change).
    """

    object_name: str
    mesh_name: str
    loop_point: np.ndarray
    loop_vertex: np.ndarray
    vertex_count: int
    object_uid: int = None


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


def _indirect_only_collections(view_layer):
    """``{object name: collection name}`` of the objects in a collection marked Indirect Only
    (Cycles) in this view layer."""
    found = {}

    def walk(layer_coll):
        if getattr(layer_coll, "indirect_only", False):
            for ob in layer_coll.collection.all_objects:
                found.setdefault(ob.name, layer_coll.collection.name)
        for child in layer_coll.children:
            walk(child)

    walk(view_layer.layer_collection)
    return found


NON_MESH_GEOMETRY = {"CURVE", "SURFACE", "FONT", "META", "CURVES", "POINTCLOUD", "VOLUME"}


@contextmanager
def _as_rendered(view_layer, geometry=True):
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
            # Modifiers and particles evaluated as a render evaluates them (not for a read
            # of lights alone: each toggle is a depsgraph update, and Live reads on those).
            for mod in ob.modifiers if geometry else ():
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


def collect_steps(context, working, only=None):
    """:func:`collect` as steps: Blender's data is read in one step (the render settings of
    :func:`_as_rendered` never outlast it), the arrays are made in a thread while it yields
    ``working`` (a Progress) every WORKING_SECONDS."""
    with _as_rendered(context.view_layer):
        reading = _read(context, context.evaluated_depsgraph_get(), only)
    return (yield from working_steps.in_background(_assemble, working, reading))


def collect(context, depsgraph=None, only=None, grid=None):
    """The scene's arrays and the meshes to write back to.

    Every mesh-like object that renders contributes geometry (modifiers applied, world
    transforms, instances), whatever the viewport shows (see :func:`_as_rendered`), unless
    its Contribute is off (then it is lit as a dynamic object is); original, non-instanced
    mesh objects whose evaluated vertex count matches their mesh receive the baked light,
    unless their Receive is off or ``only`` (objects' ``session_uid``: Bake Selected, ``--only``) leaves
    them out. ``grid``: the arrays as a bake on that grid has them (:func:`sampled`).
    """
    if depsgraph is not None:
        collected = _collect(context, depsgraph, only)
    else:
        with _as_rendered(context.view_layer):
            collected = _collect(context, context.evaluated_depsgraph_get(), only)
    return collected if grid is None else sampled(collected, grid)


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


def _note_unread_visibility(ob, notes):
    """Notes for an object's ray visibility that changes Cycles' light and that CubeGI does
    not read."""
    if not ob.visible_shadow:
        notes.append(f"{ob.name}: Visibility > Shadow is off, which CubeGI does not read; it casts shadows")
    if getattr(ob, "is_holdout", False):
        notes.append(f"{ob.name}: Visibility > Holdout is on, which CubeGI does not read; it is baked as a visible surface")
    if not ob.visible_diffuse:
        notes.append(f"{ob.name}: Visibility > Diffuse is off, which CubeGI does not read; the light it passes on "
                     "is baked")


def _is_dynamic(inst, original):
    return original.type == "MESH" and not inst.is_instance and _dynamic_setting(original)


def _dynamic_setting(ob):
    """True if ``ob`` stays out of the capture and the shadows: Dynamic on, or Contribute off."""
    settings = getattr(ob, "cubegi", None)
    return settings is not None and (settings.dynamic or not settings.contribute)


def receives(ob, only=None):
    """True if a bake writes its light into ``ob``: its Receive is on and ``only`` (a set of
    objects' ``session_uid``, which a rename keeps; None for all) holds it."""
    settings = getattr(ob, "cubegi", None)
    return (settings is None or settings.receive) and (only is None or ob.session_uid in only)


def _moving_object(ob, inst, original, notes):
    """``(SceneArrays, MeshTarget)`` of one dynamic object as it stands, or None."""
    data = read_meshes.mesh_arrays(ob, inst.matrix_world, notes)
    if data is None:
        return None
    pts = read_meshes.shading_points(data)
    mesh = original.data
    if mesh.library is not None or not read_meshes.same_vertices(mesh, data):
        notes.append(f"{original.name}: dynamic, but its mesh is linked or its modifiers change its vertices; not lit")
        return None
    n = len(pts["points"])
    arrays = SceneArrays(
        pts["points"], pts["normals"], pts["albedo"], pts["emission"], pts["triangles"].astype(np.int64),
        point_object=np.zeros(n, dtype=np.int64), object_names=[original.name],
    )
    return arrays, MeshTarget(original.name, mesh.name, pts["loop_point"], data["loop_vertex"], len(mesh.vertices),
                              original.session_uid)


def moving_objects(context, only=None):
    """The dynamic objects that receive light, as they stand now: ``[(SceneArrays,
    MeshTarget)]`` (reads only them: for updates of moving objects, see :mod:`.live`)."""
    notes, out = [], []
    with _as_rendered(context.view_layer):
        for inst, ob, original, _ in _rendered_instances(context, context.evaluated_depsgraph_get()):
            if ob.type == "MESH" and _is_dynamic(inst, original) and receives(original, only):
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


def static_shapes(view_layer, depsgraph, only=None):
    """Where the static geometry that renders stands, as ``depsgraph`` (the viewport's)
    evaluates it, without reading a material: ``{session_uid: (name, digest)}`` of every
    object that renders and is not dynamic; the digest covers its world matrix and its
    evaluated vertices and corner normals (a mesh), its bounds (curves, text, metaballs) or
    its instanced collection (an Empty that instances geometry). With ``only`` (a set of ``session_uid``) the
    others' digests are None (their membership alone is read).

    For updates (:mod:`.live`): the kept bake's shapes tell a user's edit (a move, an Edit
    Mode change, a modifier, an object deleted or added) from CubeGI's own attribute writes,
    which leave them as they were."""
    visible = _render_visible_objects(view_layer)
    out = {}
    for ob in view_layer.objects:
        if ob.hide_render or ob.name not in visible:
            continue
        if ob.type == "EMPTY" and not _instances_geometry(ob):
            continue
        if ob.type not in NON_MESH_GEOMETRY | {"MESH", "EMPTY"} or (ob.type == "MESH" and _dynamic_setting(ob)):
            continue
        uid = ob.session_uid
        out[uid] = (ob.name, None if only is not None and uid not in only else _shape_digest(ob, depsgraph))
    return out


def _instances_geometry(empty):
    """True if an Empty instances a collection that holds geometry (not lights alone)."""
    collection = empty.instance_collection if empty.instance_type == "COLLECTION" else None
    return collection is not None and any(o.type in NON_MESH_GEOMETRY | {"MESH"} for o in collection.all_objects)


def _shape_digest(ob, depsgraph):
    h = hashlib.blake2b(digest_size=16)
    h.update(np.array(ob.matrix_world, dtype=np.float64).tobytes())
    if ob.type == "EMPTY":
        h.update(np.int64(ob.instance_collection.session_uid).tobytes())
        return h.hexdigest()
    evaluated = ob.evaluated_get(depsgraph)
    if ob.type != "MESH":
        h.update(np.array([corner[:] for corner in evaluated.bound_box], dtype=np.float64).tobytes())
        return h.hexdigest()
    mesh = evaluated.data
    co = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", co)
    normals = np.empty(len(mesh.loops) * 3, dtype=np.float32)
    mesh.corner_normals.foreach_get("vector", normals)
    h.update(np.int64(len(mesh.polygons)).tobytes())
    h.update(co.tobytes())
    h.update(normals.tobytes())
    return h.hexdigest()


def scene_lights(context):
    """The lights and the sky as a bake would see them now, without reading any mesh:
    ``(lights, sky (3,), sky pattern or None, notes)``. For updates of light alone (see
    :mod:`.live`)."""
    notes, lights = [], []
    with _as_rendered(context.view_layer, geometry=False):
        for inst, ob, _, _ in _rendered_instances(context, context.evaluated_depsgraph_get()):
            if ob.type == "LIGHT":
                read_lights.add_light(inst, ob, lights, notes)
    sky, pattern = read_world.world_sky(context.scene, notes)
    return lights, sky, pattern, notes


def _collect(context, depsgraph, only):
    return _assemble(_read(context, depsgraph, only))


@dataclass
class _Reading:
    """What :func:`_read` takes from Blender for a bake; :func:`_assemble` makes the arrays
    of it with numpy alone (in a thread of its own during a stepped bake)."""

    meshes: list  # (corner data of _mesh_arrays, object name, MeshTarget with no loop_point or None)
    lights: list
    moving: list
    notes: list
    sky: object
    sky_map: object


def _read(context, depsgraph, only):
    scene = context.scene
    notes = []
    meshes, lights, moving = [], [], []
    claimed_meshes = {}  # mesh name -> the object baked with it
    non_mesh, with_surface = {}, set()
    indirect_only = _indirect_only_collections(context.view_layer)
    for name, collection in indirect_only.items():
        notes.append(f"{name}: its collection {collection!r} is Indirect Only, which CubeGI does not read; it is baked "
                     "and lights the scene as any object")
    for inst, ob, original, top in _rendered_instances(context, depsgraph):
        if ob.type == "LIGHT":
            read_lights.add_light(inst, ob, lights, notes)
            continue
        if ob.type in NON_MESH_GEOMETRY:
            # Blender evaluates curves, text, surfaces and metaballs to a mesh that it lists
            # as an instance of the same object: that one is used.
            non_mesh.setdefault(original.name, original.type)
            continue
        if ob.type != "MESH":
            continue
        if _is_dynamic(inst, original):
            if not receives(original, only):  # neither lights the rest nor is lit
                continue
            part = _moving_object(ob, inst, original, notes)
            if part is not None:
                moving.append(part)
            continue
        data = read_meshes.mesh_arrays(ob, inst.matrix_world, notes)
        if data is None:
            continue
        _note_unread_visibility(original, notes)
        target = _target(inst, original, top, data, only, claimed_meshes, notes) if original.type == "MESH" else None
        if original.type != "MESH":
            with_surface.add(original.name)
        del data["local_co"]  # read by _target alone
        meshes.append((data, original.name, target))

    for name, kind in non_mesh.items():
        if name in with_surface:
            notes.append(f"{name}: {kind.lower()} object lit and lighting others, but not baked")
        elif kind == "META":  # Blender lists no mesh of a metaball among the instances
            notes.append(f"{name}: metaballs are not read; it casts no shadow and passes on no light, which it does in "
                         "renders (convert it to a mesh to bake it)")
        else:
            notes.append(f"{name}: {kind.lower()} object has no surface; skipped")
    if scene.background_set is not None:
        notes.append(f"scene {scene.name!r}: its Background Set {scene.background_set.name!r} is not read; its "
                     "objects cast no shadow and pass on no light")
    if not meshes:
        raise BakeError("the scene has no visible geometry to bake")
    sky, sky_map = read_world.world_sky(scene, notes)
    return _Reading(meshes, lights, moving, notes, sky, sky_map)


def _target(inst, original, top, data, only, claimed_meshes, notes):
    """The MeshTarget (with no ``loop_point`` yet) of a static mesh object, or None (and why, in
    ``notes``) if its light is not written."""
    if not receives(original, only):  # it lights and shadows the rest, and keeps the light it has
        return None
    if inst.is_instance:
        notes.append(
            f"{top.name}: its instances of {original.name} light the others but are not baked "
            "(Make Instances Real to bake them)"
        )
        return None
    mesh = original.data
    if mesh.library is not None:
        notes.append(
            f"{original.name}: its mesh is linked from {mesh.library.filepath!r} and cannot be written; "
            "it lights others but is not baked (make it local or a library override to bake it)"
        )
        return None
    if mesh.name in claimed_meshes:
        notes.append(f"{original.name}: shares mesh {mesh.name!r} with {claimed_meshes[mesh.name]}, which is baked: it shows that "
                     "object's light, baked where that one stands (Object > Relations > Make Single User to bake its own)")
        return None
    if not read_meshes.same_vertices(mesh, data):
        notes.append(
            f"{original.name}: modifiers change its vertex count or order; it lights others but is not baked "
            "(apply them, or bake a copy without them)"
        )
        return None
    claimed_meshes[mesh.name] = original.name
    return MeshTarget(original.name, mesh.name, None, data["loop_vertex"], len(mesh.vertices), original.session_uid)


def _assemble(reading):
    """The CollectedScene of a reading: shading points, back sides, one set of arrays (numpy
    alone; the reading's corner data is let go as it goes)."""
    parts, targets, offset = [], [], 0
    while reading.meshes:
        data, name, target = reading.meshes.pop(0)
        pts = read_meshes.with_back_side(read_meshes.shading_points(data), data)
        pts["name"] = name
        parts.append(pts)
        if target is not None:
            target.loop_point = pts["loop_point"] + offset
            targets.append(target)
        offset += len(pts["points"])
    tri_offsets = np.cumsum([0] + [len(p["points"]) for p in parts[:-1]])
    joined = {key: np.concatenate([p[key] for p in parts]) for key in ("points", "normals", "albedo", "emission", "sent")}
    arrays = SceneArrays(
        **{key: joined[key] for key in ("points", "normals", "albedo", "emission")},
        triangles=np.concatenate([p["triangles"] + o for p, o in zip(parts, tri_offsets)]).astype(np.int64),
        sky=reading.sky, sky_map=reading.sky_map, lights=reading.lights,
        point_object=np.repeat(np.arange(len(parts)), [len(p["points"]) for p in parts]),
        object_names=[p["name"] for p in parts],
        back=np.concatenate([p["back"] for p in parts]) if any(p["back"].any() for p in parts) else None,
        reflectance=None if np.array_equal(joined["sent"], joined["albedo"]) else joined["sent"],  # all diffuse: the albedo
    )
    notes = reading.notes
    arrays.dark = _set_aside_non_finite(arrays, parts, notes)
    return CollectedScene(arrays, targets, list(dict.fromkeys(notes)), reading.moving)  # each note once


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
    for colours in (arrays.albedo, arrays.emission, arrays.reflectance):
        if colours is not None:
            colours[bad] = 0.0
    return bad


def vertex_areas(ob):
    """Each vertex's share of the object's world-space surface area, ``(v,)``."""
    mesh = ob.data
    mesh.calc_loop_triangles()
    m = np.array(ob.matrix_world, dtype=np.float64)
    co = read_meshes.vertex_positions(mesh) @ m[:3, :3].T
    tri = np.empty(len(mesh.loop_triangles) * 3, dtype=np.int64)
    mesh.loop_triangles.foreach_get("vertices", tri)
    tri = tri.reshape(-1, 3)
    p = co[tri]
    area = 0.5 * np.linalg.norm(cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    return np.bincount(tri.ravel(), np.repeat(area / 3.0, 3), minlength=len(mesh.vertices))


def scored_areas(targets, arrays):
    """Per target (by object name), each vertex's area (:func:`vertex_areas`), zero where its
    material is black or has no diffuse closure (metal, glass: ``read_materials.no_diffuse``):
    Cycles' Diffuse bake reports no light there, so comparisons with it leave them out."""
    import bpy

    out = {}
    for target in targets:
        ob = bpy.data.objects[target.object_name]
        albedo = attributes.vertex_values(target, arrays.albedo)
        out[target.object_name] = np.where((albedo.max(axis=1) > 0.0) & ~read_materials.no_diffuse_vertices(ob), vertex_areas(ob), 0.0)
    return out
