"""The scene as Cycles renders it, one Blender feature at a time: a tiny scene per feature,
baked by CubeGI and by Cycles (its Diffuse bake of the same vertices), compared with a
tolerance per row; a feature CubeGI does not read is named by a note, which its row asserts.

Every row records what it measured in ``out/conformance.json`` (feature, support, error
against Cycles); ``scripts/support_table.py`` turns that into ``docs/blender-support.md``.

The scene: the Cornell-like box of ``benchmarks.scenes.cornell`` (2 m, open at the front), lit by
one light. Tolerances: Cycles at 64 samples is about 1.5% noisy in the mean of the box; the
direct light's own error against Cycles is below 3% in bias and 8% in rel. RMSE for every
light type (``test_cycles.py``), so a row that reads its feature right stays well inside
DIRECT_BIAS_TOL, and a feature read wrong (a factor of 2 or more) is far outside it.
"""

import json
import os

import bpy
import numpy as np
import pytest
import scenes

from cubegi.cubegi_engine import metrics

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
RESULTS = os.path.join(ROOT, "out", "conformance.json")
SAMPLES = 64
DIRECT_BIAS_TOL = 0.05
DIRECT_RMSE_TOL = 0.12
FAST = dict(bounces=1, grid=(3, 3, 3), cube_size=16)


@pytest.fixture(scope="module", autouse=True)
def _fresh_results():
    """Each run of this module writes the results anew (a row whose test is gone goes too)."""
    if os.path.exists(RESULTS):
        os.remove(RESULTS)


def _record(feature, support, **measured):
    """Adds one row to the suite's results (read by scripts/support_table.py)."""
    rows = {}
    if os.path.exists(RESULTS):
        with open(RESULTS) as fh:
            rows = json.load(fh)
    rows[feature] = {"support": support, "blender": bpy.app.version_string, **measured}
    os.makedirs(os.path.dirname(RESULTS), exist_ok=True)
    with open(RESULTS, "w") as fh:
        json.dump(rows, fh, indent=1, sort_keys=True)


def _box():
    scenes.cornell(light=False)
    return [ob for ob in bpy.context.scene.objects if ob.type == "MESH"]


def _notes():
    return json.loads(bpy.context.scene.cubegi.last_report)["scene"]["notes"]


def _direct_errors(cubegi, obs, per_channel=False):
    """CubeGI's and Cycles' direct light on ``obs``: metrics.errors of ours against theirs, and
    ours per vertex; with ``per_channel``, ours and theirs as area-weighted means ``(3,)``
    instead."""
    reference, scene_data, attributes = (getattr(cubegi.cubegi_addon, m) for m in ("reference", "scene_data", "attributes"))
    assert bpy.ops.cubegi.bake(**FAST) == {"FINISHED"}
    baked, _ = reference.bake_reference(bpy.context, obs, passes=("DIRECT",), samples=SAMPLES)
    areas = np.concatenate([scene_data.vertex_areas(o) for o in obs])
    ours = np.concatenate([attributes.read(o.data, "CubeGI_direct") for o in obs])
    theirs = np.concatenate([baked["DIRECT"][o.name] for o in obs])
    err = metrics.errors(ours, theirs, areas)
    if per_channel:
        return err, areas @ ours / areas.sum(), areas @ theirs / areas.sum()
    return err, ours


def _light(kind="POINT", rotation=(0.0, 0.0, 0.0), **props):
    place = {"POINT": (0.13, -0.27, 1.63), "AREA": (0.0, 0.0, 1.98), "SUN": (0, -3, 3), "SPOT": (0.07, 0.03, 1.91)}[kind]
    energy = {"POINT": 60.0, "AREA": 80.0, "SUN": 3.0, "SPOT": 150.0}[kind]
    return scenes.add_light(kind, place, energy, rotation=rotation, **props)


def _set_emission_node(light, strength, colour=(1.0, 1.0, 1.0)):
    if light.data.node_tree is None:  # up to 5.0 a light makes its node tree on request
        light.data.use_nodes = True
    emission = next(n for n in light.data.node_tree.nodes if n.type == "EMISSION")
    emission.inputs["Strength"].default_value = strength
    emission.inputs["Color"].default_value = (*colour, 1.0)


def _point(energy):
    ob = _light("POINT")
    ob.data.energy = energy
    return ob


EXACT = "read exactly"
BLACKBODY = "approximated: a black body by Planck's law and a fit of the CIE 1931 observer (cubegi_engine/blackbody.py)"
def _spot(size_deg, blend):
    ob = _light("SPOT")
    ob.data.spot_size, ob.data.spot_blend = np.radians(size_deg), blend
    ob.data.shadow_soft_size = 0.0


def _coloured():
    _point(60.0).data.color = (1.0, 0.45, 0.1)


def _no_shadow():
    ob = _light("AREA", shape="SQUARE", size=0.6)
    ob.data.use_shadow = False


def _soft_point():
    _point(60.0).data.shadow_soft_size = 0.3


def _sun(angle_deg):
    ob = _light("SUN", rotation=(np.radians(35.0), 0.0, np.radians(10.0)))
    ob.data.angle = np.radians(angle_deg)


