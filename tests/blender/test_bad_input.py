"""Bad or odd input through the operator: a correct result or one clear error, never NaN."""

import json

import bpy
import numpy as np
import pytest
import scenes


def _bake(**kw):
    return bpy.ops.cubegi.bake(bounces=2, grid=(2, 2, 2), cube_size=8, **kw)


def _all_values(cubegi):
    read = cubegi.cubegi_addon.attributes.read
    out = {}
    for ob in bpy.context.scene.objects:
        if ob.type == "MESH":
            for name in ("CubeGI_direct", "CubeGI"):
                if name in ob.data.attributes:
                    out[(ob.name, name)] = read(ob.data, name)
    return out


def _notes():
    return json.loads(bpy.context.scene.cubegi.last_report)["scene"]["notes"]


def test_empty_scene_is_one_clear_error(empty_scene, cubegi):
    with pytest.raises(RuntimeError, match="no visible geometry"):
        _bake()


def test_no_lights_and_a_black_world_give_zeros(empty_scene, cubegi):
    scenes.cornell(light=False)
    assert _bake() == {"FINISHED"}
    values = _all_values(cubegi)
    assert values and all((v == 0).all() for v in values.values())


@pytest.mark.filterwarnings("error::RuntimeWarning")  # no NaN reaches the arithmetic: each step leaves such points out
def test_nan_and_inf_vertices_get_no_light_and_spoil_nothing(empty_scene, cubegi):
    scenes.cornell(light=True)
    mesh = bpy.data.objects["Tall"].data
    mesh.vertices[0].co = (float("nan"), 0.0, 0.0)
    mesh.vertices[1].co = (0.0, float("inf"), 0.0)
    assert _bake() == {"FINISHED"}
    values = _all_values(cubegi)
    assert all(np.isfinite(v).all() and (v >= 0).all() for v in values.values())
    tall = values[("Tall", "CubeGI_direct")]
    assert (tall[:2] == 0).all() and tall[2:].max() > 0
    assert values[("Floor", "CubeGI_direct")].mean() > 0
    assert any("NaN or Inf" in n and n.startswith("Tall") for n in _notes())


def test_degenerate_meshes_bake_finite(empty_scene, cubegi):
    scenes.cornell(light=True)
    # zero-area faces and a duplicated vertex
    scenes.mesh_object("Degenerate", [(0, 0, 0.5), (0.5, 0, 0.5), (1, 0, 0.5), (0, 0, 0.5)], [(0, 1, 2), (0, 1, 3)])
    scenes.mesh_object("NoFaces", [(0, 0, 1), (0.1, 0, 1)], [])
    me = bpy.data.meshes.new("Loose")  # a triangle, a loose edge and loose vertices
    me.from_pydata([(0, 0, 1), (0.5, 0, 1), (0.3, 0.3, 1), (0.9, 0.9, 1.5), (0.8, 0.9, 1.5), (0.1, 0.1, 0.1)], [(3, 4)], [(0, 1, 2)])
    bpy.context.scene.collection.objects.link(bpy.data.objects.new("Loose", me))
    assert _bake() == {"FINISHED"}
    values = _all_values(cubegi)
    assert all(np.isfinite(v).all() and (v >= 0).all() for v in values.values())
    assert values[("Floor", "CubeGI_direct")].mean() > 0


def test_curves_and_text_light_the_scene_and_are_noted(empty_scene, cubegi):
    scenes.cornell(light=True)
    bpy.ops.curve.primitive_bezier_circle_add(location=(0, 0, 1))
    bpy.ops.object.text_add(location=(0, 0.5, 1))
    assert _bake() == {"FINISHED"}
    notes = _notes()
    assert any(n.startswith("Text: font object lit and lighting others") for n in notes), notes
    assert any(n.startswith("B\u00e9zierCircle: curve object has no surface") for n in notes), notes


def test_objects_hidden_from_render_are_left_out(empty_scene, cubegi):
    scenes.cornell(light=True)
    bpy.data.objects["Tall"].hide_render = True
    assert _bake() == {"FINISHED"}
    assert "CubeGI" not in bpy.data.objects["Tall"].data.attributes
    assert "Tall" not in json.loads(bpy.context.scene.cubegi.last_report)["scene"]["meshes_baked"]


