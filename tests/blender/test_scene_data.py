"""Scene to arrays: albedo from textures and colour attributes, emission, world, lights,
modifiers, instances and objects hidden from render."""

import bpy
import numpy as np
import pytest
import scenes


def _collect(cubegi):
    return cubegi.cubegi_addon.scene_data.collect(bpy.context)


def _quad(name, x0, mat=None):
    v, f = scenes.grid_patch((x0, 0, 0), (1, 0, 0), (0, 1, 0), 1, 1)
    return scenes.mesh_object(name, v, f, mat)


def test_albedo_from_image_texture_at_uvs(empty_scene, cubegi):
    ob = _quad("Quad", 0.0)
    uv = ob.data.uv_layers.new(name="UVMap")
    image = bpy.data.images.new("Tex", 2, 1, float_buffer=True)  # left texel red, right blue
    image.colorspace_settings.name = "Linear Rec.709"
    image.pixels.foreach_set(np.array([1, 0, 0, 1, 0, 0, 1, 1], dtype=np.float32))
    mat = scenes.material("Textured", (0.5, 0.5, 0.5))
    tree = mat.node_tree
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = "Closest"
    bsdf = next(n for n in tree.nodes if n.type == "BSDF_PRINCIPLED")
    tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    ob.data.materials.append(mat)
    # Put every corner's UV in the left (red) or right (blue) texel by its x.
    co = np.array([ob.data.vertices[l.vertex_index].co.x for l in ob.data.loops])
    uvs = np.stack([np.where(co < 0.5, 0.25, 0.75), np.full_like(co, 0.5)], axis=1)
    uv.data.foreach_set("uv", uvs.astype(np.float32).ravel())
    arrays = _collect(cubegi).arrays
    left = arrays.points[:, 0] < 0.5
    np.testing.assert_allclose(arrays.albedo[left], [[1, 0, 0]] * left.sum(), atol=1e-6)
    np.testing.assert_allclose(arrays.albedo[~left], [[0, 0, 1]] * (~left).sum(), atol=1e-6)


def test_albedo_from_colour_attribute_emission_and_fallback(empty_scene, cubegi):
    a = _quad("A", 0.0)
    attr = a.data.color_attributes.new("Col", "FLOAT_COLOR", "POINT")
    attr.data.foreach_set("color", np.tile([0.1, 0.6, 0.3, 1.0], len(a.data.vertices)).astype(np.float32))
    mat = scenes.material("Attr", (0.5, 0.5, 0.5))
    node = mat.node_tree.nodes.new("ShaderNodeVertexColor")
    node.layer_name = "Col"
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    mat.node_tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
    a.data.materials.append(mat)
    _quad("B", 2.0, scenes.material("Glow", (0.2, 0.2, 0.2), emission=(1.0, 0.5, 0.25), strength=4.0))
    c = _quad("C", 4.0)
    odd = bpy.data.materials.new("Odd")
    odd.diffuse_color = (0.3, 0.2, 0.1, 1.0)
    if odd.node_tree is None:
        odd.use_nodes = True
    tree = odd.node_tree
    out = next(n for n in tree.nodes if n.type == "OUTPUT_MATERIAL")
    tree.links.new(tree.nodes.new("ShaderNodeBsdfGlass").outputs[0], out.inputs["Surface"])
    c.data.materials.append(odd)
    scenes.set_world((0.2, 0.3, 0.4))
    collected = _collect(cubegi)
    arr = collected.arrays
    x = arr.points[:, 0]
    # Each quad is a sheet: its 4 points and their 4 twins (the back side), alike in albedo
    # and emission (Cycles shades and lights both sides).
    assert arr.back is not None and arr.back.sum() == len(arr.points) // 2
    np.testing.assert_allclose(arr.albedo[x < 1.5], [[0.1, 0.6, 0.3]] * (x < 1.5).sum(), atol=1e-6)
    np.testing.assert_allclose(arr.emission[(x > 1.5) & (x < 3.5)], [[4.0, 2.0, 1.0]] * 8, atol=1e-6)
    np.testing.assert_allclose(arr.albedo[x > 3.5], [[0.3, 0.2, 0.1]] * 8, atol=1e-6)
    assert any("Odd" in n for n in collected.notes)
    np.testing.assert_allclose(arr.sky, [0.2, 0.3, 0.4], atol=1e-6)