LIGHT_ROWS = {
    "Spot light, size 60 degrees and blend 0.5": (lambda: _spot(60.0, 0.5), EXACT),
    "Spot light, size 120 degrees, blend 0": (lambda: _spot(120.0, 0.0), EXACT),
    "Light colour (orange)": (_coloured, EXACT),
    "Light Cast Shadow off": (_no_shadow, EXACT),
    "Point light radius 0.3 m (soft shadows)": (_soft_point, EXACT),
    # A sharp shadow edge falls between the box's vertices (about 5 cm apart) where it will:
    # the mean is right, a few vertices along the edge differ.
    "Sun light (angle 0.5 degrees)": (lambda: _sun(0.5), EXACT, 0.2),
    # Soft: the shadows' edges blur over about 17 cm a metre from the occluder (sharp: 47%).
    "Sun Angle 10 degrees (soft shadows)": (lambda: _sun(10.0), EXACT, 0.2),
    "Light Exposure": (lambda: setattr(_point(240.0).data, "exposure", -2.0), EXACT),
    "Area light, Normalize off": (lambda: _area_not_normalised(), EXACT),
    "Light node tree (Emission Strength 0.1, orange)": (lambda: _set_emission_node(_point(600.0), 0.1, (1.0, 0.5, 0.2)), EXACT),
    # A Blackbody node (3000 K) into its Emission Color, a Math node (2 x 0.25) into its Strength.
    "Light node tree with Blackbody and Math nodes": (lambda: _node_blackbody(), BLACKBODY),
    "Light Temperature (1800 K)": (lambda: _warm(1800.0), BLACKBODY),
    "Light Temperature (4000 K, area light)": (lambda: _warm(4000.0, "AREA"), BLACKBODY),
}


def _node_blackbody():
    ob = _point(240.0)
    _set_emission_node(ob, 1.0)
    tree = ob.data.node_tree
    emission = next(n for n in tree.nodes if n.type == "EMISSION")
    body = tree.nodes.new("ShaderNodeBlackbody")
    body.inputs["Temperature"].default_value = 3000.0
    tree.links.new(body.outputs["Color"], emission.inputs["Color"])
    half = tree.nodes.new("ShaderNodeMath")
    half.operation = "MULTIPLY"
    half.inputs[0].default_value, half.inputs[1].default_value = 2.0, 0.25
    tree.links.new(half.outputs[0], emission.inputs["Strength"])


def _warm(kelvin, kind="POINT"):
    ob = _light(kind, **({"shape": "SQUARE", "size": 0.6} if kind == "AREA" else {}))
    ob.data.use_temperature = True
    ob.data.temperature = kelvin


def _area_not_normalised():
    ob = _light("AREA", shape="SQUARE", size=0.6)
    ob.data.energy = 80.0 / 0.36  # the same light as 80 W normalised, if the area is read
    ob.data.normalize = False


@pytest.mark.parametrize("feature", list(LIGHT_ROWS))
def test_light_options_are_read_as_cycles_reads_them(empty_scene, cubegi, feature):
    obs = _box()
    make, support, *rmse_tol = LIGHT_ROWS[feature]
    make()
    err, ours, theirs = _direct_errors(cubegi, obs, per_channel=True)
    # Colour too: the area-weighted mean of each channel (against a tenth of the mean where a
    # channel is darker: 1800 K has no blue); a white light read as orange, or orange as
    # white, is 30% off or more in red or blue.
    channel_bias = (ours - theirs) / np.maximum(theirs, 0.1 * theirs.mean())
    _record(feature, support, direct_rel_bias=err["rel_bias"], direct_rel_rmse=err["rel_rmse"],
            channel_bias=channel_bias.tolist())
    assert abs(err["rel_bias"]) < DIRECT_BIAS_TOL, err
    assert err["rel_rmse"] < (rmse_tol[0] if rmse_tol else DIRECT_RMSE_TOL), err
    assert (np.abs(channel_bias) < DIRECT_BIAS_TOL).all(), channel_bias


def test_a_light_with_diffuse_visibility_off_lights_nothing_and_is_named(empty_scene, cubegi):
    obs = _box()
    _light("POINT").visible_diffuse = False
    _light("AREA", shape="SQUARE", size=0.6)
    err, ours = _direct_errors(cubegi, obs)
    _record("A light's Diffuse ray visibility off", "read exactly", direct_rel_bias=err["rel_bias"], direct_rel_rmse=err["rel_rmse"])
    assert abs(err["rel_bias"]) < DIRECT_BIAS_TOL and err["rel_rmse"] < DIRECT_RMSE_TOL, err  # the area light's alone
    assert any("light point: its Diffuse ray visibility is off" in n for n in _notes())


def _linked(ob):
    receivers = bpy.data.collections.new("Receivers")
    receivers.objects.link(next(o for o in bpy.context.scene.objects if o.type == "MESH"))
    ob.light_linking.receiver_collection = receivers


NOTED = {
    "Light Temperature below 1500 K": (lambda: _warm(1000.0), "light point: its Temperature (1000 K) is approximated",
                                       "approximated, with a note (1000 K: green 0.12 where Cycles has 0.04)"),
    "Area light Spread": (lambda: setattr(_light("AREA", shape="SQUARE", size=0.6).data, "spread", np.radians(15.0)),
                          "light area: Spread (15 degrees) is not read"),
    "Light linking": (lambda: _linked(_point(60.0)), "light point: light and shadow linking are not read"),
    "Light node tree with a texture": (lambda: _textured_light(), "light point: its node tree"),
}


def _textured_light():
    ob = _point(60.0)
    _set_emission_node(ob, 1.0)
    tree = ob.data.node_tree
    emission = next(n for n in tree.nodes if n.type == "EMISSION")
    tree.links.new(tree.nodes.new("ShaderNodeTexNoise").outputs["Color"], emission.inputs["Color"])


