"""The add-on as an artist uses it: registration, polls, the modal bake (driven step by step,
cancelled midway, undone), the display layers, the probe spheres, the material wiring and
the preferences."""

import json
import os
import subprocess
import sys
import threading
import time
import types

import bpy
import numpy as np
import pytest
import scenes
from state import material_state, scene_state

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture
def box(empty_scene, cubegi):
    """A closed box of albedo 0.5 lit by a point light, with a probe grid object."""
    scenes.closed_box(albedo=0.5, cells=6)
    scenes.add_light("POINT", (0.3, -0.2, 0.4), 40.0)
    assert bpy.ops.cubegi.add_probe_grid(resolution=(2, 2, 2)) == {"FINISHED"}
    return cubegi


# --- registration --------------------------------------------------------------------------

NAMED = (
    "CUBEGI_OT_bake", "CUBEGI_OT_clear", "CUBEGI_OT_add_probe_grid", "CUBEGI_OT_wire_materials",
    "CUBEGI_OT_unwire_materials", "CUBEGI_OT_update_light", "CUBEGI_OT_bake_animation", "CUBEGI_OT_export_gltf",
    "CUBEGI_OT_open_report", "VIEW3D_PT_cubegi", "VIEW3D_PT_cubegi_display",
    "VIEW3D_PT_cubegi_report",
)


def test_unregister_leaves_nothing_behind_and_register_restores_everything(cubegi):
    addon = cubegi.cubegi_addon
    classes = [c for m in (addon.prefs, addon.props, addon.operators, addon.panel) for c in m.classes]
    assert len(classes) == 16 and all(c.is_registered for c in classes)
    handlers = [(addon.session.HANDLER_LISTS, addon.session._forget_all),
                (("depsgraph_update_post",), addon.live._persistent_update),
                (("undo_post", "redo_post"), addon.live._persistent_undo),
                (("frame_change_post",), addon.animation.on_frame_change)]
    assert bpy.app.handlers.frame_change_post[:].count(addon.animation.on_frame_change) == 1  # the one frame handler
    menu = bpy.types.VIEW3D_MT_add
    assert addon.probe_view._handle is not None
    cubegi.unregister()
    try:
        assert [c for c in classes if c.is_registered] == []
        assert [c for c in NAMED if getattr(bpy.types, c, None) is not None] == []
        assert not hasattr(bpy.types.Scene, "cubegi") and not hasattr(bpy.types.Object, "cubegi")
        assert not any(getattr(f, "__name__", "") == "menu_add" for f in menu._dyn_ui_initialize())
        assert not any(getattr(f, "__name__", "") == "menu_export" for f in bpy.types.TOPBAR_MT_file_export._dyn_ui_initialize())
        assert addon.probe_view._handle is None and addon.command._handle is None  # blender -c cubegi gone
        assert not any(addon.probe_view._forget_all in getattr(bpy.app.handlers, n) for n in addon.probe_view._HANDLER_LISTS)
        assert not any(fn in getattr(bpy.app.handlers, n) for lists, fn in handlers for n in lists)
    finally:
        cubegi.register()
    assert all(c.is_registered for c in classes) and all(getattr(bpy.types, c, None) for c in NAMED)
    assert hasattr(bpy.types.Scene, "cubegi") and addon.probe_view._handle is not None and addon.command._handle is not None
    assert all(getattr(bpy.app.handlers, n).count(addon.probe_view._forget_all) == 1 for n in addon.probe_view._HANDLER_LISTS)
    assert all(getattr(bpy.app.handlers, n).count(fn) == 1 for lists, fn in handlers for n in lists)
    assert sum(getattr(f, "__name__", "") == "menu_add" for f in menu._dyn_ui_initialize()) == 1
    assert sum(getattr(f, "__name__", "") == "menu_export" for f in bpy.types.TOPBAR_MT_file_export._dyn_ui_initialize()) == 1


# --- polls explain themselves ----------------------------------------------------------------

def _refusal(op, **kw):
    with pytest.raises(RuntimeError) as info:
        op(**kw)
    return str(info.value)


def test_every_operator_says_why_it_refuses(empty_scene, cubegi):
    assert "no mesh in the scene has CubeGI attributes" in _refusal(bpy.ops.cubegi.clear)
    assert "Bake first" in _refusal(bpy.ops.cubegi.wire_materials)
    assert "No material of the scene has CubeGI's light wired in" in _refusal(bpy.ops.cubegi.unwire_materials)
    assert "Bake first: nothing is kept to update" in _refusal(bpy.ops.cubegi.update_light)
    assert "Save the file first" in _refusal(bpy.ops.cubegi.bake_animation)
    scenes.closed_box(albedo=0.5, cells=2)
    bpy.context.view_layer.objects.active = bpy.data.objects["Box"]
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        for op in (bpy.ops.cubegi.bake, bpy.ops.cubegi.add_probe_grid):
            assert "Switch to Object Mode" in _refusal(op)
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")


# --- the bake, step by step ----------------------------------------------------------------