def test_what_a_principled_bsdf_sends_on_is_read_from_its_specular_layer(empty_scene, cubegi):
    """Beside its albedo (the Base Color), each point keeps what it sends on: its specular
    layer's (cubegi_engine.specular) from the node's own Roughness, IOR and Specular IOR Level;
    a metallic one's is its albedo (no dielectric layer: baked as diffuse, with a note); a
    Diffuse BSDF's is its colour."""
    from cubegi.cubegi_engine import specular

    glossy = scenes.material("Glossy", (0.1, 0.3, 0.5))
    bsdf = next(n for n in glossy.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Roughness"].default_value, bsdf.inputs["Specular IOR Level"].default_value = 0.3, 0.8
    _quad("A", 0.0, glossy)
    metal = scenes.material("Metal", (0.6, 0.5, 0.4))
    next(n for n in metal.node_tree.nodes if n.type == "BSDF_PRINCIPLED").inputs["Metallic"].default_value = 1.0
    _quad("B", 2.0, metal)
    arr = _collect(cubegi).arrays
    x = arr.points[:, 0]
    layer = specular.layer(specular.facing_reflectance(bsdf.inputs["IOR"].default_value, 0.8), 0.3)
    expected = specular.sent_on(np.array([0.1, 0.3, 0.5]), *layer)
    assert np.all(expected > [0.1, 0.3, 0.5])
    np.testing.assert_allclose(arr.reflectance[x < 1.5], [expected] * (x < 1.5).sum(), atol=1e-6)
    np.testing.assert_allclose(arr.albedo[x < 1.5], [[0.1, 0.3, 0.5]] * (x < 1.5).sum(), atol=1e-6)
    np.testing.assert_allclose(arr.sent_on()[x > 1.5], arr.albedo[x > 1.5], atol=1e-6)


def test_modifiers_instances_and_hidden_objects(empty_scene, cubegi):
    base = _quad("Base", 0.0)
    base.modifiers.new("Subsurf", "SUBSURF").levels = 1  # changes vertex count: lights, not baked
    mirror_src = _quad("Deformed", 2.0)
    mirror_src.modifiers.new("Disp", "DISPLACE").strength = 0.5  # same count: baked
    hidden = _quad("Hidden", 4.0)
    hidden.hide_render = True
    coll = bpy.data.collections.new("Inst")
    inst_src = _quad("InstSrc", 0.0)
    bpy.context.scene.collection.objects.unlink(inst_src)
    coll.objects.link(inst_src)
    empty = bpy.data.objects.new("Instancer", None)
    empty.instance_type = "COLLECTION"
    empty.instance_collection = coll
    empty.location = (10, 0, 0)
    bpy.context.scene.collection.objects.link(empty)
    bpy.context.view_layer.update()
    collected = _collect(cubegi)
    baked = {t.object_name for t in collected.targets}
    assert baked == {"Deformed"}
    x = np.where(collected.arrays.back, np.nan, collected.arrays.points[:, 0])  # the front sides
    assert ((x >= 10) & (x <= 11)).sum() == 4  # the instance lights the scene
    assert not ((x >= 4) & (x <= 5)).any()  # hidden from render: not there
    assert collected.arrays.points[(x >= 2) & (x <= 3)][:, 2].max() == pytest.approx(0.25)  # displaced: strength x (1 - midlevel 0.5)
    assert any("Base" in n for n in collected.notes)
    assert "Instancer: its instances of InstSrc light the others but are not baked (Make Instances Real to bake them)" in collected.notes


def test_bake_takes_its_grid_from_the_probe_grid_object(empty_scene, cubegi):
    import json

    v, f = scenes.box_mesh((-2, -1, 0), (2, 1, 2), (4, 2, 2), inward=True)
    scenes.mesh_object("Room", v, f)
    scenes.add_light("POINT", (0.3, 0.2, 1.5), 50.0)
    assert bpy.ops.cubegi.add_probe_grid(resolution=(3, 2, 1)) == {"FINISHED"}
    grid = next(o for o in bpy.context.scene.objects if o.type == "EMPTY")
    assert grid.cubegi.is_probe_grid
    assert bpy.ops.cubegi.bake(bounces=1) == {"FINISHED"}
    report = json.loads(bpy.context.scene.cubegi.last_report)
    assert report["grid"]["resolution"] == [3, 2, 1]
    assert "probe grid object" in report["grid"]["source"]
    np.testing.assert_allclose(report["grid"]["lo"], [-2, -1, 0], atol=1e-5)
    np.testing.assert_allclose(report["grid"]["hi"], [2, 1, 2], atol=1e-5)


def test_several_probe_grids_each_point_uses_the_finest_that_contains_it(empty_scene, cubegi):
    import json

    grid_objects = cubegi.cubegi_addon.grid_objects
    v, f = scenes.box_mesh((-2, -1, 0), (2, 1, 2), (8, 4, 4), inward=True)
    scenes.mesh_object("Room", v, f)
    scenes.add_light("POINT", (0.3, 0.2, 1.5), 50.0)
    col = bpy.context.scene.collection
    grid_objects.new_probe_grid(col, (-2, -1, 0), (2, 1, 2), (2, 1, 1), name="Coarse")
    grid_objects.new_probe_grid(col, (0, -1, 0), (2, 1, 2), (4, 4, 4), name="Fine")
    # The near field is off: its rays would carry the finer grid's light across x = 0.
    assert bpy.ops.cubegi.bake(bounces=2, near_field=False) == {"FINISHED"}
    report = json.loads(bpy.context.scene.cubegi.last_report)
    assert [g["resolution"] for g in report["grid"]["grids"]] == [[2, 1, 1], [4, 4, 4]]
    assert report["grid"]["probes"] == 66 and "'Coarse', 'Fine'" in report["grid"]["source"]
    # The half x < 0 uses the coarse grid, less its probe at x = 1 (inside the fine grid's
    # box: that region is the fine grid's): the same light as a one-probe grid over that half
    # up to one scale (the bounce's energy factor is one number per channel for the whole
    # scene); the half x > 0 differs.
    mesh = bpy.data.objects["Room"].data
    both = cubegi.cubegi_addon.attributes.read(mesh, "CubeGI_bounce_1")
    bpy.data.objects.remove(bpy.data.objects["Fine"])
    bpy.data.objects.remove(bpy.data.objects["Coarse"])
    grid_objects.new_probe_grid(col, (-2, -1, 0), (0, 1, 2), (1, 1, 1), name="Left")
    assert bpy.ops.cubegi.bake(bounces=2, near_field=False) == {"FINISHED"}
    coarse = cubegi.cubegi_addon.attributes.read(mesh, "CubeGI_bounce_1")
    x = np.array([vv.co.x for vv in mesh.vertices])
    left, right = x < -0.01, x > 0.01
    scale = both[left].sum() / coarse[left].sum()
    np.testing.assert_allclose(both[left], scale * coarse[left], rtol=1e-4, atol=1e-6)
    assert np.abs(both[right] - scale * coarse[right]).max() > 0.05 * coarse[right].max()


def test_points_no_probe_lights_are_noted(empty_scene, cubegi):
    """A coarse grid whose only probe lies inside a finer grid's box: the coarse grid's points
    are left with no probe (that probe is the finer grid's region) and the report says so."""
    import json

    v, f = scenes.box_mesh((-2, -1, 0), (2, 1, 2), (8, 4, 4), inward=True)
    scenes.mesh_object("Room", v, f)
    scenes.add_light("POINT", (0.3, 0.2, 1.5), 50.0)
    col = bpy.context.scene.collection
    grid_objects = cubegi.cubegi_addon.grid_objects
    grid_objects.new_probe_grid(col, (-2, -1, 0), (2, 1, 2), (1, 1, 1), name="Coarse")
    grid_objects.new_probe_grid(col, (-0.5, -1, 0), (0.5, 1, 2), (2, 2, 2), name="Fine")
    assert bpy.ops.cubegi.bake(bounces=1, cube_size=8) == {"FINISHED"}
    notes = json.loads(bpy.context.scene.cubegi.last_report)["scene"]["notes"]
    said = [n for n in notes if "of the shading points get no probe light" in n]
    assert len(said) == 1 and "Room" in said[0], notes  # once


def test_corner_groups_are_numpys_unique_rows(cubegi):
    """Corners merge into shading points by (vertex, normal, material): the fast grouping
    gives np.unique's rows, first indices and inverse, in its order."""
    from cubegi.cubegi_addon.read_meshes import _groups

    rng = np.random.default_rng(4)
    for n in (0, 1, 7, 5000):
        vertex = rng.integers(0, max(n // 3, 1), n)
        normal = np.round(np.clip(rng.normal(size=(n, 3)), -1, 1) * 1e4).astype(np.int64)
        normal[::3] = normal[:1] if n else normal[::3]  # many shared normals, negative parts
        material = rng.integers(0, 40, n)
        key = np.concatenate([vertex[:, None], normal, material[:, None]], axis=1)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        got_first, got_inverse = _groups(vertex, normal, material)
        np.testing.assert_array_equal(got_first, first)
        np.testing.assert_array_equal(got_inverse, inverse.ravel())


def test_two_grid_objects_whose_probes_all_stay_store_no_probe_offsets(empty_scene, cubegi):
    """Two grid objects side by side, every probe lighting a vertex and none moved: the
    field's grid stays a grid set, and neither object gets a stored probe offset (a grid
    set's first probe indices were once stored on the first one as moves)."""
    grid_objects = cubegi.cubegi_addon.grid_objects
    v, f = scenes.box_mesh((-2, -1, 0), (2, 1, 2), (8, 4, 4), inward=True)
    scenes.mesh_object("Room", v, f)
    scenes.add_light("POINT", (0.3, 0.2, 1.5), 50.0)
    col = bpy.context.scene.collection
    grid_objects.new_probe_grid(col, (-2, -1, 0), (0, 1, 2), (2, 2, 2), name="Left")
    grid_objects.new_probe_grid(col, (0, -1, 0), (2, 1, 2), (2, 2, 2), name="Right")
    assert bpy.ops.cubegi.bake(bounces=1, move_probes=False) == {"FINISHED"}
    field = cubegi.cubegi_addon.session.kept(bpy.context.scene).bake.result.field.whole()
    assert len(field.grid.parts()) == 2 and not np.any(field.grid.displacements())
    for ob in grid_objects.probe_grid_objects(bpy.context.scene):
        assert grid_objects.OFFSET_KEY not in ob, ob.name
        assert grid_objects.stored_probe_light(ob) is not None


def _large_mixed_scene():
    """Two 250K-corner grids, one of two materials and flat-shaded, one mirrored, with
    coincident seams: a scene whose arrays take a while to make."""
    red, blue = scenes.material("Red", (0.8, 0.1, 0.1)), scenes.material("Blue", (0.1, 0.1, 0.8))
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=250, y_subdivisions=250, size=2.0)
    a = bpy.context.object
    a.data.materials.append(red)
    a.data.materials.append(blue)
    a.data.polygons.foreach_set("material_index", (np.arange(len(a.data.polygons)) % 3 == 0).astype(np.int32))
    a.data.polygons.foreach_set("use_smooth", np.zeros(len(a.data.polygons), dtype=bool))
    bpy.ops.mesh.primitive_uv_sphere_add(segments=256, ring_count=128, location=(0.0, 0.0, 1.0))
    b = bpy.context.object
    b.scale = (-1.0, 1.0, 1.0)  # mirrored
    b.data.materials.append(blue)
    return a, b


def test_the_fast_mesh_readers_read_what_blenders_plain_api_gives(empty_scene, cubegi):
    """Corners' vertices from the ``.corner_vert`` attribute, triangle materials from the face
    attribute, positions as float32: the same numbers as ``loops``' ``vertex_index``, the loop
    triangles' ``material_index`` and a float64 read of ``co`` (on every Blender version: a
    version without the attribute takes the plain path)."""
    sd = cubegi.cubegi_addon.read_meshes
    for ob in _large_mixed_scene():
        mesh = ob.data
        mesh.calc_loop_triangles()
        plain = np.empty(len(mesh.loops), dtype=np.int64)
        mesh.loops.foreach_get("vertex_index", plain)
        np.testing.assert_array_equal(sd.corner_vertices(mesh), plain)
        tri_mat = np.empty(len(mesh.loop_triangles), dtype=np.int64)
        mesh.loop_triangles.foreach_get("material_index", tri_mat)
        np.testing.assert_array_equal(sd._triangle_materials(mesh), tri_mat)
        co = np.empty(len(mesh.vertices) * 3)
        mesh.vertices.foreach_get("co", co)
        np.testing.assert_array_equal(sd.vertex_positions(mesh), co.reshape(-1, 3))
    assert len(np.unique(tri_mat)) == 1 and len(np.unique(sd._triangle_materials(_large_mixed_scene()[0].data))) == 2


def test_welding_by_hash_groups_positions_as_numpys_unique_rows(cubegi):
    """``_welded`` labels positions as ``np.unique(axis=0)`` groups them, on a float32 grid's
    positions (regular bits, where a weak hash collides) with duplicates, -0.0 and NaN."""
    sd = cubegi.cubegi_addon.read_meshes
    rng = np.random.default_rng(5)
    grid = np.stack(np.meshgrid(*[np.linspace(-1, 1, 80, dtype=np.float32)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    co = np.concatenate([grid, grid[:1000], -0.0 * grid[:1]]).astype(np.float64)[rng.permutation(len(grid) + 1001)]
    for points in (co, np.concatenate([co, [[np.nan, 0.0, 0.0], [np.nan, 0.0, 0.0]]])):
        labels = sd._welded(points)
        expected = np.unique(points + 0.0, axis=0, return_inverse=True)[1].ravel()
        # Same partition: a label maps to one expected label and back.
        pairs = np.unique(np.stack([labels, expected], axis=1), axis=0)
        assert len(pairs) == len(np.unique(labels)) == len(np.unique(expected)), len(pairs)


def test_a_large_scene_is_read_in_steps_and_gives_the_arrays_of_one_read(empty_scene, cubegi, monkeypatch):
    """A stepped bake reads Blender's data in one step and makes the arrays in a thread,
    handing control back meanwhile; the arrays and targets are those of ``collect``. The
    renderer is uploaded in steps too (a column at a time) and draws what one made at
    once draws."""
    from cubegi.cubegi_engine import cubemap
    from cubegi.cubegi_engine.records import Progress, Stage

    _large_mixed_scene()
    sd, gc = cubegi.cubegi_addon.scene_data, cubegi.cubegi_addon.gpu_capture
    working = Progress(Stage.CAPTURE, 0, 1, "reading the scene", working=True)
    steps = sd.collect_steps(bpy.context, working)
    count = 0
    while True:
        try:
            assert next(steps) is working
            count += 1
        except StopIteration as stop:
            stepped = stop.value
            break
    whole = sd.collect(bpy.context)
    assert count >= 1  # control went back while the arrays were made
    for name in ("points", "normals", "albedo", "emission", "triangles", "point_object", "back"):
        np.testing.assert_array_equal(getattr(stepped.arrays, name), getattr(whole.arrays, name), err_msg=name)
    assert [(t.object_name, t.mesh_name) for t in stepped.targets] == [(t.object_name, t.mesh_name) for t in whole.targets]
    for a, b in zip(stepped.targets, whole.targets):
        np.testing.assert_array_equal(a.loop_point, b.loop_point)
    assert stepped.notes == whole.notes

    arrays = whole.arrays
    # (The arrays made in a thread hand control back as often as that takes: not counted here.)
    monkeypatch.setattr(cubegi.cubegi_engine.working, "WORKING_SECONDS", 3600.0)
    steps = gc.GpuRenderer.steps(arrays.points, arrays.triangles, working, sheet=arrays.sheet_triangles())
    uploads = 0
    while True:
        try:
            next(steps)
            uploads += 1
        except StopIteration as stop:
            renderer = stop.value
            break
    assert uploads == 2  # a step between the batch's two vertex columns, and one before its indices
    once = gc.GpuRenderer(arrays.points, arrays.triangles, sheet=arrays.sheet_triangles())
    eye = np.array([[0.3, -0.2, 2.5]])
    vps = cubemap.cube_view_projections_many(eye, 0.01, 10.0, None)
    for with_bary in (True, False):
        got = renderer.render(vps, np.repeat(eye, 6, axis=0), None, 32, with_bary=with_bary)
        want = once.render(vps, np.repeat(eye, 6, axis=0), None, 32, with_bary=with_bary)
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, w)
        assert (got[0] >= 0).mean() > 0.05  # the views see the scene (the sphere below)