@pytest.mark.parametrize("feature", list(NOTED))
def test_light_options_not_read_are_named(empty_scene, cubegi, feature):
    _box()
    make, note, *support = NOTED[feature]
    make()
    assert bpy.ops.cubegi.bake(**FAST) == {"FINISHED"}
    found = [n for n in _notes() if note in n]
    _record(feature, support[0] if support else "not supported", note=found[0] if found else None)
    assert found, _notes()


# --- objects: the scene as a render evaluates it ----------------------------------------------

def _plate(name, z=1.0, half=0.2, x=-0.5):
    v, f = scenes.grid_patch((x - half, -half, z), (2 * half, 0, 0), (0, 2 * half, 0), 1, 1)
    return scenes.mesh_object(name, v, np.asarray(f)[:, ::-1], scenes.material(name, (0.5, 0.5, 0.5)))


def _render_only_array():
    plate = _plate("Plate")
    array = plate.modifiers.new("Array", "ARRAY")
    array.count, array.relative_offset_displace = 3, (1.5, 0.0, 0.0)
    array.show_viewport = False  # three plates in renders, one in the viewport


def _hidden_emitter():
    plate = _plate("Emitter", half=0.6, x=0.0)
    plate.modifiers.new("Particles", "PARTICLE_SYSTEM")
    settings = plate.particle_systems[0].settings
    settings.count, settings.frame_end, settings.lifetime = 0, 1, 1  # no particles, only the emitter matters
    plate.show_instancer_for_render = False  # the emitter does not render: it casts no shadow


def _triangulated():
    tall = bpy.data.objects["Tall"]
    tall.modifiers.new("Triangulate", "TRIANGULATE")


RENDER_ROWS = {
    "Modifier enabled in renders only (Array)": _render_only_array,
    "Particle emitter with Show Emitter off in renders": _hidden_emitter,
    "Triangulate modifier (vertex count unchanged)": _triangulated,
}


@pytest.mark.parametrize("feature", list(RENDER_ROWS))
def test_geometry_is_what_a_render_evaluates(empty_scene, cubegi, feature):
    obs = _box()
    _light("AREA", shape="SQUARE", size=0.6)
    RENDER_ROWS[feature]()
    before = {(o.name, m.name, m.show_viewport) for o in bpy.data.objects for m in o.modifiers}
    err, _ = _direct_errors(cubegi, obs)
    _record(feature, "read exactly", direct_rel_bias=err["rel_bias"], direct_rel_rmse=err["rel_rmse"])
    assert {(o.name, m.name, m.show_viewport) for o in bpy.data.objects for m in o.modifiers} == before  # put back
    assert abs(err["rel_bias"]) < DIRECT_BIAS_TOL and err["rel_rmse"] < DIRECT_RMSE_TOL, err
    assert not [n for n in _notes() if "vertex count" in n and n.split(":")[0] in {o.name for o in obs}], _notes()  # all baked


def test_an_unnamed_color_attribute_node_reads_the_render_attribute_and_baking_twice_changes_nothing(empty_scene, cubegi):
    obs = _box()
    _light("AREA", shape="SQUARE", size=0.6)
    floor = bpy.data.objects["Floor"]
    mesh = floor.data
    for name, colour in (("Paint", (0.8, 0.1, 0.1)), ("Other", (0.1, 0.8, 0.1))):
        attr = mesh.color_attributes.new(name, "FLOAT_COLOR", "POINT")
        attr.data.foreach_set("color", np.tile((*colour, 1.0), len(attr.data)).astype(np.float32).ravel())
    mesh.color_attributes.render_color_index = mesh.color_attributes.find("Paint")
    mesh.color_attributes.active_color = mesh.color_attributes["Other"]
    tree = floor.active_material.node_tree
    node = tree.nodes.new("ShaderNodeVertexColor")  # layer_name left empty
    bsdf = next(n for n in tree.nodes if n.type == "BSDF_PRINCIPLED")
    tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
    read = cubegi.cubegi_addon.attributes.read
    assert bpy.ops.cubegi.bake(**FAST) == {"FINISHED"}
    first = {o.name: read(o.data, "CubeGI_total") for o in obs}
    kept = cubegi.cubegi_addon.session.kept(bpy.context.scene)
    floor_albedo = kept.bake.arrays.albedo[kept.bake.arrays.point_object == kept.bake.arrays.object_names.index("Floor")]
    np.testing.assert_allclose(floor_albedo, np.tile((0.8, 0.1, 0.1), (len(floor_albedo), 1)), atol=1e-6)
    cubegi.cubegi_addon.session.forget()
    assert bpy.ops.cubegi.bake(**FAST) == {"FINISHED"}
    for o in obs:
        np.testing.assert_allclose(read(o.data, "CubeGI_total"), first[o.name], rtol=1e-5, atol=1e-7, err_msg=o.name)
    _record("Color Attribute node with no name", "read exactly", note="the render colour attribute; a second bake equal")


def _shadow_off():
    bpy.data.objects["Tall"].visible_shadow = False


def _alpha():
    mat = bpy.data.objects["Tall"].active_material
    next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED").inputs["Alpha"].default_value = 0.0


def _generated_coordinates():
    tree = bpy.data.objects["Floor"].active_material.node_tree
    image = bpy.data.images.new("Checker", 8, 8)
    image.generated_type = "COLOR_GRID"
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    coords = tree.nodes.new("ShaderNodeTexCoord")
    tree.links.new(coords.outputs["Generated"], tex.inputs["Vector"])
    bsdf = next(n for n in tree.nodes if n.type == "BSDF_PRINCIPLED")
    tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    bpy.data.objects["Floor"].data.uv_layers.new(name="UVMap")