@pytest.mark.parametrize("kw,needle", [(dict(cube_size=2), "cube-map size"), (dict(cube_size=1024), "cube-map size")])
def test_out_of_range_settings_are_refused_and_change_nothing(empty_scene, cubegi, kw, needle):
    scenes.cornell(light=True)
    before = {ob.name: sorted(a.name for a in ob.data.attributes) for ob in bpy.context.scene.objects if ob.type == "MESH"}
    with pytest.raises(RuntimeError, match=needle):
        bpy.ops.cubegi.bake(**kw)
    after = {ob.name: sorted(a.name for a in ob.data.attributes) for ob in bpy.context.scene.objects if ob.type == "MESH"}
    assert after == before


def test_a_grid_too_large_for_memory_is_refused_with_the_estimate(empty_scene, cubegi):
    scenes.cornell(light=True)
    before = sorted(a.name for a in bpy.data.objects["Floor"].data.attributes)
    with pytest.raises(RuntimeError, match=r"would need about [\d.]+ GiB"):
        bpy.ops.cubegi.bake(grid=(200, 200, 200), cube_size=512)  # the probes around its vertices alone: terabytes
    assert sorted(a.name for a in bpy.data.objects["Floor"].data.attributes) == before


def test_memory_estimate_by_hand():
    from cubegi.cubegi_engine import bake

    # 10 probes of 6 x 32^2 texels at 80 bytes, 100 points at 8 x 8 x 9 x 4 + 400 = 2704 bytes.
    assert bake.memory_estimate(10, 32, 100) == 10 * 6 * 1024 * 80 + 100 * 2704
    with pytest.raises(ValueError, match="more than half"):
        bake.check_memory(10, 32, 100, limit=2 * bake.memory_estimate(10, 32, 100) - 2)
    assert bake.check_memory(10, 32, 100, limit=10**12) > 0


@pytest.mark.parametrize("res", [(1, 1, 1), (1, 1, 2)])
def test_one_probe_or_a_line_of_probes_bakes(empty_scene, cubegi, res):
    scenes.cornell(light=True)
    assert bpy.ops.cubegi.bake(bounces=2, grid=res, cube_size=8) == {"FINISHED"}
    values = _all_values(cubegi)
    assert all(np.isfinite(v).all() for v in values.values())
    assert values[("Floor", "CubeGI")].mean() > 0


def test_materials_without_nodes_or_with_unknown_shaders_fall_back_to_the_viewport_colour(empty_scene, cubegi):
    scenes.cornell(light=True)
    bare = bpy.data.materials.new("Bare")
    bare.diffuse_color = (0.2, 0.2, 0.2, 1.0)
    if bare.node_tree is None:
        bare.use_nodes = True
    bare.node_tree.nodes.clear()
    glass = bpy.data.materials.new("Glass")
    glass.diffuse_color = (0.9, 0.9, 0.9, 1.0)
    if glass.node_tree is None:
        glass.use_nodes = True
    nodes = glass.node_tree.nodes
    out = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
    for n in [n for n in nodes if n != out]:
        nodes.remove(n)
    glass.node_tree.links.new(nodes.new("ShaderNodeBsdfGlass").outputs[0], out.inputs["Surface"])
    bpy.data.objects["Tall"].data.materials[0] = bare
    bpy.data.objects["Short"].data.materials[0] = glass
    assert _bake() == {"FINISHED"}
    notes = _notes()
    assert any("'Bare': no node surface, using its viewport colour" in n for n in notes), notes
    assert any("'Glass': shader ShaderNodeBsdfGlass not understood" in n for n in notes), notes
    assert all(np.isfinite(v).all() for v in _all_values(cubegi).values())


def test_a_probe_grid_with_no_geometry_inside_is_refused(empty_scene, cubegi):
    scenes.cornell(light=True)
    cubegi.cubegi_addon.grid_objects.new_probe_grid(bpy.context.scene.collection, (10, 10, 10), (12, 12, 12), (2, 2, 2))
    with pytest.raises(RuntimeError, match="contains no geometry"):
        bpy.ops.cubegi.bake(bounces=1, cube_size=8)
    assert "CubeGI" not in bpy.data.objects["Floor"].data.attributes


def test_geometry_outside_the_grid_gets_the_nearest_probes_and_a_note(empty_scene, cubegi):
    scenes.cornell(light=True)
    # A grid over the lower half of the box only.
    cubegi.cubegi_addon.grid_objects.new_probe_grid(bpy.context.scene.collection, (-1, -1, 0), (1, 1, 1), (2, 2, 2))
    assert bpy.ops.cubegi.bake(bounces=2, cube_size=8) == {"FINISHED"}
    assert any("lie outside every probe grid" in n for n in _notes())
    ceiling = cubegi.cubegi_addon.attributes.read(bpy.data.objects["Ceiling"].data, "CubeGI")
    assert np.isfinite(ceiling).all() and ceiling.mean() > 0