def _job(cubegi, bounces=3):
    ops = cubegi.cubegi_addon.operators
    settings = cubegi.cubegi_engine.settings.BakeSettings(cube_size=8, bounces=bounces)
    return ops.BakeJob(bpy.context, settings, progressive=True)


def _read(mesh_name, name):
    from cubegi.cubegi_addon import attributes

    return attributes.read(bpy.data.meshes[mesh_name], name)


def test_the_modal_bake_shows_the_light_after_every_bounce_and_ends_as_a_plain_bake(box):
    job = _job(box)
    seen = []
    while not job.step():
        step = job.last
        mesh = bpy.data.meshes["Box"]
        if step.stage == "bounce":
            k = step.done - 2
            assert f"CubeGI_bounce_{k}" in mesh.attributes and f"CubeGI_bounce_{k + 1}" not in mesh.attributes
            seen.append(float(_read("Box", "CubeGI_total").mean()))
    assert len(seen) == 3 and seen[0] < seen[1] < seen[2]  # the light grows bounce by bounce
    report = job.report
    progressive = {n: _read("Box", n) for n in ("CubeGI_direct", "CubeGI", "CubeGI_total", "CubeGI_bounce_3")}
    assert report.bounces[-1].bounce == 3
    # The same bake run straight through (execute) writes the same numbers.
    assert bpy.ops.cubegi.bake(bounces=3, cube_size=8) == {"FINISHED"}
    for name, values in progressive.items():
        np.testing.assert_allclose(_read("Box", name), values, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(progressive["CubeGI_total"], progressive["CubeGI_direct"] + progressive["CubeGI"], rtol=1e-5)


@pytest.mark.parametrize("steps", [0, 1, 2, 3, 4])
def test_cancelling_the_modal_bake_midway_leaves_the_scene_exactly_as_before(box, steps):
    assert bpy.ops.cubegi.bake(bounces=1, cube_size=8) == {"FINISHED"}  # an earlier bake to keep
    mesh = bpy.data.meshes["Box"]
    mesh.attributes.new("user_colour", "FLOAT_COLOR", "POINT")
    mesh.color_attributes.active_color_name = "user_colour"
    before = scene_state()
    job = _job(box, bounces=4)
    for _ in range(steps):  # steps that report progress (the working steps between them hand control back only)
        assert not job.step()
        while job.last.working:
            assert not job.step()
    if steps >= 3:  # the preview has changed the meshes by now (bounce 1 and the totals)
        assert scene_state() != before
    job.cancel()
    assert scene_state() == before


def test_a_cancelled_bake_stops_the_tables_it_started(box, monkeypatch):
    """Esc while the tables are built (in threads, cut into pieces) stops them at their
    next piece: none starts after the cancel but those already past it (one a worker), where
    before every piece ran to the end (at a million vertices tens of seconds and gigabytes
    that a bake started next waited on). The tables are cut into pieces of 8 points here,
    each slowed by 0.1 s; the scene is as it was."""
    from cubegi.cubegi_engine import geometry, visibility, working

    monkeypatch.setattr(geometry, "piece_size", lambda size=0: 8)
    monkeypatch.setattr(visibility, "piece_size", lambda size=0: 8)
    depth_test, calls = visibility._depth_test, []

    def slow(*args):
        calls.append(time.perf_counter())
        time.sleep(0.1)
        return depth_test(*args)

    monkeypatch.setattr(visibility, "_depth_test", slow)
    before = scene_state()
    job = _job(box, bounces=2)
    while not calls:
        assert not job.step()
    job.cancel()
    cancelled = time.perf_counter()
    time.sleep(1.5)
    late = [t for t in calls if t > cancelled]
    assert len(late) <= working.WORKERS, (len(late), len(calls))
    assert scene_state() == before


def test_invoke_in_background_runs_to_completion_and_undo_takes_the_bake_back(box):
    bpy.ops.ed.undo_push(message="before the bake")
    before = scene_state()
    # (INVOKE_DEFAULT, undo=True) is how a button calls it: the bake becomes one undo step.
    assert bpy.ops.cubegi.bake("INVOKE_DEFAULT", True, bounces=2, cube_size=8) == {"FINISHED"}
    assert "CubeGI_bounce_2" in bpy.data.meshes["Box"].attributes
    assert json.loads(bpy.context.scene.cubegi.last_report)["bounces"][-1]["bounce"] == 2
    bpy.ops.ed.undo()
    assert scene_state() == before


# --- what the viewport shows -----------------------------------------------------------------

def test_the_display_setting_picks_the_active_colour_attribute_and_the_viewport_shows_it(box):
    settings = bpy.context.scene.cubegi
    assert bpy.ops.cubegi.bake(bounces=2, cube_size=8, lit="ALL") == {"FINISHED"}
    colours = bpy.data.meshes["Box"].color_attributes
    assert colours.active_color_name == "CubeGI_total"
    for display, name in (("DIRECT", "CubeGI_direct"), ("INDIRECT", "CubeGI"), ("LIT", "CubeGI_lit"), ("TOTAL", "CubeGI_total")):
        settings.display = display
        assert colours.active_color_name == name
    settings.display = "BOUNCE"
    settings.display_bounce = 2
    assert colours.active_color_name == "CubeGI_bounce_2"
    spaces = box.cubegi_addon.display.view_spaces()
    assert spaces and all(s.shading.color_type == "VERTEX" for s in spaces)


def test_probes_store_their_light_and_draw_as_spheres_shaded_with_it(box):
    import gpu
    from mathutils import Matrix

    probe_view = box.cubegi_addon.probe_view
    grid = next(o for o in bpy.context.scene.objects if o.type == "EMPTY")
    assert box.cubegi_addon.grid_objects.stored_probe_light(grid) is None
    assert bpy.ops.cubegi.bake(bounces=2, cube_size=8) == {"FINISHED"}
    coeffs, valid = box.cubegi_addon.grid_objects.stored_probe_light(grid)
    assert coeffs.shape == (8, 9, 3) and valid.all() and np.isfinite(coeffs).all() and coeffs[:, 0].min() > 0
    # A camera looking down -Z at one probe from above sees its sphere's top: the light a
    # surface facing +Z gets there (evaluated from the stored SH).
    from cubegi.cubegi_engine import sh

    pos = box.cubegi_addon.grid_objects.probe_grid(grid).positions()
    k = 7  # a top probe
    expected = sh.irradiance_diffuse(coeffs[k], np.array([0.0, 0.0, 1.0]))
    radius = probe_view.sphere_radius(box.cubegi_addon.grid_objects.probe_grid(grid), box.cubegi_addon.prefs.get().sphere_scale)
    eye = pos[k] + np.array([0.0, 0.0, 3 * radius])
    view = Matrix.Translation(-eye)
    proj = Matrix(np.array(box.cubegi_engine.cubemap.orthographic(0.5 * radius, 0.1 * radius, 10 * radius)).tolist())
    off = gpu.types.GPUOffScreen(16, 16, format="RGBA32F")
    with off.bind():
        fb = gpu.state.active_framebuffer_get()
        fb.clear(color=(0.0, 0.0, 0.0, 0.0), depth=1.0)
        with gpu.matrix.push_pop(), gpu.matrix.push_pop_projection():
            gpu.matrix.load_matrix(view)
            gpu.matrix.load_projection_matrix(proj)
            probe_view.draw(bpy.context.scene)
        pixels = np.asarray(fb.read_color(0, 0, 16, 16, 4, 0, "FLOAT")).ravel(order="K").reshape(16, 16, 4)
    off.free()
    centre = pixels[6:10, 6:10, :3].reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(centre, np.minimum(expected, 1.0), rtol=0.05, atol=1e-3)
    assert bpy.ops.cubegi.clear() == {"FINISHED"} and box.cubegi_addon.grid_objects.stored_probe_light(grid) is None


# --- renders ---------------------------------------------------------------------------------

def test_material_wiring_round_trips_and_adds_albedo_times_light_as_emission(box):
    mats = box.cubegi_addon.materials
    assert bpy.ops.cubegi.bake(bounces=2, cube_size=8) == {"FINISHED"}
    mat = bpy.data.objects["Box"].active_material
    # A texture-like link into Base Color must survive and feed the emission too.
    rgb = mat.node_tree.nodes.new("ShaderNodeRGB")
    rgb.outputs[0].default_value = (0.25, 0.5, 1.0, 1.0)
    bsdf = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    mat.node_tree.links.new(rgb.outputs[0], bsdf.inputs["Base Color"])
    before = material_state(mat)
    assert bpy.ops.cubegi.wire_materials() == {"FINISHED"}
    assert mats.is_wired(mat) and material_state(mat) != before
    nodes = mat.node_tree.nodes
    assert nodes[mats.ATTRIBUTE].attribute_name == "CubeGI"
    assert nodes[mats.MULTIPLY].inputs["A"].links[0].from_node == rgb
    assert nodes[mats.ADD].inputs[0].links[0].from_node == bsdf
    assert "No material left to wire" in _refusal(bpy.ops.cubegi.wire_materials)
    assert bpy.ops.cubegi.unwire_materials() == {"FINISHED"}
    assert material_state(mat) == before


def test_a_wired_material_renders_base_colour_times_the_baked_light(empty_scene, cubegi, tmp_path):
    """Cycles, no lights, a black world and no bounces: a pixel is exactly the emission."""
    mats = cubegi.cubegi_addon.materials
    verts = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
    mat = scenes.material("Plane", (0.8, 0.4, 0.2))
    ob = scenes.mesh_object("Plane", verts, [(0, 1, 2, 3)], mat)
    cubegi.cubegi_addon.attributes.put(ob.data, "CubeGI", np.full((4, 3), 0.5))
    mats.wire(mat)
    scene = bpy.context.scene
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    cam.location = (0, 0, 3)
    scene.camera = cam
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.max_bounces = 0
    scene.render.resolution_x = scene.render.resolution_y = 8
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = str(tmp_path / "wired.exr")
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(str(tmp_path / "wired.exr"))
    px = np.empty(8 * 8 * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    centre = px.reshape(8, 8, 4)[3:5, 3:5, :3].reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(centre, [0.4, 0.2, 0.1], rtol=0.02)


# --- the panel and the preferences -----------------------------------------------------------

class _Layout:
    """Records what a panel's draw puts in its layout."""

    def __init__(self):
        self.props, self.operators, self.labels, self.operator_props = [], [], [], []

    def column(self, **_):
        return self

    row = box = column

    def prop(self, data, name, **_):
        self.props.append(name)

    def operator(self, idname, **_):
        self.operators.append(idname)
        self.operator_props.append(types.SimpleNamespace())
        return self.operator_props[-1]  # the button's operator properties, as Blender returns them

    def label(self, text="", **_):
        self.labels.append(text)


def _draw(panel):
    layout = _Layout()
    getattr(bpy.types, panel).draw(type("Panel", (), {"layout": layout})(), bpy.context)
    return layout


def test_the_panels_show_grid_and_bake_settings_display_choice_and_the_last_report(box):
    grid = next(o for o in bpy.context.scene.objects if o.type == "EMPTY")
    bpy.context.view_layer.objects.active = grid
    main = _draw("VIEW3D_PT_cubegi")
    assert {"resolution", "show_probes", "show_irradiance", "cube_size", "bounces", "tolerance", "add_tail", "visibility", "lit",
            "shadow_size", "sun_shadow_size", "area_shadow_size"} <= set(main.props)
    assert main.operators == ["cubegi.add_probe_grid", "cubegi.bake", "cubegi.bake", "cubegi.clear", "cubegi.update_light",
                              "cubegi.bake_animation"]
    assert vars(main.operator_props[2]) == {"selected_only": True}  # Bake Selected
    bpy.context.view_layer.objects.active = next(o for o in bpy.context.scene.objects if o.type == "MESH")
    assert {"receive", "contribute", "dynamic"} <= set(_draw("VIEW3D_PT_cubegi").props)
    bpy.context.view_layer.objects.active = next(o for o in bpy.context.scene.objects if o.type == "LIGHT")
    assert "shadow_size" in _draw("VIEW3D_PT_cubegi").props[:1]
    bpy.context.view_layer.objects.active = grid
    shown = _draw("VIEW3D_PT_cubegi_display")
    assert shown.props == ["display"] and shown.operators == ["cubegi.wire_materials", "cubegi.unwire_materials"]
    bpy.context.scene.cubegi.display = "BOUNCE"
    assert _draw("VIEW3D_PT_cubegi_display").props == ["display", "display_bounce"]
    assert _draw("VIEW3D_PT_cubegi_report").labels == ["no bake yet"]
    assert bpy.ops.cubegi.bake(bounces=3, cube_size=8) == {"FINISHED"}
    text = "\n".join(_draw("VIEW3D_PT_cubegi_report").labels)
    assert "3 bounces in" in text and "bounce 3:" in text and "estimated missing indirect light after bounce 3" in text


def test_preferences_set_new_grids_only(box, monkeypatch):
    prefs = box.cubegi_addon.prefs
    assert tuple(prefs.get().grid_resolution) == (4, 4, 2)

    class Mine:
        grid_resolution = (3, 1, 2)
        sphere_scale = 0.2

    monkeypatch.setattr(prefs, "get", lambda context=None: Mine())
    assert bpy.ops.cubegi.add_probe_grid() == {"FINISHED"}
    assert tuple(bpy.context.active_object.cubegi.resolution) == (3, 1, 2)
    assert not {"shadow_size", "sun_shadow_size", "area_shadow_size"} & set(prefs.CubeGIPreferences.__annotations__)  # the file's


def test_shadow_map_sizes_are_the_files_per_scene_and_per_light(empty_scene, cubegi, monkeypatch):
    """Shadow-map sizes are saved in the file (the scene's per light type, and a light's own),
    so one file bakes the same on every machine (before: this machine's Preferences). A
    light's own size is what the scene's same size gives; an update after it changes redraws
    that light's shadow and equals a fresh bake. (The maps drawn are watched: where a map's
    texel cannot decide the block's shadow edge a ray does, so the light itself no longer
    shows the size.)"""
    v, f = scenes.box_mesh((-2, -2, 0), (2, 2, 2.5), (16, 16, 4), inward=True)
    room = scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    v, f = scenes.box_mesh((-0.6, -0.4, 0.0), (0.3, 0.5, 0.9), (3, 3, 3), inward=False)
    scenes.mesh_object("Block", v, f, scenes.material("Red", (0.7, 0.1, 0.1)))
    lamp = scenes.add_light("POINT", (1.0, 1.0, 2.0), 200.0, shadow_soft_size=0.0)  # hard: one cube map of shadow_size
    read = cubegi.cubegi_addon.attributes.read
    kwargs = dict(grid=(3, 3, 2), cube_size=8, bounces=1)
    lights = cubegi.cubegi_engine.lights
    sizes, test = [], lights.shadow_visibility

    def watched(receivers, occluders, eye, depth, *args, **kw):
        sizes.append(depth.size)
        return test(receivers, occluders, eye, depth, *args, **kw)

    monkeypatch.setattr(lights, "shadow_visibility", watched)

    def direct():
        drawn = set(sizes)
        sizes.clear()
        assert len(drawn) == 1, drawn
        return read(room.data, "CubeGI_direct").copy(), drawn.pop()

    scene = bpy.context.scene.cubegi
    assert scene.shadow_size == 512 and lamp.data.cubegi.shadow_size == 0
    assert bpy.ops.cubegi.bake(**kwargs) == {"FINISHED"}
    fine, size = direct()
    assert size == 512 and json.loads(scene.last_report)["settings"]["shadow_size"] == 512
    scene.shadow_size = 16
    assert bpy.ops.cubegi.bake(**kwargs) == {"FINISHED"}
    coarse, size = direct()
    assert size == 16 and json.loads(scene.last_report)["settings"]["shadow_size"] == 16
    scene.shadow_size = 512
    lamp.data.cubegi.shadow_size = 16
    assert bpy.ops.cubegi.bake(**kwargs) == {"FINISHED"}
    light, size = direct()
    assert size == 16
    np.testing.assert_array_equal(light, coarse)
    lamp.data.cubegi.shadow_size = 0
    assert bpy.ops.cubegi.update_light() == {"FINISHED"}
    light, size = direct()
    assert size == 512
    np.testing.assert_allclose(light, fine, rtol=0, atol=1e-5 * fine.max())


class _Event:
    def __init__(self, type):
        self.type = type


def _modal_operator(cubegi, **props):
    """The bake operator's modal code on a stand-in for its instance (Blender creates operator
    instances only when it runs one), to drive it as a window would: invoke() runs
    ``_start`` and adds the handler, then Blender calls ``modal`` for every event."""
    import types

    op_class = cubegi.cubegi_addon.operators.CUBEGI_OT_bake
    messages = []
    props.setdefault("lit", "NONE")
    props.setdefault("report_path", "")
    props.setdefault("selected_only", False)
    op = types.SimpleNamespace(
        grid=(0, 0, 0), reference_samples=0, report=lambda kind, text: messages.append((kind, text)), **props
    )
    op.properties = types.SimpleNamespace(is_property_set=lambda name: name in props)
    for name in ("_job", "_start", "_finish", "_end", "cancel", "modal"):
        setattr(op, name, getattr(op_class, name).__get__(op))
    op.CANCELLED_MESSAGE = op_class.CANCELLED_MESSAGE
    return op, op_class, messages


def test_the_modal_handler_steps_on_timer_events_and_escape_cancels(box):
    context = bpy.context
    before = scene_state()
    op, op_class, messages = _modal_operator(box, bounces=3, cube_size=8)
    op._start(context)
    assert op.modal(context, _Event("MOUSEMOVE")) == {"PASS_THROUGH"}
    reported = []  # the steps that report progress; working steps between them only hand control back
    while len(reported) < 3:  # capture, direct, direct done: the direct light is on the mesh
        assert op.modal(context, _Event("TIMER")) == {"RUNNING_MODAL"}
        if not op._bake.last.working:
            reported.append(op._bake.last.message)
    assert reported[-1] == "direct light done" and "CubeGI_direct" in bpy.data.meshes["Box"].attributes
    assert op.modal(context, _Event("ESC")) == {"CANCELLED"}
    assert messages[-1][0] == {"WARNING"} and "cancelled" in messages[-1][1]
    assert scene_state() == before

    op, op_class, messages = _modal_operator(box, bounces=3, cube_size=8)
    op._start(context)
    results, reported = [], 0
    while not results or results[-1] == {"RUNNING_MODAL"}:
        results.append(op.modal(context, _Event("TIMER")))
        reported += results[-1] == {"RUNNING_MODAL"} and not op._bake.last.working
        assert len(results) < 200
    assert results[-1] == {"FINISHED"} and reported == 7  # 7 steps that report (and the working steps), then the report
    assert "CubeGI_bounce_3" in bpy.data.meshes["Box"].attributes
    assert any("baked 1 meshes, 3 bounces" in text for _, text in messages)


def test_quality_presets_write_the_scene_settings_and_the_operator_takes_one(empty_scene, cubegi):
    from cubegi.cubegi_engine.settings import QUALITY

    s = bpy.context.scene.cubegi
    assert (s.quality, s.cells, s.cube_size, s.bounces) == ("BALANCED", 8, 16, 5)
    s.quality = "FINAL"
    assert (s.cells, s.cube_size, s.bounces) == tuple(QUALITY["FINAL"][k] for k in ("cells", "cube_size", "bounces"))
    s.cube_size = 24  # still editable after a preset
    assert s.cube_size == 24 and s.quality == "FINAL"
    s.quality = "BALANCED"
    scenes.closed_box(cells=4)
    assert bpy.ops.cubegi.bake(quality="DRAFT", bounces=2) == {"FINISHED"}
    rep = json.loads(s.last_report)
    assert (rep["settings"]["cells"], rep["settings"]["cube_size"], rep["settings"]["bounces"]) == (4, 16, 2)


def test_blender_conventions_one_line_tooltips_no_redo_of_a_bake_units_and_an_open_report(box):
    """Each operator's tooltip is one line (Blender shows a docstring's breaks and indents);
    a bake is one undo step with no Adjust Last Operation panel (a tweak there would run the
    whole bake again); the probe spacing is a distance and a grid's resolution an X/Y/Z
    vector; Open Report puts the whole report into a text."""
    ops = [getattr(bpy.types, n) for n in NAMED if n.startswith("CUBEGI_OT")]
    for op in ops:
        # Where the class gives a description() for its buttons, Blender asks it (and the RNA's is empty).
        texts = [getattr(bpy.ops.cubegi, op.bl_idname.split(".")[1]).get_rna_type().description]
        if hasattr(op, "description"):
            texts = [op.description(bpy.context, types.SimpleNamespace(selected_only=on)) for on in (False, True)]
        for text in texts:
            assert text and "\n" not in text and len(text) <= 120, (op.__name__, text)
    assert bpy.types.CUBEGI_OT_bake.bl_options == {"UNDO"}
    scene_props = bpy.context.scene.cubegi.bl_rna.properties
    assert scene_props["probe_spacing"].subtype == "DISTANCE" and scene_props["probe_spacing"].unit == "LENGTH"
    assert bpy.context.scene.objects[0].cubegi.bl_rna.properties["resolution"].subtype == "XYZ"
    assert not bpy.ops.cubegi.open_report.poll()  # no report before a bake
    assert bpy.ops.cubegi.bake(bounces=1, cube_size=8) == {"FINISHED"}
    assert bpy.ops.cubegi.open_report() == {"FINISHED"}
    assert json.loads(bpy.data.texts["CubeGI Report"].as_string()) == json.loads(bpy.context.scene.cubegi.last_report)
    assert bpy.ops.cubegi.open_report() == {"FINISHED"} and len([t for t in bpy.data.texts if t.name.startswith("CubeGI")]) == 1


def test_probe_spacing_fits_a_grid_of_probes_that_far_apart(empty_scene, cubegi, tmp_path):
    """Probe Spacing, a distance, instead of Grid Cells (a count whose meaning changes with
    the scene's size): the fitted grid's probes are about that far apart, in the panel, the
    operator and the command line; a spacing that would need too many probes is capped with
    a note; zero or less is refused."""
    scenes.closed_box(albedo=0.5, cells=6)  # 1 x 1 x 1, padded a little
    scenes.add_light("POINT", (0.3, -0.2, 0.4), 40.0)
    scene = bpy.context.scene.cubegi
    scene.probe_spacing = 0.25
    assert bpy.ops.cubegi.bake(bounces=1, cube_size=8) == {"FINISHED"}
    report = json.loads(scene.last_report)
    size = np.array(report["grid"]["hi"]) - np.array(report["grid"]["lo"])
    assert report["grid"]["resolution"] == [int(r) for r in np.round(size / 0.25)] and report["settings"]["probe_spacing"] == 0.25
    assert bpy.ops.cubegi.bake(bounces=1, cube_size=8, probe_spacing=0.5) == {"FINISHED"}
    assert json.loads(scene.last_report)["grid"]["resolution"] == [int(r) for r in np.round(size / 0.5)]
    assert bpy.ops.cubegi.bake(bounces=1, cube_size=8, probe_spacing=0.001) == {"FINISHED"}
    report = json.loads(scene.last_report)
    assert report["grid"]["probes"] <= box_cap(cubegi) and any("probe spacing of 0.001" in n for n in report["scene"]["notes"])
    scene.probe_spacing = 0.0
    assert bpy.ops.cubegi.bake(bounces=1, cube_size=8, cells=4) == {"FINISHED"}
    assert max(json.loads(scene.last_report)["grid"]["resolution"]) == 4  # 0: Grid Cells again
    src = tmp_path / "in.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(src))
    r = subprocess.run([sys.executable, "-m", "cubegi_engine", "bake", str(src), "-o", str(tmp_path / "o.blend"), "--report",
                        str(tmp_path / "r.json"), "--probe-spacing", "0.5", "--bounces", "1", "--cube-size", "8"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "r.json").read_text())["grid"]["resolution"] == [int(r) for r in np.round(size / 0.5)]
    r = subprocess.run([sys.executable, "-m", "cubegi_engine", "bake", str(src), "-o", str(tmp_path / "o.blend"),
                        "--probe-spacing", "-1"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "--probe-spacing: probe spacing must be a distance above 0" in r.stderr, r.stderr
    r = subprocess.run([sys.executable, "-m", "cubegi_engine", "bake", str(src), "-o", str(tmp_path / "o.blend"), "--report",
                        str(tmp_path / "r.json"), "--probe-spacing", "0", "--cells", "4", "--bounces", "1", "--cube-size", "8"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr  # 0, as in the panel: Grid Cells sets the spacing
    assert max(json.loads((tmp_path / "r.json").read_text())["grid"]["resolution"]) == 4


def box_cap(cubegi):
    return cubegi.cubegi_addon.grid_objects.MAX_FITTED_PROBES


def _large_room():
    """A room of 29K triangles with 40 blocks, a sun and a sky: a bake of several seconds."""
    v, f = scenes.box_mesh((-4, -4, 0), (4, 4, 3), (60, 60, 30), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    rng = np.random.default_rng(3)
    for k in range(40):
        x, y = rng.uniform(-3.5, 3.5, 2)
        v, f = scenes.box_mesh((x - 0.2, y - 0.2, 0.0), (x + 0.2, y + 0.2, rng.uniform(0.3, 1.5)), (4, 4, 4), inward=False)
        scenes.mesh_object(f"Block{k}", v, f, scenes.material(f"B{k}", tuple(rng.uniform(0.2, 0.8, 3))))
    scenes.add_light("SUN", (0, 0, 5), 3.0, rotation=(0.5, 0.2, 0.0))
    scenes.add_light("AREA", (0.0, 0.0, 2.9), 300.0, shape="SQUARE", size=1.0)
    scenes.set_world((0.3, 0.4, 0.6), 1.0)


def test_a_long_bake_hands_control_back_in_short_steps_and_esc_in_any_of_them_changes_nothing(empty_scene, cubegi):
    """The modal bake advances one step per timer event: the capture is drawn in batches, the
    tables, the placement and each light's shadow test run in a thread while the bake hands
    control back, a light's shadow maps and the sky's come a few at a time. On a bake of
    several seconds no step is more than a tenth of it (before: the capture with its tables,
    and the direct light, were one step each, 45% and 29% of the bake; the upload to the GPU
    was one step), and Esc in the middle
    of any of them (a thread still running) leaves the scene as it was."""
    _large_room()
    pipeline = cubegi.cubegi_addon.pipeline
    settings = cubegi.cubegi_addon.props.bake_settings(bpy.context.scene, {})
    before = scene_state()
    steps, gaps = pipeline.bake_steps(bpy.context, settings, progressive=True), []
    t0 = last = time.perf_counter()
    messages = []
    try:
        while True:
            messages.append(next(steps).message)
            gaps.append(time.perf_counter() - last)
            last = time.perf_counter()
    except StopIteration:
        gaps.append(time.perf_counter() - last)
    total = time.perf_counter() - t0
    longest = max(gaps)
    print(f"bake {total:.2f} s in {len(gaps)} steps; the longest {longest:.2f} s ({100 * longest / total:.0f}%): "
          f"{messages[gaps.index(longest) - 1] if gaps.index(longest) else 'the first'}")
    assert total > 2.0  # a bake long enough to matter
    assert longest < 0.1 * total, (longest, total)  # measured: 0.41 s of 12.7 s (3%), a batch of the capture
    for kind in ("the scene to the GPU", "captured", "building the tables"):
        assert any(m.startswith(kind) for m in messages), kind
    # Esc at every kind of working step: the scene's upload, the capture's batches, the
    # tables' thread, a light's shadows, the sky.
    for kind in ("the scene to the GPU", "captured", "building the tables", "direct light: 1 of", "direct light: the sky"):
        before = scene_state()  # the finished bake's light: a cancelled one must leave it
        cubegi.cubegi_addon.session.forget()  # a new capture, not the kept one
        job = cubegi.cubegi_addon.operators.BakeJob(bpy.context, settings, progressive=True)
        while not (job.last is not None and job.last.message.startswith(kind)):
            assert not job.step(), kind
        job.cancel()
        assert scene_state() == before, kind



def test_the_scene_is_simplified_for_the_probes_while_they_are_placed(empty_scene, cubegi, monkeypatch):
    """A new capture's simplified scene does not depend on the probes: it is made in a
    thread of its own while they are placed (the million-vertex Room: 2.5 s less a bake).
    The placement here waits until the simplification has started; run one after the
    other, it would wait in vain. The proxy drawn is the one made alone."""
    _large_room()
    bake = cubegi.cubegi_engine.bake
    started, drawn, done = threading.Event(), [], threading.Semaphore(0)
    place, simplify = bake.place, bake.simplify

    def simplifying(scene, budget):
        started.set()
        try:
            proxy = simplify(scene, budget)
            drawn.append((proxy, scene, budget))
            return proxy
        finally:
            done.release()

    def placing(*args, **kwargs):
        assert started.wait(30.0), "the scene was not being simplified while the probes were placed"
        return place(*args, **kwargs)

    monkeypatch.setattr(bake, "simplify", simplifying)
    monkeypatch.setattr(bake, "place", placing)
    assert bpy.ops.cubegi.bake(capture_triangles=5000) == {"FINISHED"}
    report = json.loads(bpy.context.scene.cubegi.last_report)
    assert report["timings"]["placement"] > 0.0 and len(drawn) == 1
    proxy, scene, budget = drawn[0]
    alone = simplify(scene, budget)
    assert proxy is not None and np.array_equal(proxy.triangles, alone.triangles) and np.array_equal(proxy.points, alone.points)
    # Esc while the probes are placed (the simplification running beside them) leaves the
    # scene as it was.
    before, release, placed = scene_state(), threading.Event(), threading.Event()

    def held(*args, **kwargs):
        release.wait(30.0)
        try:
            return place(*args, **kwargs)
        finally:
            placed.set()

    monkeypatch.setattr(bake, "place", held)
    cubegi.cubegi_addon.session.forget()  # a new capture, not the kept one
    job = cubegi.cubegi_addon.operators.BakeJob(bpy.context, cubegi.cubegi_addon.props.bake_settings(bpy.context.scene, {}),
                                                progressive=True)
    try:
        while not (job.last is not None and job.last.message.startswith("placing the probes")):
            assert not job.step()
        job.cancel()
    finally:
        release.set()
    assert scene_state() == before
    # The cancelled bake's threads end on their own (not in the tests after this one).
    assert placed.wait(60.0) and done.acquire(timeout=60.0) and done.acquire(timeout=60.0)

# --- every bake setting declared once ------------------------------------------------------

def _another(o):
    """A valid value of the option ``o`` other than its default."""
    if o.switch:
        return not o.default
    if o.kind is float:
        return 0.05 if o.default is None else o.default * 2
    return o.minimum if o.minimum is not None and o.minimum != o.default else o.default * 2


def test_every_bake_option_is_a_property_a_panel_entry_a_flag_a_forwarded_word_and_a_report_entry(box, cubegi):
    """The settings declaration (cubegi_engine/settings.py) makes the scene's properties,
    the operator's, the panel's rows, the command line's options, the words a cluster's
    bakes get, the report's settings and the capture's key: a setting declared there is in
    every one, with its label, default and range."""
    from cubegi.cubegi_addon import cli
    from cubegi.cubegi_engine.settings import OPTIONS, SECTIONS, BakeSettings

    scene_props = bpy.context.scene.cubegi.bl_rna.properties
    op_props = bpy.ops.cubegi.bake.get_rna_type().properties
    drawn = _draw("VIEW3D_PT_cubegi").props
    assert len(OPTIONS) >= 15 and {o.section for o in OPTIONS} == {*SECTIONS, None}
    parser = cli._parser("cubegi")
    for o in OPTIONS:
        if o.section is not None:
            prop = scene_props[o.name]
            assert prop.name == o.label and prop.description == o.help and o.name in drawn, o.name
            assert getattr(bpy.context.scene.cubegi, o.name) == o.stored(o.default) or o.name in ("cube_size", "bounces"), o.name
            if o.minimum is not None:
                assert prop.hard_min == pytest.approx(o.minimum), o.name
            if not o.switch:  # no setting takes a negative value: the panel cannot offer one
                assert prop.hard_min >= 0, o.name
            if o.maximum is not None:
                assert prop.hard_max == pytest.approx(o.maximum), o.name
        else:
            assert o.name not in scene_props and o.name not in drawn, o.name
        assert op_props[o.name].name == o.label, o.name
        if o.minimum is not None:
            assert op_props[o.name].soft_min == pytest.approx(o.minimum), o.name  # soft: validate names a bad value
        value = _another(o)
        args = parser.parse_args(["bake", "in.blend", "-o", "out.blend", *o.words(value)])
        assert cli._given(args) == {o.name: o.given(value)}, o.name
        assert cli._forwarded(args) == o.words(value), o.name
        settings = cli.checked_settings(args)
        assert getattr(settings, o.name) == o.given(value) and settings.as_dict()[o.name] == o.given(value), o.name
        changed = BakeSettings(**{o.name: o.given(value)}).capture_key() != BakeSettings().capture_key()
        assert changed == o.capture, o.name
    assert set(BakeSettings().as_dict()) == {o.name for o in OPTIONS}
    assert {o.name for o in OPTIONS if o.capture} == {"cube_size", "visibility", "capture_triangles", "near_field"}


def test_a_cast_capture_hands_the_tables_the_hosts_ray_caster(empty_scene, cubegi, monkeypatch):
    """A simplified scene's probes are cast (capture.RayCubes), and the tables built from
    them still cast their near field through the host's caster (gather.near_caster): without
    it, the near field under covered points took the voxel index and its triangles' planes
    (about 0.5 GB at 4.77M triangles)."""
    _large_room()
    capture, gather = cubegi.cubegi_engine.capture, cubegi.cubegi_engine.gather
    seen, tables = [], capture._tables

    def spying(scene, grid, cubes, visibility, proxy, settings, renderer, tracing=None):
        seen.append((proxy is not None, type(renderer).__name__, gather.near_caster(scene, renderer) is not None))
        return tables(scene, grid, cubes, visibility, proxy, settings, renderer, tracing)

    monkeypatch.setattr(capture, "_tables", spying)
    assert bpy.ops.cubegi.bake(capture_triangles=5000) == {"FINISHED"}
    assert seen == [(True, "RayCubes", True)]