def _background_set():
    backdrop = bpy.data.scenes.new("Backdrop")
    v, f = scenes.box_mesh((-3, -3, -0.5), (3, 3, 3), (2, 2, 2), inward=True)
    scenes.mesh_object("Set", v, f, scenes.material("Set", (0.5, 0.5, 0.5)), collection=backdrop.collection)
    bpy.context.scene.background_set = backdrop


def _emission_in_group():
    group = bpy.data.node_groups.new("Glow", "ShaderNodeTree")
    group.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
    out = group.nodes.new("NodeGroupOutput")
    glow = group.nodes.new("ShaderNodeEmission")
    glow.inputs["Strength"].default_value = 5.0
    group.links.new(glow.outputs["Emission"], out.inputs[0])
    mat = bpy.data.objects["Short"].active_material = scenes.material("Glowing", (0.5, 0.5, 0.5))
    tree = mat.node_tree
    node = tree.nodes.new("ShaderNodeGroup")
    node.node_tree = group
    output = next(n for n in tree.nodes if n.type == "OUTPUT_MATERIAL")
    tree.links.new(node.outputs[0], output.inputs["Surface"])


OBJECT_NOTES = {
    "Object Visibility > Shadow off": (_shadow_off, "Tall: Visibility > Shadow is off"),
    "Principled Alpha below 1 (a cut-out)": (_alpha, "Alpha is not read; baked as an opaque surface"),
    "Image texture mapped by Generated coordinates": (_generated_coordinates, "is mapped by the Generated output of a "
                                                      "Texture Coordinate node, which CubeGI does not read; sampled at the UV map"),
    "Background Set scene": (_background_set, "its Background Set 'Backdrop' is not read"),
    "Emission shader inside a node group": (_emission_in_group, "its surface is a node group, which CubeGI does not read"),
}


def _assert_noted(feature, make, note, support):
    """Bake the box lit by an area light with ``make()``'s feature: a note holds ``note``."""
    _box()
    _light("AREA", shape="SQUARE", size=0.6)
    make()
    assert bpy.ops.cubegi.bake(**FAST) == {"FINISHED"}
    found = [n for n in _notes() if note in n]
    _record(feature, support, note=found[0] if found else None)
    assert found, _notes()


@pytest.mark.parametrize("feature", list(OBJECT_NOTES))
def test_object_and_material_features_not_read_are_named(empty_scene, cubegi, feature):
    _assert_noted(feature, *OBJECT_NOTES[feature], "not supported")


# --- materials, the world, more objects ----------------------------------------------------------

def _material_of(name, make):
    """Give object ``name`` a material whose surface ``make(tree, output)`` wires."""
    mat = bpy.data.materials.new(f"{name} surface")
    if mat.node_tree is None:
        mat.use_nodes = True
    tree = mat.node_tree
    for node in [n for n in tree.nodes if n.type != "OUTPUT_MATERIAL"]:
        tree.nodes.remove(node)
    output = next(n for n in tree.nodes if n.type == "OUTPUT_MATERIAL")
    make(tree, output)
    bpy.data.objects[name].data.materials.clear()
    bpy.data.objects[name].data.materials.append(mat)


def _diffuse_bsdf():
    def make(tree, output):
        bsdf = tree.nodes.new("ShaderNodeBsdfDiffuse")
        bsdf.inputs["Color"].default_value = (0.8, 0.1, 0.1, 1.0)
        tree.links.new(bsdf.outputs["BSDF"], output.inputs["Surface"])
    _material_of("Tall", make)


def _emission_shader():
    def make(tree, output):
        glow = tree.nodes.new("ShaderNodeEmission")
        glow.inputs["Color"].default_value = (1.0, 0.8, 0.6, 1.0)
        glow.inputs["Strength"].default_value = 3.0
        tree.links.new(glow.outputs["Emission"], output.inputs["Surface"])
    _material_of("Short", make)


def _principled(name, **inputs):
    mat = bpy.data.objects[name].active_material
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    for key, value in inputs.items():
        bsdf.inputs[key].default_value = value