def _flip(ob, faces):
    import bmesh

    bm = bmesh.new()
    bm.from_mesh(ob.data)
    bm.faces.ensure_lookup_table()
    bmesh.ops.reverse_faces(bm, faces=[bm.faces[i] for i in faces])
    bm.to_mesh(ob.data)
    bm.free()


def test_flipped_normals_are_named_in_a_note_and_bake_finite(empty_scene, cubegi):
    box = scenes.closed_box(albedo=0.5, cells=4)
    scenes.add_light("POINT", (0.3, -0.2, 0.4), 10.0)
    assert _bake() == {"FINISHED"}
    assert not any("back faces" in n for n in _notes())
    right = _all_values(cubegi)[("Box", "CubeGI")].mean()
    # Half the box's faces turned outward: the probes see their backs.
    _flip(box, range(0, len(box.data.polygons), 2))
    assert _bake() == {"FINISHED"}
    (note,) = [n for n in _notes() if n.startswith("Box: ")]
    assert "back faces" in note and "Recalculate" in note
    values = _all_values(cubegi)
    assert all(np.isfinite(v).all() and (v >= 0).all() for v in values.values())
    # Back faces pass on no light, so the box holds less indirect light than with its
    # normals right (Cycles would reflect from both sides: the note says so).
    assert values[("Box", "CubeGI")].mean() < right


def _open_box(name, lo, hi, open_x):
    """A room (inward normals) without its wall at x = open_x."""
    v, f = scenes.box_mesh(lo, hi, (4, 4, 4), inward=True)
    v = np.asarray(v, dtype=np.float64)
    f = [face for face in f if not np.allclose(v[list(face), 0], open_x)]
    return scenes.mesh_object(name, v.tolist(), f, scenes.material(name, (0.8, 0.8, 0.8)))


def test_a_one_sided_wall_between_rooms_lets_no_light_through(empty_scene, cubegi):
    """A single plane, no thickness, closes a lit room and a sealed one (each open towards
    it, the sealed one 1 cm away): a sheet, shaded on both sides as Cycles shades it; its side
    towards the sealed room gets no light (nothing passes through a diffuse sheet), and the
    sealed room stays black. No face is seen from behind, so there is no note."""
    _open_box("Lit", (0, -1, 0), (2, 1, 2), 0.0)
    _open_box("Sealed", (-2, -1, 0), (-0.01, 1, 2), -0.01)
    scenes.mesh_object("Wall", [(0, -1, 0), (0, 1, 0), (0, 1, 2), (0, -1, 2)], [(0, 1, 2, 3)])  # faces +X
    scenes.add_light("POINT", (1.0, 0.0, 1.0), 50.0)
    assert bpy.ops.cubegi.bake(bounces=2, grid=(4, 2, 2), cube_size=16) == {"FINISHED"}
    read = cubegi.cubegi_addon.attributes.read
    lit = read(bpy.data.objects["Lit"].data, "CubeGI_total").mean()
    sealed = read(bpy.data.objects["Sealed"].data, "CubeGI_total")
    assert lit > 0 and sealed.max() <= 1e-3 * lit, sealed.max() / lit
    assert not any(n.startswith("Wall: ") and "back faces" in n for n in _notes())


def test_linked_library_meshes_light_the_scene_but_are_not_written(empty_scene, cubegi, tmp_path):
    lib_path = tmp_path / "library.blend"
    v, f = scenes.box_mesh((-0.3, -0.3, 0.0), (0.3, 0.3, 0.6), (2, 2, 2), inward=False)
    scenes.mesh_object("Crate", v, f, scenes.material("Red", (0.8, 0.1, 0.1)))
    bpy.ops.wm.save_as_mainfile(filepath=str(lib_path))
    library_bytes = lib_path.read_bytes()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scenes.closed_box(albedo=0.5, cells=4)
    scenes.add_light("POINT", (0.3, -0.2, 0.4), 10.0)
    assert _bake() == {"FINISHED"}
    without = _all_values(cubegi)[("Box", "CubeGI")]
    with bpy.data.libraries.load(str(lib_path), link=True) as (src, dst):
        dst.objects = ["Crate"]
    bpy.context.scene.collection.objects.link(dst.objects[0])
    assert dst.objects[0].data.library is not None
    assert _bake() == {"FINISHED"}
    note = [n for n in _notes() if "linked from" in n]
    assert len(note) == 1 and note[0].startswith("Crate: ") and "not baked" in note[0]
    assert not any(a.name.startswith("CubeGI") for a in dst.objects[0].data.attributes)
    report = json.loads(bpy.context.scene.cubegi.last_report)
    assert report["scene"]["meshes_baked"] == ["Box"]
    # The crate is there for the light: the box's indirect light changes.
    assert np.abs(_all_values(cubegi)[("Box", "CubeGI")] - without).max() > 1e-3 * without.max()
    assert lib_path.read_bytes() == library_bytes