def _dark_glossy():
    """Every surface of the box dark (base colour 0.1) at Specular IOR Level 1: its specular
    layer sends on about a third as much again as the base colour."""
    for mat in bpy.data.materials:
        bsdf = next((n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None)
        if bsdf is not None:
            bsdf.inputs["Base Color"].default_value = (0.1, 0.1, 0.1, 1.0)
            bsdf.inputs["Specular IOR Level"].default_value = 1.0


def _textured_roughness():
    mat = bpy.data.objects["Tall"].active_material
    noise = mat.node_tree.nodes.new("ShaderNodeTexNoise")
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    mat.node_tree.links.new(noise.outputs["Fac"], bsdf.inputs["Roughness"])


def _mixed(kind):
    def make(tree, output):
        a = tree.nodes.new("ShaderNodeBsdfDiffuse")
        a.inputs["Color"].default_value = (0.4, 0.05, 0.05, 1.0)
        b = tree.nodes.new("ShaderNodeBsdfDiffuse" if kind == "ADD" else "ShaderNodeBsdfGlossy")
        b.inputs["Color"].default_value = (0.3, 0.3, 0.3, 1.0)  # together at most 0.7: the box stays finite
        mix = tree.nodes.new("ShaderNodeAddShader" if kind == "ADD" else "ShaderNodeMixShader")
        sockets = [s for s in mix.inputs if s.type == "SHADER"]
        tree.links.new(a.outputs["BSDF"], sockets[0])
        tree.links.new(b.outputs["BSDF"], sockets[1])
        tree.links.new(mix.outputs["Shader"], output.inputs["Surface"])
    _material_of("Tall", make)


def _holdout():
    def make(tree, output):
        tree.links.new(tree.nodes.new("ShaderNodeHoldout").outputs["Holdout"], output.inputs["Surface"])
    _material_of("Tall", make)


def _sky_per_vertex():
    scenes.set_world((0.2, 0.4, 0.8), 2.0)
    bpy.context.scene.cubegi.sky_per_vertex = True


def _world_colour_node():
    """The world's colour from a Color (RGB) node, its own Color a dim grey: read as the node's."""
    world = scenes.set_world((0.05, 0.05, 0.05), 2.0)
    tree = world.node_tree
    rgb = tree.nodes.new("ShaderNodeRGB")
    rgb.outputs[0].default_value = (0.2, 0.4, 0.8, 1.0)
    tree.links.new(rgb.outputs[0], next(n for n in tree.nodes if n.type == "BACKGROUND").inputs["Color"])
    bpy.context.scene.cubegi.sky_per_vertex = True


def _sky_texture():
    world = scenes.set_world((0.2, 0.3, 0.5), 1.0)
    tree = world.node_tree
    bg = next(n for n in tree.nodes if n.type == "BACKGROUND")
    tree.links.new(tree.nodes.new("ShaderNodeTexSky").outputs["Color"], bg.inputs["Color"])


def _world_unseen_by_diffuse():
    world = scenes.set_world((0.2, 0.4, 0.8), 4.0)
    world.cycles_visibility.diffuse = False
    _light("AREA", shape="SQUARE", size=0.6)


def _object_mapped(output):
    _generated_coordinates()
    tree = bpy.data.objects["Floor"].active_material.node_tree
    coords = next(n for n in tree.nodes if n.type == "TEX_COORD")
    tex = next(n for n in tree.nodes if n.type == "TEX_IMAGE")
    tree.links.new(coords.outputs[output], tex.inputs["Vector"])


def _attribute_node():
    floor = bpy.data.objects["Floor"]
    mesh = floor.data
    attr = mesh.attributes.new("Paint", "FLOAT_COLOR", "POINT")
    attr.data.foreach_set("color", np.tile((0.8, 0.1, 0.1, 1.0), len(attr.data)).astype(np.float32).ravel())
    floor.active_material = floor.active_material.copy()  # the floor's alone (the white is the walls' too)
    tree = floor.active_material.node_tree
    node = tree.nodes.new("ShaderNodeAttribute")
    node.attribute_name = "Paint"
    bsdf = next(n for n in tree.nodes if n.type == "BSDF_PRINCIPLED")
    tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])


def _mapped_environment():
    world = scenes.set_world((1.0, 1.0, 1.0), 1.0)
    image = bpy.data.images.new("Sky", 16, 8, float_buffer=True)
    image.pixels.foreach_set(np.tile((0.3, 0.5, 0.9, 1.0), 16 * 8).astype(np.float32))
    tree = world.node_tree
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = image
    mapping = tree.nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, 1.0)
    tree.links.new(tree.nodes.new("ShaderNodeTexCoord").outputs["Generated"], mapping.inputs["Vector"])
    tree.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    tree.links.new(env.outputs["Color"], next(n for n in tree.nodes if n.type == "BACKGROUND").inputs["Color"])


def _metaball():
    meta = bpy.data.metaballs.new("Blob")
    meta.elements.new().radius = 0.3
    ob = bpy.data.objects.new("Blob", meta)
    ob.location = (0.4, 0.3, 0.5)
    bpy.context.scene.collection.objects.link(ob)


def _bevelled_curve():
    curve = bpy.data.curves.new("Rail", "CURVE")
    curve.dimensions, curve.bevel_depth = "3D", 0.05
    spline = curve.splines.new("POLY")
    spline.points.add(1)
    spline.points[0].co, spline.points[1].co = (-0.6, 0.4, 0.3, 1.0), (0.6, 0.4, 0.3, 1.0)
    ob = bpy.data.objects.new("Rail", curve)
    bpy.context.scene.collection.objects.link(ob)


def _uv_map_by_name():
    """The floor's image on its second UV map, named by a UV Map node: the first (all at one
    corner of the image) would give one colour, the second a red and blue floor."""
    floor = bpy.data.objects["Floor"]
    mesh = floor.data
    mesh.uv_layers.new(name="First")  # all zeros: the image's first pixel
    second = mesh.uv_layers.new(name="Second")
    co = np.array([v.co for v in mesh.vertices])
    loops = np.array([loop.vertex_index for loop in mesh.loops])
    lo, hi = co.min(axis=0), co.max(axis=0)
    uv = (co[loops][:, :2] - lo[:2]) / np.maximum(hi[:2] - lo[:2], 1e-9)
    second.data.foreach_set("uv", uv.astype(np.float32).ravel())
    image = bpy.data.images.new("Halves", 2, 1, float_buffer=True)
    image.pixels.foreach_set(np.array([0.8, 0.1, 0.1, 1.0, 0.1, 0.1, 0.8, 1.0], dtype=np.float32))
    floor.active_material = floor.active_material.copy()
    tree = floor.active_material.node_tree
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    node = tree.nodes.new("ShaderNodeUVMap")
    node.uv_map = "Second"
    tree.links.new(node.outputs["UV"], tex.inputs["Vector"])
    tree.links.new(tex.outputs["Color"], next(n for n in tree.nodes if n.type == "BSDF_PRINCIPLED").inputs["Base Color"])


def _image_without_uv_map():
    """The floor (no UV map) dark in the viewport, its Base Color a light image: Cycles reads
    the image at UV (0, 0), and so does CubeGI (it took the viewport colour)."""
    floor = bpy.data.objects["Floor"]
    assert not floor.data.uv_layers
    image = bpy.data.images.new("Light", 2, 2, float_buffer=True)
    image.pixels.foreach_set(np.tile(np.array([0.9, 0.85, 0.8, 1.0], dtype=np.float32), 4))
    floor.active_material = floor.active_material.copy()
    floor.active_material.diffuse_color = (0.05, 0.05, 0.05, 1.0)
    tree = floor.active_material.node_tree
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tree.links.new(tex.outputs["Color"], next(n for n in tree.nodes if n.type == "BSDF_PRINCIPLED").inputs["Base Color"])


def _geometry_nodes_instances():
    v, f = scenes.grid_patch((-0.6, 0.2, 0.05), (1.2, 0, 0), (0, 0.4, 0), 2, 1)
    ob = scenes.mesh_object("Scatter", v, f, scenes.material("Scatter", (0.5, 0.5, 0.5)))
    group = bpy.data.node_groups.new("Scatter", "GeometryNodeTree")
    group.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    group.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes = group.nodes
    inp, out = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    on_points, cube = nodes.new("GeometryNodeInstanceOnPoints"), nodes.new("GeometryNodeMeshCube")
    cube.inputs["Size"].default_value = (0.1, 0.1, 0.1)
    group.links.new(inp.outputs[0], on_points.inputs["Points"])
    group.links.new(cube.outputs["Mesh"], on_points.inputs["Instance"])
    group.links.new(on_points.outputs["Instances"], out.inputs[0])
    ob.modifiers.new("Scatter", "NODES").node_group = group


def _indirect_only():
    collection = bpy.data.collections.new("Props")
    bpy.context.scene.collection.children.link(collection)
    tall = bpy.data.objects["Tall"]
    for owner in list(tall.users_collection):
        owner.objects.unlink(tall)
    collection.objects.link(tall)
    bpy.context.view_layer.layer_collection.children["Props"].indirect_only = True


def _particle_instances():
    _instanced()
    shade = bpy.data.objects["Shade"]
    plate = _plate("Emitter", half=0.6, x=0.0, z=0.02)
    plate.modifiers.new("Particles", "PARTICLE_SYSTEM")
    settings = plate.particle_systems[0].settings
    settings.count, settings.frame_end, settings.render_type, settings.instance_object = 4, 1, "OBJECT", shade


def _instanced():
    lamp_shade = bpy.data.collections.new("Shade")
    v, f = scenes.box_mesh((-0.1, -0.1, 0.0), (0.1, 0.1, 0.2), (1, 1, 1), inward=False)
    scenes.mesh_object("Shade", v, f, scenes.material("Shade", (0.5, 0.5, 0.5)), collection=lamp_shade)
    empty = bpy.data.objects.new("Shades", None)
    empty.instance_type, empty.instance_collection = "COLLECTION", lamp_shade
    empty.location = (0.5, 0.5, 0.3)
    bpy.context.scene.collection.objects.link(empty)


def _text():
    curve = bpy.data.curves.new("Sign", "FONT")
    curve.body, curve.extrude = "GI", 0.05
    ob = bpy.data.objects.new("Sign", curve)
    ob.location = (-0.5, 0.3, 0.4)
    bpy.context.scene.collection.objects.link(ob)


EMITTERS = ("approximated: emitters light the scene as area lights (exact form factors, shadow maps from their "
            "sample points); measured -7% to +2% here")
SPECULAR = ("approximated: the light its specular layer reflects is sent on as a diffuse surface's (a share measured in "
            "Cycles by Roughness and the facing reflectance: cubegi_engine/specular.py)")
SKY_THROUGH_PROBES = "approximated: through the probes (-7% here); with Sky per Vertex exact to a few per cent"
MATERIAL_ROWS = {
    # feature: (make the scene, the pass compared, support, tolerance of the bias)
    "Diffuse BSDF (red)": (_diffuse_bsdf, "INDIRECT", EXACT, None),
    "Principled Base Color (blue)": (lambda: _principled("Tall", **{"Base Color": (0.1, 0.2, 0.8, 1.0)}), "INDIRECT", EXACT, None),
    "Principled specular layer (every surface base colour 0.1, Specular IOR Level 1)": (_dark_glossy, "INDIRECT", SPECULAR, None),
    "Emission shader (a glowing block)": (_emission_shader, "DIRECT", EMITTERS, 0.1),
    "Principled Emission (strength 4)": (lambda: _principled("Short", **{"Emission Color": (1.0, 0.9, 0.7, 1.0),
                                                                         "Emission Strength": 4.0}), "DIRECT", EMITTERS, 0.1),
    "Add Shader of two Diffuse BSDFs": (lambda: _mixed("ADD"), "INDIRECT", EXACT, None),
    "World colour and strength (through the open front)": (lambda: scenes.set_world((0.2, 0.4, 0.8), 2.0), "DIRECT",
                                                           SKY_THROUGH_PROBES, 0.1),
    "World colour, Sky per Vertex": (lambda: _sky_per_vertex(), "DIRECT", EXACT, None),
    "World colour from a Color node, Sky per Vertex": (_world_colour_node, "DIRECT", EXACT, None),
    "Object Visibility > Camera off": (lambda: setattr(bpy.data.objects["Tall"], "visible_camera", False), "DIRECT", EXACT, None),
    "Attribute node (a named colour attribute)": (lambda: _attribute_node(), "INDIRECT", EXACT, None),
    "Image texture on a UV map named by a UV Map node": (_uv_map_by_name, "INDIRECT", EXACT, None),
    "Image texture on a mesh with no UV map": (lambda: _image_without_uv_map(), "INDIRECT", EXACT, None),
    # (the area light is the only light the surfaces get; the world, 4x brighter, lights none)
    "World Ray Visibility > Diffuse off": (_world_unseen_by_diffuse, "DIRECT", EXACT, None),
}
# The indirect light against Cycles: CubeGI's own error on the Cornell box is 1-3% per wall at
# higher settings; FAST's 3 x 3 x 3 probes, one bounce and the tail make it -7% to -10% here (a
# material read wrong, its viewport grey for a red, is off by half or more).
INDIRECT_BIAS_TOL = 0.15