def test_a_light_with_nan_or_negative_power_is_skipped_with_a_note(empty_scene, cubegi, tmp_path):
    v, f = scenes.box_mesh((-2, -2, 0), (2, 2, 2.5), (4, 4, 3), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    scenes.add_light("POINT", (0.3, 0.2, 1.5), 80.0)
    assert bpy.ops.cubegi.bake(grid=(2, 2, 2), bounces=2, cube_size=8) == {"FINISHED"}
    alone = cubegi.cubegi_addon.attributes.read(bpy.data.objects["Room"].data, "CubeGI_total")
    nan = scenes.add_light("POINT", (0.0, 0.0, 1.0), 50.0)
    nan.location.x = float("nan")
    negative = scenes.add_light("SUN", (0.0, 0.0, 2.0), 1.0)
    negative.data.energy = -3.0
    report_path = tmp_path / "r.json"
    assert bpy.ops.cubegi.bake(grid=(2, 2, 2), bounces=2, cube_size=8, report_path=str(report_path)) == {"FINISHED"}
    with_bad = cubegi.cubegi_addon.attributes.read(bpy.data.objects["Room"].data, "CubeGI_total")
    np.testing.assert_allclose(with_bad, alone, rtol=1e-6)  # the valid light's light, whole
    notes = json.loads(report_path.read_text())["scene"]["notes"]  # strict JSON
    assert any(nan.name in n and "NaN or Inf" in n for n in notes), notes
    assert any(negative.name in n and "negative power" in n for n in notes), notes


def _hide_wall(how):
    """Hide the thin-wall scene's wall in the viewport only: H, the monitor toggle, or its
    collection's eye and monitor."""
    wall = bpy.data.objects["Wall"]
    if how == "hide_set":
        wall.hide_set(True)
    elif how == "hide_viewport":
        wall.hide_viewport = True
    else:
        coll = bpy.data.collections.new("Walls")
        bpy.context.scene.collection.children.link(coll)
        coll.objects.link(wall)
        bpy.context.scene.collection.objects.unlink(wall)
        bpy.context.view_layer.layer_collection.children["Walls"].hide_viewport = True  # the eye
        coll.hide_viewport = True  # the monitor: disabled in viewports
    return wall


def _assert_hidden(wall, how):
    if how == "hide_set":
        assert wall.hide_get()
    elif how == "hide_viewport":
        assert wall.hide_viewport
    else:
        assert bpy.context.view_layer.layer_collection.children["Walls"].hide_viewport
        assert bpy.data.collections["Walls"].hide_viewport


@pytest.mark.parametrize("how", ["hide_set", "hide_viewport", "collection"])
def test_objects_hidden_only_in_the_viewport_bake_as_they_render(empty_scene, cubegi, how):
    """The render's view of the scene decides: a wall hidden in the viewport (H, the monitor
    toggle, or its collection hidden) still shadows, still receives light, and stays hidden."""
    scenes.thin_wall()
    settings = dict(grid=(4, 2, 2), bounces=2, cube_size=8)
    assert bpy.ops.cubegi.bake(**settings) == {"FINISHED"}
    read = cubegi.cubegi_addon.attributes.read
    shown = {n: read(bpy.data.objects[n].data, "CubeGI_total") for n in ("Rooms", "Wall")}
    cubegi.cubegi_addon.session.forget()
    bpy.ops.cubegi.clear()
    wall = _hide_wall(how)
    assert bpy.ops.cubegi.bake(**settings) == {"FINISHED"}
    for name, values in shown.items():
        np.testing.assert_allclose(read(bpy.data.objects[name].data, "CubeGI_total"), values, rtol=1e-5, atol=1e-7)
    _assert_hidden(wall, how)


def test_show_in_renders_does_not_change_the_next_bake(empty_scene, cubegi):
    """A bake reads a wired material through CubeGI's own wiring: same light, no note."""
    scenes.cornell(light=True)
    settings = dict(grid=(3, 3, 3), bounces=2, cube_size=8)
    assert bpy.ops.cubegi.bake(**settings) == {"FINISHED"}
    read = cubegi.cubegi_addon.attributes.read
    before = {ob.name: read(ob.data, "CubeGI") for ob in bpy.context.scene.objects if ob.type == "MESH"}
    assert bpy.ops.cubegi.wire_materials() == {"FINISHED"}
    assert bpy.ops.cubegi.bake(**settings) == {"FINISHED"}
    assert not json.loads(bpy.context.scene.cubegi.last_report)["scene"]["notes"]
    for name, values in before.items():
        np.testing.assert_allclose(read(bpy.data.objects[name].data, "CubeGI"), values, rtol=1e-6, atol=1e-9, err_msg=name)


def test_a_modifier_that_reorders_vertices_is_not_baked_onto_the_wrong_ones(empty_scene, cubegi):
    v, f = scenes.box_mesh((-2, -2, 0), (2, 2, 2.5), (4, 4, 3), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    bv, bf = scenes.box_mesh((-0.5, -0.5, 0.0), (0.5, 0.5, 1.0), (2, 2, 2), inward=False)
    block = scenes.mesh_object("Block", bv, bf)
    scenes.add_light("POINT", (0.3, 0.2, 1.8), 80.0)
    tree = bpy.data.node_groups.new("Sort", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes = tree.nodes
    gin, gout = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    sort, pos, xyz = nodes.new("GeometryNodeSortElements"), nodes.new("GeometryNodeInputPosition"), nodes.new("ShaderNodeSeparateXYZ")
    tree.links.new(gin.outputs[0], sort.inputs["Geometry"])
    tree.links.new(pos.outputs[0], xyz.inputs[0])
    tree.links.new(xyz.outputs["Z"], sort.inputs["Sort Weight"])
    tree.links.new(sort.outputs[0], gout.inputs[0])
    block.modifiers.new("Sort", "NODES").node_group = tree
    evaluated = block.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh()
    assert len(evaluated.vertices) == len(block.data.vertices)  # the count is kept ...
    order = np.empty(len(evaluated.loops), dtype=np.int64)
    evaluated.loops.foreach_get("vertex_index", order)
    original = np.empty(len(block.data.loops), dtype=np.int64)
    block.data.loops.foreach_get("vertex_index", original)
    assert not np.array_equal(order, original)  # ... the order is not
    block.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh_clear()
    assert bpy.ops.cubegi.bake(grid=(2, 2, 2), bounces=1, cube_size=8) == {"FINISHED"}
    assert "CubeGI" not in block.data.attributes and "CubeGI" in bpy.data.objects["Room"].data.attributes
    notes = json.loads(bpy.context.scene.cubegi.last_report)["scene"]["notes"]
    assert any(n.startswith("Block: modifiers change its vertex count or order") for n in notes), notes


def test_material_inputs_cubegi_cannot_read_are_named_in_notes(empty_scene, cubegi):
    """Each fallback says which input of which material, and what was used instead; a Value
    node feeding Emission Strength is read (it used to be ignored: 50x too dark)."""
    def principled(name, **values):
        mat = scenes.material(name, (0.5, 0.5, 0.5))
        bsdf = mat.node_tree.nodes["Principled BSDF"]
        for key, value in values.items():
            bsdf.inputs[key].default_value = value
        return mat, bsdf

    mixed, bsdf = principled("Mixed")
    mix = mixed.node_tree.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mixed.node_tree.links.new(mix.outputs["Result"], bsdf.inputs["Base Color"])
    glowing, bsdf = principled("Glowing", **{"Emission Color": (1.0, 1.0, 1.0, 1.0), "Emission Strength": 1.0})
    value = glowing.node_tree.nodes.new("ShaderNodeValue")
    value.outputs[0].default_value = 50.0
    glowing.node_tree.links.new(value.outputs[0], bsdf.inputs["Emission Strength"])
    mathed, bsdf = principled("Mathed", **{"Emission Color": (1.0, 1.0, 1.0, 1.0)})
    mathed.node_tree.links.new(mathed.node_tree.nodes.new("ShaderNodeMath").outputs[0], bsdf.inputs["Emission Strength"])
    missing, bsdf = principled("Missing")
    tex = missing.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = bpy.data.images.new("brick.png", 4, 4)
    tex.image.source, tex.image.filepath = "FILE", "/nonexistent/brick.png"  # as a file moved away
    missing.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    metal, _ = principled("Metal", Metallic=1.0)
    glass, _ = principled("Glass", **{"Transmission Weight": 1.0})
    for k, mat in enumerate((mixed, glowing, mathed, missing, metal, glass)):
        v, f = scenes.box_mesh((3 * k, 0, 0), (3 * k + 1, 1, 1), (1, 1, 1), inward=False)
        scenes.mesh_object(mat.name, v, f, mat)
    scenes.add_light("SUN", (0, 0, 5), 2.0)
    assert bpy.ops.cubegi.bake(grid=(2, 2, 2), bounces=1, cube_size=8) == {"FINISHED"}
    notes = json.loads(bpy.context.scene.cubegi.last_report)["scene"]["notes"]
    expected = [
        "material 'Mixed': Base Color fed by a Mix node, which CubeGI does not read; using its viewport colour",
        "material 'Mathed': Emission Strength fed by a Math node, which CubeGI does not read; using 0",
        "material 'Missing': Base Color image 'brick.png' has no pixels (missing file?); using its viewport colour",
        "material 'Metal': Metallic is set; CubeGI bakes it as a diffuse surface, which a metallic surface is not",
        "material 'Glass': Transmission Weight is set; CubeGI bakes it as a diffuse surface, which a transmissive surface is not",
    ]
    for line in expected:
        assert line in notes, (line, [n for n in notes if n.startswith(line[:18])])
    assert not any("'Glowing'" in n for n in notes), notes
    collected = cubegi.cubegi_addon.scene_data.collect(bpy.context)
    owner = collected.arrays.point_object == collected.arrays.object_names.index("Glowing")
    np.testing.assert_allclose(collected.arrays.emission[owner], 50.0)  # the Value node's strength


def test_an_emitter_too_small_for_the_probes_still_lights_the_scene(empty_scene, cubegi):
    """A 2 mm triangle of strength 1e6: the probes' texels miss it, but emissive triangles
    light the points directly as area lights (exact form factors), so its light is there
    (it used to be lost: 0 everywhere)."""
    v, f = scenes.box_mesh((-2, -2, 0), (2, 2, 2.5), (4, 4, 3), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    tiny = np.array([[0.0, 0.0, 1.5], [0.002, 0.0, 1.5], [0.0, 0.002, 1.5]])
    scenes.mesh_object("Spark", tiny, [[0, 2, 1]], scenes.material("Hot", (0, 0, 0), emission=(1, 1, 1), strength=1e6))
    assert bpy.ops.cubegi.bake(grid=(2, 2, 2), bounces=1, cube_size=8) == {"FINISHED"}
    direct = cubegi.cubegi_addon.attributes.read(bpy.data.objects["Room"].data, "CubeGI_direct")
    # Its power over the room: 2e-6 m^2 x 1e6 x pi (both faces) ~ 6 W: the floor 1.5 m below
    # gets about L A cos / (pi d^2) = 1e6 x 2e-6 / (pi 2.25) = 0.28 at the centre.
    assert direct.max() > 0.1 and np.isfinite(direct).all()


def test_a_linked_world_colour_is_read_or_noted(empty_scene, cubegi):
    read = cubegi.cubegi_addon.scene_data.collect
    v, f = scenes.grid_patch((-1, -1, 0), (2, 0, 0), (0, 2, 0), 2, 2)
    scenes.mesh_object("Ground", v, f)
    world = scenes.set_world((0.05, 0.05, 0.05))
    tree = world.node_tree
    bg = tree.nodes["Background"]
    sky = tree.nodes.new("ShaderNodeTexSky")
    tree.links.new(sky.outputs["Color"], bg.inputs["Color"])
    collected = read(bpy.context)
    assert any("Background Color fed by a Sky Texture node" in n for n in collected.notes), collected.notes
    # An environment image: its solid-angle-weighted mean (top half 2.0, bottom half 0.0: 1.0)
    # and its pattern over that mean, which the probes see.
    image = bpy.data.images.new("env", 64, 32, float_buffer=True)
    px = np.zeros((32, 64, 4), dtype=np.float32)
    px[16:, :, :3] = 2.0  # image rows run bottom to top: the upper half of the sphere
    px[..., 3] = 1.0
    image.pixels.foreach_set(px.ravel())
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = image
    tree.links.new(env.outputs["Color"], bg.inputs["Color"])
    bg.inputs["Strength"].default_value = 0.5
    collected = read(bpy.context)
    np.testing.assert_allclose(collected.arrays.sky, 0.5, rtol=1e-6)
    pattern = collected.arrays.sky_map
    assert pattern.shape == (32, 64, 3)
    np.testing.assert_allclose(pattern[16:], 2.0, rtol=1e-6)
    np.testing.assert_allclose(pattern[:16], 0.0, atol=1e-7)
    assert not any("environment image" in n for n in collected.notes), collected.notes
    # The ground sees the bright half: more light than from a uniform sky of the same mean.
    assert bpy.ops.cubegi.bake(grid=(2, 2, 2), cube_size=16, bounces=1) == {"FINISHED"}
    directional = cubegi.cubegi_addon.attributes.read(bpy.data.objects["Ground"].data, "CubeGI_direct").mean()
    tree.links.remove(bg.inputs["Color"].links[0])
    bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)  # x 0.5 strength: the same mean
    assert bpy.ops.cubegi.bake(grid=(2, 2, 2), cube_size=16, bounces=1) == {"FINISHED"}
    uniform = cubegi.cubegi_addon.attributes.read(bpy.data.objects["Ground"].data, "CubeGI_direct").mean()
    assert directional > 1.4 * uniform > 0, (directional, uniform)
    tree.links.new(env.outputs["Color"], bg.inputs["Color"])
    # Pixels that are NaN or infinite count as black, with a note; the sky stays finite.
    px[20, 3, 0], px[25, 40, 1] = np.inf, np.nan
    image.pixels.foreach_set(px.ravel())
    collected = read(bpy.context)
    assert np.isfinite(collected.arrays.sky).all() and np.isfinite(collected.arrays.sky_map).all()
    assert any("'env' has 2 pixels that are NaN or infinite" in n for n in collected.notes), collected.notes
    # Turned by a Mapping node, the image is averaged, with a note.
    mapping = tree.nodes.new("ShaderNodeMapping")
    tree.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    collected = read(bpy.context)
    assert collected.arrays.sky_map is None
    assert any("environment image 'env' is mapped" in n for n in collected.notes), collected.notes


def test_lights_that_reach_nothing_visible_are_left_out_and_named(empty_scene, cubegi):
    v, f = scenes.box_mesh((-2, -2, 0), (2, 2, 2.5), (4, 4, 3), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    scenes.add_light("POINT", (0.3, 0.2, 1.5), 100.0)
    assert bpy.ops.cubegi.bake(grid=(2, 2, 2), bounces=1, cube_size=8) == {"FINISHED"}
    alone = cubegi.cubegi_addon.attributes.read(bpy.data.objects["Room"].data, "CubeGI_total")
    away = scenes.add_light("SPOT", (0.0, 0.0, 2.6), 500.0, spot_size=0.3)  # above the ceiling, pointing up
    away.rotation_euler = (3.14159, 0.0, 0.0)
    faint = scenes.add_light("POINT", (-1.0, 1.0, 1.0), 1e-6)  # a millionth of a watt beside 100 W
    away.name, faint.name = "Away", "Faint"
    assert bpy.ops.cubegi.bake(grid=(2, 2, 2), bounces=1, cube_size=8) == {"FINISHED"}
    report = json.loads(bpy.context.scene.cubegi.last_report)
    assert report["left_out"] == ["light Away: reaches no surface", "light Faint: below 0.0001 of the brightest light everywhere"]
    text = "\n".join(cubegi.cubegi_engine.report.BakeReport.from_dict(report).summary_lines())
    assert "left out: light Away: reaches no surface" in text
    np.testing.assert_allclose(cubegi.cubegi_addon.attributes.read(bpy.data.objects["Room"].data, "CubeGI_total"), alone, rtol=1e-5)


def test_meshes_too_coarse_for_vertex_light_are_named(empty_scene, cubegi):
    """A room of primitive cubes (8 vertices each): their light is known only at corners a
    cell or more apart, and the bake says so, naming them; a subdivided box is not named."""
    import json

    bpy.ops.mesh.primitive_cube_add(size=1, location=(0, 0, 0.5))
    bpy.context.object.scale = (4.0, 3.0, 1.0)
    bpy.context.object.name = "Slab"
    v, f = scenes.box_mesh((-1, -1, 1.5), (1, 1, 3.5), (8, 8, 8), inward=True)
    scenes.mesh_object("Fine", v, f)
    scenes.add_light("POINT", (0.2, 0.1, 2.5), 50.0)
    assert bpy.ops.cubegi.bake(bounces=1, cube_size=8) == {"FINISHED"}
    notes = json.loads(bpy.context.scene.cubegi.last_report)["scene"]["notes"]
    coarse = [n for n in notes if "edges longer than a probe cell" in n]
    assert len(coarse) == 1 and coarse[0].startswith("Slab:") and "Fine" not in coarse[0], notes


@pytest.mark.parametrize("shape", ["quad", "box"])
def test_a_lamp_close_under_a_ceiling_is_named_with_the_gap(empty_scene, cubegi, shape):
    """An emissive panel 1 cm under a ceiling traps light in a gap no probe resolves: the
    bake names the panel, the ceiling and the gap, and still gives the ceiling over it the
    light bouncing between them (more indirect light there than beside the panel). The same
    panel half a metre down is not named. A quad, or a closed box 2 cm thick whose top no
    probe sees either (its top and the ceiling over it were hidden from each other's rays
    as the floor under a block is: the ceiling there got no indirect light, and no note)."""
    v, f = scenes.box_mesh((-1, -1, 0), (1, 1, 2), (8, 8, 8), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    ceiling_v, ceiling_f = scenes.grid_patch((-1, -1, 1.99), (0, 2, 0), (2, 0, 0), 16, 16)  # faces down
    ceiling = scenes.mesh_object("Ceiling", ceiling_v, ceiling_f, scenes.material("Plaster", (0.8, 0.8, 0.8)))
    if shape == "quad":
        lamp_v, lamp_f = scenes.grid_patch((-0.25, -0.25, 1.98), (0, 0.5, 0), (0.5, 0, 0), 4, 4)
    else:
        lamp_v, lamp_f = scenes.box_mesh((-0.25, -0.25, 1.96), (0.25, 0.25, 1.98), (4, 4, 1), inward=False)
    lamp = scenes.mesh_object("Panel", lamp_v, lamp_f, scenes.material("Glow", (0.8, 0.8, 0.8), emission=(1, 1, 1), strength=10.0))
    assert bpy.ops.cubegi.bake(bounces=3, cube_size=8) == {"FINISHED"}
    trapped = [n for n in _notes() if "gathered by the near field alone" in n]
    assert len(trapped) == 1 and trapped[0].startswith("Panel: an emitter 1 cm from Ceiling"), _notes()
    assert "leaves out the energy balance" in trapped[0]  # it fills over 90% of their view (emitters.GAP_VIEW)
    attrs = cubegi.cubegi_addon.attributes
    indirect = attrs.read(ceiling.data, attrs.INDIRECT).mean(axis=1)
    xy = np.array([v.co[:2] for v in ceiling.data.vertices])
    over = np.all(np.abs(xy) < 0.2, axis=1)
    assert over.any() and indirect[over].mean() > 2.0 * indirect[~over].mean()
    lamp.location.z = -0.5
    assert bpy.ops.cubegi.bake(bounces=3, cube_size=8) == {"FINISHED"}
    assert not [n for n in _notes() if "gathered by the near field alone" in n], _notes()


@pytest.mark.parametrize("how", ["hide_set", "hide_viewport", "collection"])
def test_the_cycles_reference_bakes_objects_hidden_only_in_the_viewport(empty_scene, cubegi, how):
    """Cycles bakes only what it can select: a wall hidden in the viewport is shown for the
    reference's bake and hidden again; its reference is the one it gets when shown."""
    scenes.thin_wall()
    settings = dict(grid=(4, 2, 2), bounces=1, cube_size=8, reference_samples=4)
    read = cubegi.cubegi_addon.attributes.read
    assert bpy.ops.cubegi.bake(**settings) == {"FINISHED"}
    shown = read(bpy.data.objects["Wall"].data, "CubeGI_ref_direct")
    bpy.ops.cubegi.clear()
    wall = _hide_wall(how)
    assert bpy.ops.cubegi.bake(**settings) == {"FINISHED"}
    hidden = read(bpy.data.objects["Wall"].data, "CubeGI_ref_direct")
    assert np.ptp(shown) > 0 and np.allclose(hidden, shown, rtol=1e-4, atol=1e-6)
    _assert_hidden(wall, how)


def test_an_object_sharing_a_baked_mesh_is_named_with_the_object_whose_light_it_shows(empty_scene, cubegi):
    """Two stools sharing one mesh (a linked duplicate) stand in differently lit places: one
    mesh holds one set of vertex colours, so the second shows the first's light. The note
    names both and how to bake the second in its own place."""
    v, f = scenes.box_mesh((-2, -2, 0), (2, 2, 2.5), (6, 6, 4), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    sv, sf = scenes.box_mesh((-0.2, -0.2, 0.0), (0.2, 0.2, 0.5), (2, 2, 2), inward=False)
    first = scenes.mesh_object("StoolA", sv, sf, scenes.material("Wood", (0.5, 0.3, 0.2)))
    first.location.x = -1.0
    second = bpy.data.objects.new("StoolB", first.data)
    second.location.x = 1.0
    bpy.context.scene.collection.objects.link(second)
    scenes.add_light("POINT", (1.2, 0.0, 1.5), 100.0)
    assert bpy.ops.cubegi.bake(bounces=1, cube_size=8) == {"FINISHED"}
    shared = [n for n in _notes() if n.startswith("StoolB: shares mesh")]
    assert len(shared) == 1 and "with StoolA, which is baked" in shared[0] and "Make Single User" in shared[0], _notes()