@pytest.mark.parametrize("feature", list(MATERIAL_ROWS))
def test_materials_and_the_world_are_read_as_cycles_reads_them(empty_scene, cubegi, feature):
    obs = _box()
    make, which, support, bias_tol = MATERIAL_ROWS[feature]
    if "World" not in feature:
        _light("AREA", shape="SQUARE", size=0.6)
    make()
    reference, scene_data, attributes = (getattr(cubegi.cubegi_addon, m) for m in ("reference", "scene_data", "attributes"))
    assert bpy.ops.cubegi.bake(**FAST) == {"FINISHED"}
    baked, _ = reference.bake_reference(bpy.context, obs, passes=(which,), samples=SAMPLES)
    layer = "CubeGI_direct" if which == "DIRECT" else "CubeGI"
    areas = np.concatenate([scene_data.vertex_areas(o) for o in obs])
    ours = np.concatenate([attributes.read(o.data, layer) for o in obs])
    theirs = np.concatenate([baked[which][o.name] for o in obs])
    err = metrics.errors(ours, theirs, areas)
    _record(feature, support, **{f"{which.lower()}_rel_bias": err["rel_bias"], f"{which.lower()}_rel_rmse": err["rel_rmse"]})
    tol = bias_tol or (DIRECT_BIAS_TOL if which == "DIRECT" else INDIRECT_BIAS_TOL)
    assert abs(err["rel_bias"]) < tol, err
    assert not [n for n in _notes() if "not understood" in n or "does not read" in n], _notes()
    if feature.startswith("Image texture on a UV map"):  # red and blue halves, not the first map's one colour
        kept = cubegi.cubegi_addon.session.kept(bpy.context.scene)
        albedo = kept.bake.arrays.albedo[kept.bake.arrays.point_object == kept.bake.arrays.object_names.index("Floor")]
        assert albedo[:, 0].max() > 0.7 and albedo[:, 0].min() < 0.2 and albedo[:, 2].max() > 0.7, albedo


MATERIAL_NOTES = {
    "Principled Metallic 1": (lambda: _principled("Tall", Metallic=1.0), "metallic"),
    "Principled Transmission 1": (lambda: _principled("Tall", **{"Transmission Weight": 1.0}), "transmissive"),
    "Mix Shader (Diffuse and Glossy)": (lambda: _mixed("MIX"), "its Glossy BSDF shader is baked as a diffuse reflection"),
    "Holdout shader": (_holdout, "shader ShaderNodeHoldout not understood, using its viewport colour"),
    "World Sky Texture": (_sky_texture, "Sky"),
    "Collection instance": (_instanced, "Shades: its instances of Shade light the others but are not baked"),
    "Geometry Nodes instances (Instance on Points)": (_geometry_nodes_instances, "Scatter: its instances of"),
    "Particle instances (an object per particle)": (_particle_instances, "Emitter: its instances of Shade"),
    "Collection Indirect Only": (_indirect_only, "Tall: its collection 'Props' is Indirect Only"),
    "Text object": (_text, "Sign: font object lit and lighting others, but not baked"),
    "Metaball": (_metaball, "Blob: metaballs are not read"),
    "Object Visibility > Holdout": (lambda: setattr(bpy.data.objects["Tall"], "is_holdout", True),
                                    "Tall: Visibility > Holdout is on, which CubeGI does not read"),
    "Curve with a bevel (render geometry)": (_bevelled_curve, "Rail: curve object lit and lighting others, but not baked"),
    "Image texture mapped by Object coordinates": (lambda: _object_mapped("Object"), "is mapped by the Object output"),
    "Environment Texture rotated by a Mapping node": (_mapped_environment, "is mapped"),
    "Principled Subsurface Weight 1": (lambda: _principled("Tall", **{"Subsurface Weight": 1.0}), "subsurface-scattering"),
    "Principled Roughness from a texture": (_textured_roughness, "Roughness fed by a Noise Texture node, which CubeGI does not "
                                            "read; using 1"),
}


@pytest.mark.parametrize("feature", list(MATERIAL_NOTES))
def test_materials_world_and_objects_not_read_exactly_are_named(empty_scene, cubegi, feature):
    _assert_noted(feature, *MATERIAL_NOTES[feature], "approximated, with a note")


def test_keyframed_light_world_and_material_are_read_each_frame_by_bake_animation(empty_scene, cubegi, tmp_path):
    """Animation: the options of the rows above keyframed at once (a light's power, colour,
    Exposure and Temperature, a spot's size and blend, the world's strength, a material's
    colour and emission, an object's place and its render visibility): every frame of
    ``bake-animation`` equals a still bake of that frame, so each is read per frame as the
    still rows read it against Cycles."""
    import subprocess
    import sys

    obs = _box()
    lamp = _light("AREA", shape="SQUARE", size=0.6)
    world = scenes.set_world((0.2, 0.3, 0.5), 0.5)
    background = next(n for n in world.node_tree.nodes if n.type == "BACKGROUND")
    bsdf = next(n for n in bpy.data.objects["Tall"].active_material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    spot = _light("SPOT")
    spot.data.use_temperature = True
    glow = next(n for n in bpy.data.objects["Short"].active_material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    glow.inputs["Emission Color"].default_value = (1.0, 0.9, 0.7, 1.0)
    tall = bpy.data.objects["Tall"]
    keys = {1: dict(energy=80.0, strength=0.5, colour=(0.8, 0.1, 0.1, 1.0), light=(1.0, 1.0, 1.0), exposure=0.0, kelvin=6500.0,
                    size=60.0, blend=0.1, emission=0.0, x=tall.location.x, hidden=False),
            3: dict(energy=20.0, strength=2.0, colour=(0.1, 0.1, 0.8, 1.0), light=(1.0, 0.5, 0.2), exposure=-1.0, kelvin=2500.0,
                    size=110.0, blend=0.6, emission=3.0, x=tall.location.x + 0.3, hidden=True)}
    for frame, k in keys.items():
        lamp.data.energy, background.inputs["Strength"].default_value = k["energy"], k["strength"]
        bsdf.inputs["Base Color"].default_value = k["colour"]
        spot.data.color, spot.data.exposure, spot.data.temperature = k["light"], k["exposure"], k["kelvin"]
        spot.data.spot_size, spot.data.spot_blend = np.radians(k["size"]), k["blend"]
        glow.inputs["Emission Strength"].default_value = k["emission"]
        tall.location.x = k["x"]
        bpy.data.objects["Short"].hide_render = k["hidden"]
        lamp.data.keyframe_insert("energy", frame=frame)
        background.inputs["Strength"].keyframe_insert("default_value", frame=frame)
        bsdf.inputs["Base Color"].keyframe_insert("default_value", frame=frame)
        for prop in ("color", "exposure", "temperature", "spot_size", "spot_blend"):
            spot.data.keyframe_insert(prop, frame=frame)
        glow.inputs["Emission Strength"].keyframe_insert("default_value", frame=frame)
        tall.keyframe_insert("location", frame=frame)
        bpy.data.objects["Short"].keyframe_insert("hide_render", frame=frame)
    src, out = tmp_path / "anim.blend", tmp_path / "out.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(src))
    r = subprocess.run([sys.executable, "-m", "cubegi_engine", "bake-animation", str(src), "-o", str(out), "--frames", "1", "3",
                        "--bounces", "1", "--grid", "3", "3", "3", "--cube-size", "16"], cwd=ROOT, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    worst = 0.0
    for frame in (1, 2, 3):
        bpy.context.scene.frame_set(frame)
        assert bpy.ops.cubegi.bake(**FAST) == {"FINISHED"}
        read = cubegi.cubegi_addon.attributes.read
        with np.load(tmp_path / "out.cubegi" / f"frame_{frame:04d}.npz") as data:
            for o in [o for o in obs if not o.hide_render]:
                for part, layer in (("direct", "CubeGI_direct"), ("indirect", "CubeGI")):
                    still, cached = read(o.data, layer), data[f"{o.name}:{part}"]
                    worst = max(worst, float(np.abs(cached - still).max() / max(still.max(), 1e-9)))
    _record("Keyframed: light power, colour, Exposure, Temperature, spot size and blend, world strength, material "
            "colour and emission, an object's place and render visibility (bake-animation)", EXACT,
            note=f"every frame equals a still bake of it (largest difference {100 * worst:.2g}% of the peak)")
    assert worst < 1e-3, worst


def test_surfaces_with_no_diffuse_closure_are_left_out_of_the_errors(empty_scene, cubegi):
    """A block at Metallic 1 and one at Transmission Weight 1: Cycles' Diffuse bake gives them
    no light (no diffuse closure), CubeGI bakes them as diffuse (with a note), so the errors
    against Cycles leave their vertices out (scene_data.scored_areas), as they leave out
    black ones; the other surfaces count. (A new user's shop scored its metal shelf: the
    bake's p95 error 159,425%.)"""
    obs = _box()
    _light("AREA", shape="SQUARE", size=0.6)
    for name, inputs in (("Tall", {"Metallic": 1.0}), ("Short", {"Transmission Weight": 1.0})):
        ob = bpy.data.objects[name]
        ob.active_material = ob.active_material.copy()
        _principled(name, **inputs)
    assert bpy.ops.cubegi.bake(**FAST) == {"FINISHED"}
    addon = cubegi.cubegi_addon
    kept = addon.session.kept(bpy.context.scene)
    scored = addon.scene_data.scored_areas(kept.bake.targets, kept.bake.arrays)
    baked, _ = addon.reference.bake_reference(bpy.context, obs, passes=("DIRECT", "INDIRECT"), samples=4)
    for ob in obs:
        none_in_cycles = ob.name in ("Tall", "Short")
        assert (scored[ob.name].sum() == 0) == none_in_cycles, ob.name
        assert (baked["DIRECT"][ob.name].max() + baked["INDIRECT"][ob.name].max() == 0) == none_in_cycles, ob.name
    report = json.loads(bpy.context.scene.cubegi.last_report)
    assert any("metallic" in n for n in report["scene"]["notes"]) and any("transmissive" in n for n in report["scene"]["notes"])
