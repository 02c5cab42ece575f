"""CubeGI against Cycles, baked inside the test, on a small Cornell-box-like scene.

The box (``benchmarks/scenes.py``, ``cornell``) is 2 m on a side, open at the front (-Y), with a red left
and a green right wall and two blocks standing a little above the floor. Lights sit off the 0.1 m lattice of the
geometry: a shadow boundary that passes exactly through a row of vertices (or a sun exactly
edge-on to a wall) makes those vertices a coin toss for any method. Cycles bakes the same vertices' DIRECT and
INDIRECT diffuse light (colour pass off) with a fixed seed.
"""

import json

import bpy
import numpy as np
import pytest
import scenes

from cubegi.cubegi_engine import metrics

# Tolerances, and what limits them:
# * direct light: CubeGI's formulas are exact for unshadowed light; the error left is
#   Cycles' noise at 128 samples (about 1% of the mean), shadow-map aliasing along shadow
#   edges (texel size 1/512 of 90 degrees; area lights: 64 samples at 1/128) and the single
#   shadow sample of a point light with a small radius against Cycles' soft shadow.
#   Measured (seed 0): |bias| <= 0.6% for every type; rel. RMSE 0.5% (point), 0.7% (spot),
#   1.6% to 2.2% (area; with 16 samples it was 3.3% to 4.5%, with 144 1.2% to 1.7%).
DIRECT_BIAS_TOL = 0.03
DIRECT_RMSE_TOL = 0.08
# * the sun's RMSE is 0.047 (0.10 with a 2048^2 map): the sun shines in through the open
#   front at a grazing angle, and the vertices on the lines where the floor and back wall
#   meet the side walls sit exactly on a shadow edge, so each one is fully lit or fully dark
#   by a hair's breadth in either renderer. A handful of vertices carries the whole RMSE;
#   the bias is -0.0%.
DIRECT_RMSE_TOL_BY_LIGHT = {"sun": 0.15}
# * indirect light: interpolating 9 SH coefficients between probes half a metre apart
#   blurs the light in space and direction (the method's own bias); the corners, where the
#   light changes fastest, carry most of it.
#   Probes see concave corners from half a metre away, so corners get too much light; the
#   near field (rays to the surfaces within an eighth of a metre) takes most of that back:
#   measured bias -3.2% and rel. RMSE 0.17 after 4 bounces (and the tail) on a 4x4x4 grid
#   with energy conservation (without the near field -3.5% and 0.21; without either, +8.5%
#   and 0.23).
INDIRECT_BIAS_TOL = 0.06
INDIRECT_RMSE_TOL = 0.20
# A dark glossy box's indirect bias with its specular layer's light (see the test): +6.3%.
SPECULAR_BIAS_TOL = 0.10


def cornell_box():
    scenes.cornell(light=False)
    return [ob for ob in bpy.context.scene.objects if ob.type == "MESH"]


LIGHTS = {
    "point": dict(kind="POINT", location=(0.13, -0.27, 1.63), energy=60.0, shadow_soft_size=0.01),
    "spot": dict(
        kind="SPOT", location=(0.07, 0.03, 1.91), energy=150.0, shadow_soft_size=0.01,
        spot_size=np.radians(75), spot_blend=0.3, rotation=(0.25, 0.0, 0.0),
    ),
    "sun": dict(kind="SUN", location=(0, -3, 3), energy=3.0, rotation=(np.radians(50), 0.0, np.radians(20))),
    "area_square": dict(kind="AREA", location=(0, 0, 1.98), energy=80.0, shape="SQUARE", size=0.6),
    "area_rectangle": dict(kind="AREA", location=(0, 0.2, 1.98), energy=80.0, shape="RECTANGLE", size=0.9, size_y=0.4),
    "area_disk": dict(kind="AREA", location=(0, 0, 1.98), energy=80.0, shape="DISK", size=0.6),
    "area_ellipse": dict(kind="AREA", location=(0.2, 0, 1.98), energy=80.0, shape="ELLIPSE", size=0.8, size_y=0.4),
}


def _bake_both(cubegi, obs, passes, samples):
    reference = cubegi.cubegi_addon.reference
    scene_data = cubegi.cubegi_addon.scene_data
    attributes = cubegi.cubegi_addon.attributes
    assert bpy.ops.cubegi.bake(bounces=4, grid=(4, 4, 4), cube_size=32) == {"FINISHED"}
    ref, _ = reference.bake_reference(bpy.context, obs, passes=passes, samples=samples)
    areas = np.concatenate([scene_data.vertex_areas(o) for o in obs])
    ours = {
        "DIRECT": np.concatenate([attributes.read(o.data, "CubeGI_direct") for o in obs]),
        "INDIRECT": np.concatenate([attributes.read(o.data, "CubeGI") for o in obs]),
    }
    theirs = {p: np.concatenate([ref[p][o.name] for o in obs]) for p in passes}
    return {p: metrics.errors(ours[p], theirs[p], areas) for p in passes}


@pytest.mark.parametrize("light", list(LIGHTS))
def test_direct_light_matches_cycles(empty_scene, cubegi, light):
    obs = cornell_box()
    spec = dict(LIGHTS[light])
    kind, loc, energy = spec.pop("kind"), spec.pop("location"), spec.pop("energy")
    rotation = spec.pop("rotation", (0.0, 0.0, 0.0))
    scenes.add_light(kind, loc, energy, rotation, **spec)
    err = _bake_both(cubegi, obs, ("DIRECT",), samples=128)["DIRECT"]
    print(light, err)
    assert abs(err["rel_bias"]) < DIRECT_BIAS_TOL, err
    assert err["rel_rmse"] < DIRECT_RMSE_TOL_BY_LIGHT.get(light, DIRECT_RMSE_TOL), err


def test_indirect_light_matches_cycles(empty_scene, cubegi):
    scenes.cornell(light=True)
    obs = [ob for ob in bpy.context.scene.objects if ob.type == "MESH"]
    err = _bake_both(cubegi, obs, ("DIRECT", "INDIRECT"), samples=256)
    print(err)
    assert abs(err["INDIRECT"]["rel_bias"]) < INDIRECT_BIAS_TOL, err
    assert err["INDIRECT"]["rel_rmse"] < INDIRECT_RMSE_TOL, err


def test_a_closed_room_at_albedo_0_95_is_within_3_percent_of_cycles(empty_scene, cubegi):
    """Light bounces about 20 times here, so an energy error per bounce is amplified about
    20 times: this is what energy conservation per bounce is for. Measured: indirect bias
    -2.5% at 4x4x4 probes with 16^2 and 32^2 faces and at 6x6x6 (without the correction:
    +2.4%, +3.7%, -3.5%). Cycles at 256 samples, diffuse bounces unlimited."""
    import json

    rho = 0.95
    scenes.closed_box(size=2.0, cells=8, albedo=rho)
    v, f = scenes.box_mesh((-0.4, -0.5, -1.0), (0.3, 0.2, -0.1), (3, 3, 3), inward=False)
    scenes.mesh_object("Block", v, f, scenes.material("Grey", (rho,) * 3))
    scenes.add_light("POINT", (0.3, -0.2, 0.5), 20.0)
    assert bpy.ops.cubegi.bake(bounces=8, grid=(4, 4, 4), cube_size=16, reference_samples=256) == {"FINISHED"}
    report = json.loads(bpy.context.scene.cubegi.last_report)
    errors = report["reference"]["errors"]
    print(errors)
    assert report["tail"]["added"] and report["tail"]["share_of_indirect"] > 0.5  # most of it is the tail
    assert abs(errors["indirect"]["rel_bias"]) < 0.03, errors
    assert abs(errors["total"]["rel_bias"]) < 0.03, errors
    # What the correction did: bounce 1 (light from a point light, very uneven) had 9% too
    # much; later bounces (smoother light) were within 0.4% and are corrected by that much.
    factors = [r["energy_factor"] for r in report["bounces"]]
    assert all(0.85 < f < 1.15 for f in factors[0]) and all(0.99 < f < 1.01 for fs in factors[1:] for f in fs), factors


def test_an_emissive_panel_lights_both_ways_as_cycles_does(empty_scene, cubegi):
    """A one-sided emissive quad hanging 0.4 m below a white ceiling, facing down: Cycles
    emits from both faces, so the ceiling above it is lit. Emissive triangles are two-sided
    area lights here (exact form factors, shadow maps from points on both faces). Measured at
    128 samples: direct rel. RMSE 2.0%, bias -0.1% (through the probes it was 260%, -50%);
    indirect 21.9%, bias +15% (was 46%, -43%): the probes see the panel's upper face as a
    back face, which passes on no light."""
    v, f = scenes.box_mesh((-2, -2, 0), (2, 2, 2.5), (8, 8, 5), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    pv, pf = scenes.grid_patch((-0.4, -0.4, 2.1), (0.8, 0, 0), (0, 0.8, 0), 2, 2)
    scenes.mesh_object("Panel", pv, np.asarray(pf)[:, ::-1], scenes.material("Lamp", (0, 0, 0), emission=(1, 1, 1), strength=6.0))
    scenes.set_world((0.0, 0.0, 0.0))
    obs = [bpy.data.objects["Room"]]
    err = _bake_both(cubegi, obs, ("DIRECT", "INDIRECT"), samples=128)
    print(err)
    assert err["DIRECT"]["rel_rmse"] < 0.05 and abs(err["DIRECT"]["rel_bias"]) < 0.02, err
    assert err["INDIRECT"]["rel_rmse"] < 0.3 and abs(err["INDIRECT"]["rel_bias"]) < 0.25, err
    ceiling = cubegi.cubegi_addon.attributes.read(bpy.data.objects["Room"].data, "CubeGI_direct")
    co = np.array([vv.co for vv in bpy.data.objects["Room"].data.vertices])
    above = (co[:, 2] > 2.49) & (np.abs(co[:, 0]) < 0.5) & (np.abs(co[:, 1]) < 0.5)
    assert ceiling[above].mean() > 0.2  # the panel's back lights the ceiling (Cycles: about 0.3)


def test_a_box_lamp_under_a_ceiling_is_shadowed_face_by_face_as_cycles_does(empty_scene, cubegi):
    """A glowing box 2 cm thick, 1 cm under a ceiling: the ceiling over it sees the box's top
    and not its bottom, whose light the top stops. Each face is shadowed by the samples on
    it (cubegi_engine.emitters.emitter_direct); one share for the whole box, weighted by
    each sample's nearness, gave the ceiling's vertices over the box anything from none to
    twice Cycles' light, as the nearest sample lay on the top or the bottom."""
    v, f = scenes.box_mesh((-1, -1, 0), (1, 1, 2), (8, 8, 8), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    ceiling_v, ceiling_f = scenes.grid_patch((-1, -1, 1.99), (0, 2, 0), (2, 0, 0), 16, 16)  # faces down
    ceiling = scenes.mesh_object("Ceiling", ceiling_v, ceiling_f, scenes.material("Plaster", (0.8, 0.8, 0.8)))
    lamp_v, lamp_f = scenes.box_mesh((-0.3, -0.2, 1.96), (0.3, 0.2, 1.98), (1, 1, 1), inward=False)
    scenes.mesh_object("Lamp", lamp_v, lamp_f, scenes.material("Glow", (0.8, 0.8, 0.8), emission=(1, 1, 1), strength=4.0))
    scenes.set_world((0.0, 0.0, 0.0))
    assert bpy.ops.cubegi.bake(bounces=1, grid=(4, 4, 4), cube_size=16) == {"FINISHED"}
    ours = cubegi.cubegi_addon.attributes.read(ceiling.data, "CubeGI_direct").mean(axis=1)
    ref, _ = cubegi.cubegi_addon.reference.bake_reference(bpy.context, [ceiling], passes=("DIRECT",), samples=64)
    theirs = ref["DIRECT"]["Ceiling"].mean(axis=1)
    co = np.array([vv.co for vv in ceiling.data.vertices])
    over = (np.abs(co[:, 0]) < 0.25) & (np.abs(co[:, 1]) < 0.15)  # over the top, off its edges
    ratio = ours[over] / theirs[over]
    print(over.sum(), ratio)
    assert over.sum() >= 8 and np.all(np.abs(ratio - 1.0) < 0.12), ratio


def test_a_panel_under_a_finely_modelled_ceiling_fills_the_gap_with_cycles_light(empty_scene, cubegi):
    """A glowing panel (0.6 m in 15 cm squares) 1 cm under a ceiling modelled in 6 cm squares:
    the light bouncing between the panel's top and the ceiling over it is gathered by the
    near field alone, from each side's light mixed over the triangles its rays land on.
    Sampled as modelled, the panel's triangles reaching its edge (where half its view is
    open) passed the edge's light across 15 cm: the ceiling over the panel got 0.13-1.04 of
    Cycles' indirect light, 0.6 on the mean. Both are now sampled as finely as the gap (refine_near_emitters),
    and the energy balance, which cannot weigh the gap's light, is left out: with it, the
    room away from the panel came out 1.7x Cycles'."""
    v, f = scenes.box_mesh((-1.5, -1.5, 0), (1.5, 1.5, 2.5), (12, 12, 10), inward=True)
    room = scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    cv, cf = scenes.grid_patch((-1.5, -1.5, 2.49), (0, 3, 0), (3, 0, 0), 48, 48)  # faces down
    ceiling = scenes.mesh_object("Ceiling", cv, cf, scenes.material("Plaster", (0.8, 0.8, 0.8)))
    pv, pf = scenes.grid_patch((-0.3, -0.3, 2.48), (0, 0.6, 0), (0.6, 0, 0), 4, 4)
    scenes.mesh_object("Panel", pv, pf, scenes.material("Glow", (0.8, 0.8, 0.8), emission=(1, 1, 1), strength=10.0))
    scenes.set_world((0.0, 0.0, 0.0))
    assert bpy.ops.cubegi.bake() == {"FINISHED"}
    attrs = cubegi.cubegi_addon.attributes
    ref, _ = cubegi.cubegi_addon.reference.bake_reference(bpy.context, [ceiling, room], passes=("INDIRECT",), samples=64)
    co = np.array([vv.co for vv in ceiling.data.vertices])
    over = np.all(np.abs(co[:, :2]) < 0.26, axis=1)  # over the panel, a ray's few centimetres in from its edge
    ratio = attrs.read(ceiling.data, attrs.INDIRECT).mean(axis=1)[over] / ref["INDIRECT"]["Ceiling"].mean(axis=1)[over]
    ours, theirs = attrs.read(room.data, attrs.INDIRECT).mean(axis=1), ref["INDIRECT"]["Room"].mean(axis=1)
    print(over.sum(), np.round(ratio, 2), ours.mean() / theirs.mean())
    # (Cycles' own noise at 64 samples spreads the vertices' ratios by about 0.1.)
    assert over.sum() >= 64 and abs(np.mean(ratio) - 1.0) < 0.08 and np.percentile(ratio, 10) > 0.8, ratio
    assert abs(ours.mean() / theirs.mean() - 1.0) < 0.08, (ours.mean(), theirs.mean())


def test_a_rug_5_mm_over_the_floor_shadows_it(empty_scene, cubegi):
    """A rug 5 mm above a floor, under an area light (coarse shadow maps, 64^2 per sample
    point at 2.4 m: a receiver is lifted 2 cm before its look-up, over the rug): the floor
    under it is dark, as in Cycles. A front face between the lifted receiver and its
    own surface is asked by a ray (lights._occluded); the area light lit the floor under the
    rug fully (2.16 where Cycles has 0)."""
    v, f = scenes.box_mesh((-3, -3, 0), (3, 3, 2.6), (24, 24, 10), inward=True)
    room = scenes.mesh_object("Room", v, f, scenes.material("White", (0.8, 0.8, 0.8)))
    rv, rf = scenes.grid_patch((-1.0, -0.7, 0.005), (2.0, 0, 0), (0, 1.4, 0), 4, 4)
    scenes.mesh_object("Rug", rv, rf, scenes.material("Red", (0.6, 0.08, 0.06)))
    scenes.add_light("AREA", (0.3, 0.2, 2.4), 150.0, shape="SQUARE", size=1.0)
    scenes.set_world((0.0, 0.0, 0.0))
    assert bpy.ops.cubegi.bake(bounces=1) == {"FINISHED"}
    ours = cubegi.cubegi_addon.attributes.read(room.data, "CubeGI_direct").mean(axis=1)
    ref, _ = cubegi.cubegi_addon.reference.bake_reference(bpy.context, [room], passes=("DIRECT",), samples=16)
    theirs = ref["DIRECT"]["Room"].mean(axis=1)
    co = np.array([vv.co for vv in room.data.vertices])
    floor = co[:, 2] < 1e-3
    under = floor & (np.abs(co[:, 0]) < 0.95) & (np.abs(co[:, 1]) < 0.65)
    lit = ours[floor & ~under].max()
    assert under.sum() >= 20 and theirs[under].max() < 0.01 * lit and ours[under].max() < 0.01 * lit, (ours[under], lit)


def _env_image(name="Sky"):
    """An equirectangular sky: blue, brighter overhead and towards one side, over a brown
    ground half."""
    image = bpy.data.images.new(name, 128, 64, float_buffer=True)
    elev = ((np.arange(64) + 0.5) / 64 - 0.5) * np.pi  # rows run bottom to top
    u = (np.arange(128) + 0.5) / 128
    sky = np.array([0.4, 0.6, 1.0]) * (0.5 + 1.5 * np.clip(np.sin(elev), 0, 1))[:, None]
    px = np.zeros((64, 128, 4), np.float32)
    px[:, :, :3] = np.where((elev > 0)[:, None, None], sky[:, None, :], np.array([0.25, 0.2, 0.15]))
    px[32:, :, :3] *= (1.0 + 0.8 * np.cos(2 * np.pi * (u - 0.3)))[None, :, None]
    px[..., 3] = 1.0
    image.pixels.foreach_set(px.ravel())
    return image


# The sky reaches the vertices through the probes (their cube maps' sky texels, projected on
# 9 SH coefficients), uniform or from an environment image's directions, less the directions
# the near field finds blocked close by. Measured on the courtyard without its sun, 4
# bounces, against Cycles at 128 samples (rel. RMSE, bias): uniform sky direct 7.9% (-0.1%),
# total 4.5%; the image below direct 10.4% (-0.1%), total 7.0% (through the probes alone:
# 9.6% (+1.6%) and 6.8%, 12.0% (+1.7%) and 9.2%; averaged to a uniform sky, as before that,
# 64% (-47%) and 55%). The error sits where the walls meet the ground (the probes see those
# corners from a distance, beyond the near field's reach). With the sky per vertex (256
# lines of sight of its own, ``sky_per_vertex``; here 415K of them, a ray each): uniform
# direct 4.2% (-0.1%), total 4.3%; the image 3.9% (-0.8%), 5.0%. By depth maps, 4.8% and
# 5.0%, 5.0% and 5.7% (shadows a little wide where surfaces meet); by rays started straight
# off their surface, not into their own triangles, direct 14.3% and 19.1% (where a wall meets
# the ground, a ray starts on the wall's plane: see lifts.RAY_LIFT).
SKY_TOL = {("uniform", False): (0.11, 0.07), ("image", False): (0.14, 0.10),
           ("uniform", True): (0.05, 0.05), ("image", True): (0.05, 0.06)}


@pytest.mark.parametrize("sky,per_vertex", list(SKY_TOL), ids=[f"{s}-{'per-vertex' if v else 'probes'}" for s, v in SKY_TOL])
def test_the_sky_matches_cycles(empty_scene, cubegi, sky, per_vertex):
    from benchmarks import scenes as bench_scenes
    from cubegi.cubegi_addon import attributes, reference, scene_data

    bench_scenes.courtyard()
    for ob in [o for o in bpy.data.objects if o.type == "LIGHT"]:
        bpy.data.objects.remove(ob)
    if sky == "image":
        tree = bpy.context.scene.world.node_tree
        env = tree.nodes.new("ShaderNodeTexEnvironment")
        env.image = _env_image()
        tree.links.new(env.outputs["Color"], tree.nodes["Background"].inputs["Color"])
    obs = sorted((o for o in bpy.context.scene.objects if o.type == "MESH"), key=lambda o: o.name)
    assert bpy.ops.cubegi.bake(bounces=4, sky_per_vertex=per_vertex) == {"FINISHED"}
    assert json.loads(bpy.context.scene.cubegi.last_report)["settings"]["sky_per_vertex"] is per_vertex
    ref, _ = reference.bake_reference(bpy.context, obs, samples=128, seed=0)

    def stack(values):
        return np.concatenate([values[o.name] for o in obs])

    ours = {layer: stack({o.name: attributes.read(o.data, layer) for o in obs}) for layer in ("CubeGI_direct", "CubeGI")}
    areas = np.concatenate([scene_data.vertex_areas(o) for o in obs])
    err = metrics.compare(ours["CubeGI_direct"], ours["CubeGI"], stack(ref["DIRECT"]), stack(ref["INDIRECT"]), areas)
    print(sky, per_vertex, err)
    direct_tol, total_tol = SKY_TOL[sky, per_vertex]
    assert err["direct"]["rel_rmse"] < direct_tol and abs(err["direct"]["rel_bias"]) < 0.04, err
    assert err["total"]["rel_rmse"] < total_tol and abs(err["total"]["rel_bias"]) < 0.04, err


def test_the_sky_at_points_no_probe_lights_by_rays_and_by_maps(empty_scene, cubegi):
    """The courtyard's points no probe lights (its walls' and ground's outer faces, open to
    the sky all round) take the sky along their own lines of sight: by a ray each way where
    those are few, else by a depth map each way. The rays see all of the open sky; the maps
    widen shadows where surfaces meet (a back face in a texel next to a receiver's counts:
    0.92 of the sky on average here), never narrow them."""
    from benchmarks import scenes as bench_scenes
    from cubegi.cubegi_addon import gpu_capture, session
    from cubegi.cubegi_engine import sky

    bench_scenes.courtyard()
    assert bpy.ops.cubegi.bake() == {"FINISHED"}
    bake = session.kept(bpy.context.scene).bake
    arrays = bake.arrays
    alone = np.flatnonzero(bake.result.capture.transport.covered)
    assert 500 < len(alone) < len(arrays.points)
    renderer = gpu_capture.GpuRenderer(arrays.points, arrays.triangles)
    light = {}
    for way, most in (("rays", 10**9), ("maps", 0)):
        light[way] = sky.sky_direct(arrays, renderer, alone, rays_at_most=most)[:, 0]
    down = arrays.normals[alone, 2] < -0.9  # the ground's underside: the open sky below
    assert down.sum() > 10 and np.all(light["rays"][down] > 0.99)
    assert light["rays"].mean() > 0.97 and light["maps"].mean() > 0.85
    assert np.all(light["rays"] >= light["maps"] - 0.05)


def test_suns_worked_out_before_the_capture_give_the_direct_stage_s_light(empty_scene, cubegi):
    """A bake works out its suns while the scene is simplified (``direct.sun_steps``) and its
    other lights after the capture: each light's part, their order and the lights left out
    are those of every light worked out in the direct stage, and the bake's own parts are
    those. The courtyard's sun (with an Angle: rays across its disk), another sun, a lamp,
    and a sun and a lamp too faint to draw."""
    from benchmarks import scenes as bench_scenes
    from cubegi.cubegi_addon import gpu_capture, session
    from cubegi.cubegi_engine import direct
    from cubegi.cubegi_engine.settings import BakeSettings
    from cubegi.cubegi_engine.working import run

    bench_scenes.courtyard()
    scenes.add_light("POINT", (0.5, -0.5, 1.5), 300.0, shadow_soft_size=0.0)
    scenes.add_light("POINT", (0.5, 0.5, 1.5), 1e-6)
    scenes.add_light("SUN", (0.0, 0.0, 5.0), 0.5, (0.3, 0.2, 0.0))
    scenes.add_light("SUN", (0.0, 0.0, 5.0), 1e-6, (-0.3, 0.2, 0.0))
    assert bpy.ops.cubegi.bake() == {"FINISHED"}
    bake = session.kept(bpy.context.scene).bake
    arrays, transport = bake.arrays, bake.result.capture.transport
    # In scene order (by name): the courtyard's Sun, the lamps, the suns added.
    assert [light.kind for light in arrays.lights] == ["SUN", "POINT", "POINT", "SUN", "SUN"]
    renderer = gpu_capture.GpuRenderer(arrays.points, arrays.triangles, sheet=arrays.sheet_triangles())
    settings = BakeSettings()
    whole = run(direct.direct_light_steps(arrays, renderer, settings, transport))
    suns = run(direct.sun_steps(arrays, renderer, settings))
    assert len(suns.asked) == 3 and len(suns.parts) == 2 and len(suns.left_out) == 1
    split = run(direct.direct_light_steps(arrays, renderer, settings, transport, done=suns))
    assert list(split.parts) == list(whole.parts) == list(bake.result.direct_parts.parts)
    assert [x.line() for x in split.left_out] == [x.line() for x in whole.left_out] and len(whole.left_out) == 2
    for key, value in whole.parts.items():
        np.testing.assert_array_equal(split.parts[key], value)
        np.testing.assert_array_equal(bake.result.direct_parts.parts[key], value)
    assert whole.parts[next(iter(whole.parts))].max() > 0.1


def test_a_large_point_light_casts_soft_shadows_as_cycles(empty_scene, cubegi):
    """A bulb of 0.1 m radius 0.5 m from the red wall, the blocks between it and the floor:
    its shadows are averaged over 32 points on its sphere. Measured against Cycles at 256
    samples: direct light 2.0% rel. RMSE (one sharp map from its centre gave 8.6%; 16 points
    4.2%, 64 points 1.5%)."""
    scenes.cornell(light=False)
    scenes.add_light("POINT", (-0.5, -0.3, 1.0), 60.0, shadow_soft_size=0.1)
    obs = [ob for ob in bpy.context.scene.objects if ob.type == "MESH"]
    err = _bake_both(cubegi, obs, ("DIRECT",), samples=256)["DIRECT"]
    print(err)
    assert err["rel_rmse"] < 0.035 and abs(err["rel_bias"]) < 0.01, err


def test_the_near_field_brings_contacts_and_corners_to_cycles(empty_scene, cubegi):
    """The probes see the box's edges and the blocks, standing 2 cm above the floor, from up
    to a cell away; rays from each vertex see what is next to it. Measured at the default
    8x8x8 grid, 16^2, 256 samples: the scene's indirect rel. RMSE 14.9% without the near
    field, 10.0% with it. The blocks' undersides: +14% too bright without (lit by the probes
    above them, behind their plane: no other probe sees them), -12% with (the near field
    alone; the probes behind them are left out)."""
    scenes.cornell(light=True)
    obs = [ob for ob in bpy.context.scene.objects if ob.type == "MESH"]
    attributes, scene_data = cubegi.cubegi_addon.attributes, cubegi.cubegi_addon.scene_data
    ref, _ = cubegi.cubegi_addon.reference.bake_reference(bpy.context, obs, passes=("INDIRECT",), samples=256)
    theirs = np.concatenate([ref["INDIRECT"][o.name] for o in obs])
    areas = np.concatenate([scene_data.vertex_areas(o) for o in obs])
    normal_z = np.concatenate([[v.normal.z for v in o.data.vertices] for o in obs])
    height = np.concatenate([[(o.matrix_world @ v.co).z for v in o.data.vertices] for o in obs])
    under = (normal_z < -0.9) & (height < 0.1)
    assert under.sum() == 32  # the two blocks' bottom faces
    got = {}
    for near in (False, True):
        cubegi.cubegi_addon.session.forget()
        assert bpy.ops.cubegi.bake(bounces=4, grid=(8, 8, 8), cube_size=16, near_field=near) == {"FINISHED"}
        ours = np.concatenate([attributes.read(o.data, "CubeGI") for o in obs])
        under_bias = (areas[under] @ ours[under].mean(axis=1)) / (areas[under] @ theirs[under].mean(axis=1)) - 1.0
        got[near] = (metrics.errors(ours, theirs, areas)["rel_rmse"], under_bias)
    print(got)
    (rmse_off, under_off), (rmse_on, under_on) = got[False], got[True]
    assert rmse_on < 0.8 * rmse_off, got
    assert abs(under_off) < 0.3 and abs(under_on) < 0.2, got



def test_the_near_fields_edge_shadows_are_not_scaled_back_onto_the_room(empty_scene, cubegi):
    """The thin wall's lit room (white, albedo 0.8, Specular IOR Level 0: diffuse as the
    balance assumes). Its vertices on the room's edges have the edges' shadows, which cover
    strips much narrower than the vertices' shares of the surfaces: a per-vertex bake, Cycles'
    too, sums less than the light landing on the surfaces. The near field's balance scaled
    that back up onto every point: indirect bias +2.3% against Cycles at 4096 samples;
    +0.7% since it only scales light it adds. And what the probes see of a triangle with a
    corner inside the partition (a floor vertex under it) is its seen corners' light."""
    scenes.thin_wall()
    for m in bpy.data.materials:
        bsdf = next((n for n in m.node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None) if m.node_tree else None
        if bsdf is not None:
            bsdf.inputs["Specular IOR Level"].default_value = 0.0
    obs = [ob for ob in bpy.context.scene.objects if ob.type == "MESH"]
    addon = cubegi.cubegi_addon
    addon.session.forget()
    assert bpy.ops.cubegi.bake() == {"FINISHED"}
    ref, _ = addon.reference.bake_reference(bpy.context, obs, passes=("INDIRECT",), samples=256, seed=0)
    theirs = np.concatenate([ref["INDIRECT"][o.name] for o in obs]).mean(axis=1)
    ours = np.concatenate([addon.attributes.read(o.data, "CubeGI") for o in obs]).mean(axis=1)
    areas = np.concatenate([addon.scene_data.vertex_areas(o) for o in obs])
    lit = theirs > 0.05  # the left room (no light reaches the right one)
    bias = (areas[lit] @ ours[lit]) / (areas[lit] @ theirs[lit]) - 1.0
    print("indirect bias over the lit room", bias)
    assert abs(bias) < 0.015, bias

    result = addon.session.kept(bpy.context.scene).bake.result
    transport, cubes = result.capture.transport, result.capture.cubes
    hidden = transport.covered[transport.corners]  # (p, t, 3)
    mixed = hidden.any(axis=-1) & ~hidden.all(axis=-1)
    raw = cubes.bary.reshape(transport.bary.shape)
    assert mixed.any() and (raw[mixed] * hidden[mixed]).sum() > 0  # the probes see such triangles
    assert (transport.bary[mixed] * hidden[mixed]).sum() == 0
    assert np.allclose(transport.bary[mixed].sum(axis=-1), raw[mixed].sum(axis=-1), atol=1e-5)

def test_no_light_reaches_a_wall_inside_the_partition_standing_against_it(empty_scene, cubegi):
    """The thin wall's rooms under a 0.5 m area light: their walls', floor's and ceiling's
    vertices at x = 0 lie inside the 2 cm partition, under its end faces. Cycles gives them
    no light; the lamp's shadow maps, biased by more than the partition's half-thickness,
    gave 12 of the 30 up to 0.56 (the lit room's vertices half a metre off: 0.65), and a
    light edit drew them again the same way."""
    scenes.thin_wall()
    addon = cubegi.cubegi_addon
    light = next(ob for ob in bpy.data.objects if ob.type == "LIGHT")
    light.data.type, light.data.size, light.location.z = "AREA", 0.5, 2.4
    rooms = bpy.data.objects["Rooms"]
    co = np.array([v.co for v in rooms.data.vertices])
    inside = np.abs(co[:, 0]) < 1e-6
    beside = np.isclose(co[:, 0], -0.5) & (np.abs(co[:, 1]) < 1.99)  # the left room's, half a metre off
    assert inside.sum() >= 20 and beside.any()
    assert bpy.ops.cubegi.bake() == {"FINISHED"}
    ref, _ = addon.reference.bake_reference(bpy.context, [rooms], passes=("DIRECT",), samples=16, seed=0)
    theirs = ref["DIRECT"]["Rooms"].mean(axis=1)
    assert theirs[inside].max() < 1e-3 * theirs[beside].mean(), theirs[inside].max()
    for edit in ("bake", "moved"):
        if edit == "moved":  # drawn again on the kept capture (relight)
            light.location.x = -0.6
            assert bpy.ops.cubegi.update_light() == {"FINISHED"}
        ours = addon.attributes.read(rooms.data, "CubeGI_direct").mean(axis=1)
        print(edit, ours[inside].max(), ours[beside].mean())
        assert ours[beside].mean() > 0.5 * theirs[beside].mean()  # the lit room is lit
        assert np.all(ours[inside] == 0.0), (edit, ours[inside].max())


def _cylinder(name, centre, radius, z0, z1, mat, segments, rows, cap=False):
    """An open cylinder sheet (a lampshade), or one closed at its top (``cap``)."""
    import bmesh

    bm = bmesh.new()
    angle = 2.0 * np.pi * np.arange(segments) / segments
    ring = [[bm.verts.new((centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a), z0 + (z1 - z0) * j / rows)) for a in angle]
            for j in range(rows + 1)]
    for j in range(rows):
        for k in range(segments):
            bm.faces.new((ring[j][k], ring[j][(k + 1) % segments], ring[j + 1][(k + 1) % segments], ring[j + 1][k]))
    if cap:
        bm.faces.new(ring[-1])
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    mesh.materials.append(mat)
    ob = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def test_a_lamps_base_inside_its_shade_takes_the_shades_light(empty_scene, cubegi):
    """A table lamp in a 5 x 4 x 2.6 m room at night: a point light inside an open shade of
    36 cm, over a 10 cm base. The shade's lit inside lights the base; no probe sees it (the
    cells are 63 cm), and the near field's rays reached a quarter cell: the base's indirect
    light was -89% against Cycles. An object smaller than a cell gathers through Blender's
    BVH tree across itself and its surroundings, its light not scaled by the near field's
    balance (which took the base's gain off the whole room: its walls -6 -> -13%)."""
    white, wood = scenes.material("Wall", (0.8, 0.78, 0.74)), scenes.material("Oak", (0.5, 0.35, 0.2))
    shade, metal = scenes.material("Shade", (0.85, 0.75, 0.55)), scenes.material("Base", (0.6, 0.6, 0.6))
    v, f = scenes.box_mesh((-2.5, -2.0, 0.0), (2.5, 2.0, 2.6), (25, 20, 13), inward=True)
    room = scenes.mesh_object("Room", v, f, white)
    v, f = scenes.box_mesh((1.55, 1.15, 0.55), (2.05, 1.65, 0.58), (5, 5, 1), inward=False)
    table = scenes.mesh_object("Table", v, f, wood)
    base = _cylinder("Base", (1.8, 1.4), 0.05, 0.58, 0.88, metal, 16, 4, cap=True)
    _cylinder("Shade", (1.8, 1.4), 0.18, 0.85, 1.10, shade, 32, 4)
    scenes.add_light("POINT", (1.8, 1.4, 0.96), 40.0, shadow_soft_size=0.02)
    assert bpy.ops.cubegi.bake() == {"FINISHED"}
    err = {}
    for ob in (base, room, table):
        ref, _ = cubegi.cubegi_addon.reference.bake_reference(bpy.context, [ob], passes=("INDIRECT",), samples=64, seed=0)
        areas = cubegi.cubegi_addon.scene_data.vertex_areas(ob)
        ours = cubegi.cubegi_addon.attributes.read(ob.data, "CubeGI").mean(axis=1)
        err[ob.name] = areas @ ours / (areas @ ref["INDIRECT"][ob.name].mean(axis=1)) - 1.0
    print(err)
    assert abs(err["Base"]) < 0.35, err
    assert abs(err["Room"]) < 0.1, err


def _against_cycles(cubegi, obs, part, layer, samples=32):
    """The error measures of CubeGI's ``layer`` on ``obs`` against Cycles' ``part`` pass."""
    addon = cubegi.cubegi_addon
    ref, _ = addon.reference.bake_reference(bpy.context, obs, passes=(part,), samples=samples, seed=0)
    areas = np.concatenate([addon.scene_data.vertex_areas(o) for o in obs])
    ours = np.concatenate([addon.attributes.read(o.data, layer) for o in obs])
    err = metrics.errors(ours, np.concatenate([ref[part][o.name] for o in obs]), areas)
    print(err)
    return err


def _thick_walled_room():
    """A 4 x 3 x 2.5 m room of 0.2 m thick walls, floor and ceiling (boxes, subdivided so
    that their light can vary across them): the meshes."""
    import bmesh

    def wall(name, loc, scale):
        bpy.ops.mesh.primitive_cube_add(size=1, location=loc)
        ob = bpy.context.object
        ob.name, ob.scale = name, scale
        bpy.ops.object.transform_apply(scale=True)
        bm = bmesh.new()
        bm.from_mesh(ob.data)
        bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=6, use_grid_fill=True)
        bm.to_mesh(ob.data)
        bm.free()
        ob.data.materials.append(scenes.material(name, (0.7, 0.7, 0.7)))
        return ob

    return [wall("Floor", (0, 0, -0.1), (4.4, 3.4, 0.2)), wall("Ceiling", (0, 0, 2.6), (4.4, 3.4, 0.2)),
            wall("N", (0, 1.6, 1.25), (4.4, 0.2, 2.5)), wall("S", (0, -1.6, 1.25), (4.4, 0.2, 2.5)),
            wall("E", (2.1, 0, 1.25), (0.2, 3.0, 2.5)), wall("W", (-2.1, 0, 1.25), (0.2, 3.0, 2.5))]


def test_sunlit_outer_walls_do_not_brighten_the_room_inside(empty_scene, cubegi):
    """A room of thick walls (boxes) under a sun, lit inside by a bulb: the walls' sunlit
    outer faces are seen by no probe, and their light leaves through the sky. The energy
    balance leaves them out on both sides; counting their light as landing made the room's
    indirect light +46% too bright (a hand-made room of this kind), now within 15%.
    Measured here (32 samples): indirect bias +44% and rel. RMSE 77% before, +1.6% and 23%
    after."""
    import math

    obs = _thick_walled_room()
    scenes.add_light("SUN", (0, 0, 10), 4.0, rotation=(math.radians(50), 0.0, math.radians(-80)))
    scenes.add_light("POINT", (0.3, 0.2, 1.8), 200.0)
    scenes.set_world((0.0, 0.0, 0.0))
    assert bpy.ops.cubegi.bake(bounces=4, cube_size=16) == {"FINISHED"}
    err = _against_cycles(cubegi, obs, "INDIRECT", "CubeGI")
    assert abs(err["rel_bias"]) < 0.15 and err["rel_rmse"] < 0.35, err


def test_a_thick_walled_rooms_outer_faces_get_the_sky(empty_scene, cubegi):
    """The same room under a blue sky, lit inside by a bulb: no probe lies outside a grid
    fitted to it, so its outer faces see the sky along their own lines of sight (64
    orthographic depth maps, as a sun's). Measured (32 samples): direct light bias -41% and
    rel. RMSE 55% through the probes alone; now -0.01% and 0.15%."""
    obs = _thick_walled_room()
    scenes.add_light("POINT", (0.3, 0.2, 1.8), 200.0)
    scenes.set_world((0.4, 0.5, 0.7))
    assert bpy.ops.cubegi.bake(bounces=2, cube_size=16) == {"FINISHED"}
    err = _against_cycles(cubegi, obs, "DIRECT", "CubeGI_direct")
    assert abs(err["rel_bias"]) < 0.02 and err["rel_rmse"] < 0.05, err


def test_a_raised_block_and_the_floor_under_it_get_their_light(empty_scene, cubegi):
    """A 1.8 x 0.8 m block standing 12 cm above the floor of a closed 4 x 3 x 2.6 m room lit
    by a lamp: the underside's probes all stand above it (behind its plane), and the near
    field's rays (reach a quarter of a cell) cover little of its view, so those probes light
    it (they see it through the gap). The floor under it no probe sees at all: its rays reach
    a cell, meet the underside over most of its view, and the probes in front of it light
    the directions that leave under the block's edge. Measured against Cycles at 128
    samples: the underside's indirect light -20% (black when probes behind a vertex were
    always left out), the floor under it -15% (black before)."""
    attributes, scene_data = cubegi.cubegi_addon.attributes, cubegi.cubegi_addon.scene_data
    v, f = scenes.box_mesh((-2.0, -1.5, 0.0), (2.0, 1.5, 2.6), (16, 12, 10), inward=True)
    scenes.mesh_object("Room", v, f, scenes.material("Plaster", (0.78, 0.76, 0.72)))
    v, f = scenes.box_mesh((-1.8, 0.2, 0.12), (0.0, 1.0, 0.47), (9, 4, 2), inward=False)
    scenes.mesh_object("Sofa", v, f, scenes.material("Fabric", (0.35, 0.22, 0.18)))
    scenes.add_light("POINT", (1.1, -0.7, 1.9), 150.0, shadow_soft_size=0.1)
    scenes.set_world((0.0, 0.0, 0.0))
    obs = [bpy.data.objects["Room"], bpy.data.objects["Sofa"]]
    assert bpy.ops.cubegi.bake(bounces=4) == {"FINISHED"}
    ref, _ = cubegi.cubegi_addon.reference.bake_reference(bpy.context, obs, passes=("INDIRECT",), samples=128)

    def bias(ob, where):
        a = scene_data.vertex_areas(ob)[where]
        ours = attributes.read(ob.data, "CubeGI")[where].mean(axis=1) @ a
        return ours / (ref["INDIRECT"][ob.name][where].mean(axis=1) @ a) - 1.0

    room, sofa = obs
    underside = bias(sofa, np.array([vv.normal.z for vv in sofa.data.vertices]) < -0.9)
    co = np.array([vv.co for vv in room.data.vertices])
    floor_under = bias(room, (co[:, 2] < 1e-3) & (co[:, 0] > -1.7) & (co[:, 0] < -0.1) & (co[:, 1] > 0.3) & (co[:, 1] < 0.9))
    print(underside, floor_under)
    assert abs(underside) < 0.25, underside
    assert abs(floor_under) < 0.5, floor_under


def test_the_reference_report_leaves_black_vertices_out(empty_scene, cubegi):
    """Cycles' Diffuse bake reports no light on a black material (no diffuse closure); CubeGI
    reports the light that reaches it. The report's errors leave those vertices out."""
    from benchmarks import scenes as bench_scenes
    from cubegi.cubegi_addon import attributes, pipeline, scene_data

    bench_scenes.white_box()  # its emissive panel is black
    report = pipeline.bake(bpy.context, reference_samples=16)
    panel = bpy.data.objects["Panel"].data
    assert np.all(attributes.read(panel, attributes.REF_INDIRECT) == 0.0)
    assert attributes.read(panel, attributes.INDIRECT).mean() > 0.1
    obs = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    ours = np.concatenate([attributes.read(o.data, attributes.INDIRECT) for o in obs])
    theirs = np.concatenate([attributes.read(o.data, attributes.REF_INDIRECT) for o in obs])
    areas = np.concatenate([scene_data.vertex_areas(o) for o in obs])
    black = np.concatenate([np.full(len(o.data.vertices), o.name == "Panel") for o in obs])
    kept = metrics.errors(ours[~black], theirs[~black], areas[~black])
    everything = metrics.errors(ours, theirs, areas)
    got = report.reference.errors["indirect"]
    assert got["rel_rmse"] == pytest.approx(kept["rel_rmse"], rel=1e-6)
    assert everything["rel_rmse"] > got["rel_rmse"] + 0.01, (everything, got)


def test_thirteen_area_lamps_share_their_shadow_eyes_and_match_cycles(empty_scene, cubegi):
    """Thirteen 0.3 m lamps under the box's ceiling: each would take 64 shadow eyes (832
    cube maps); they share the scene's budget (cubegi_engine.eyes.SHADOW_EYES), 4 each.
    Measured against Cycles at 128 samples: direct rel. RMSE 2.1% (1.6% with 64 each)."""
    obs = cornell_box()
    places = [(x, y) for x in (-0.62, -0.21, 0.19, 0.61) for y in (-0.58, -0.19, 0.22)] + [(0.03, 0.63)]
    for x, y in places:
        scenes.add_light("AREA", (x, y, 1.97), 80.0 / len(places), shape="SQUARE", size=0.3)
    err = _bake_both(cubegi, obs, ("DIRECT",), samples=128)["DIRECT"]
    eyes = cubegi.cubegi_addon.session.kept(bpy.context.scene).bake.result.direct_parts.eyes
    print(err, eyes)
    assert len(eyes) == len(places) and sum(eyes.values()) <= cubegi.cubegi_engine.eyes.SHADOW_EYES, eyes
    assert abs(err["rel_bias"]) < DIRECT_BIAS_TOL, err
    assert err["rel_rmse"] < DIRECT_RMSE_TOL, err


def _white_cup(centre, radius=0.06, height=0.1, wall=0.006, segments=128, rings=32):
    """A white cup (albedo 1) with walls ``wall`` thick, finely cut (its inside is crowded:
    hundreds of triangles within the near field's reach): the object, and a mask of its
    inside's vertices."""
    ang = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    z = np.linspace(wall, height, rings + 1)
    verts, faces, inside = [], [], []

    def add(points, quads, is_inside):
        start = len(verts)
        verts.extend(np.asarray(points).tolist())
        inside.extend([is_inside] * len(points))
        faces.extend([[int(i) + start for i in face] for face in quads])

    def wall_quads(flip):
        k = np.arange(rings)[:, None] * segments + np.arange(segments)[None, :]
        nxt = np.arange(rings)[:, None] * segments + (np.arange(segments)[None, :] + 1) % segments
        quads = np.stack([k, nxt, nxt + segments, k + segments], axis=-1).reshape(-1, 4)
        return quads[:, ::-1] if flip else quads

    for r, flip, is_inside, zs in ((radius, False, False, np.linspace(0.0, height, rings + 1)), (radius - wall, True, True, z)):
        add([[*(centre[:2] + r * c), centre[2] + h] for h in zs for c in ring], wall_quads(flip), is_inside)
    for r, h, up, is_inside in ((radius - wall, wall, True, True), (radius, 0.0, False, False)):  # the bottoms: fans
        pts = [[*centre[:2], centre[2] + h]] + [[*(centre[:2] + r * c), centre[2] + h] for c in ring]
        tri = [[0, 1 + j, 1 + (j + 1) % segments] for j in range(segments)]
        add(pts, [t if up else t[::-1] for t in tri], is_inside)
    rim = [[*(centre[:2] + r * c), centre[2] + height] for r in (radius, radius - wall) for c in ring]
    k = np.arange(segments)
    add(rim, np.stack([k, (k + 1) % segments, (k + 1) % segments + segments, k + segments], axis=1), False)  # facing up
    mesh = bpy.data.meshes.new("Cup")
    mesh.from_pydata(verts, [], faces)
    mesh.materials.append(scenes.material("Cup", (1.0, 1.0, 1.0)))
    ob = bpy.data.objects.new("Cup", mesh)
    bpy.context.scene.collection.objects.link(ob)
    bpy.ops.object.select_all(action="DESELECT")
    ob.select_set(True)
    bpy.context.view_layer.objects.active = ob
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.remove_doubles(threshold=1e-6)
    bpy.ops.object.mode_set(mode="OBJECT")
    axis = np.array([ob.matrix_world @ v.co for v in ob.data.vertices]) - centre
    r = np.linalg.norm(axis[:, :2], axis=1)
    normal = np.array([v.normal for v in ob.data.vertices])
    inner = (r < radius - wall / 2) & (axis[:, 2] > wall / 2)
    facing_in = np.einsum("ij,ij->i", normal[:, :2], -axis[:, :2]) > 0.5 * r
    return ob, inner & ((normal[:, 2] > 0.9) | facing_in)


def test_a_white_cups_inside_is_lit_by_itself_as_cycles_lights_it(empty_scene, cubegi, monkeypatch):
    """The inside of a small white cup (albedo 1, 6 cm wide, under the box's lamp) gets most
    of its light from itself, many bounces over: the probes never see in, and its finely cut
    inside is too crowded for the near field's own rays. Through Blender's BVH tree one
    point per small cluster casts the rays, and the tail sums their light to its end.
    Measured (the mean indirect light against Cycles at 64 samples): inside -69.6% with the
    probes' light alone, -0.8% with the clusters' rays; outside -1.0% and +1.4%."""
    scenes.cornell(light=True)
    cup, inside = _white_cup(np.array([-0.5, -0.55, 0.0]))
    addon = cubegi.cubegi_addon
    ref, _ = addon.reference.bake_reference(bpy.context, [cup], passes=("INDIRECT",), samples=64, seed=0)
    areas = addon.scene_data.vertex_areas(cup)
    at = np.array([v.co for v in cup.data.vertices]) - [-0.5, -0.55, 0.0]
    outside = ~inside & (at[:, 2] > 0.03) & (np.linalg.norm(at[:, :2], axis=1) > 0.06 - 1e-4)  # the outer wall

    def mean(light, where):
        return areas[where] @ light[where].mean(axis=1) / areas[where].sum()

    got = {}
    for caster in (False, True):
        if not caster:
            monkeypatch.setattr(cubegi.cubegi_engine.capture, "near_caster", lambda scene, renderer: None)
        else:
            monkeypatch.undo()
        addon.session.forget()
        assert bpy.ops.cubegi.bake() == {"FINISHED"}
        report = json.loads(bpy.context.scene.cubegi.last_report)
        ours = addon.attributes.read(cup.data, addon.attributes.INDIRECT)
        got[caster] = [mean(ours, m) / mean(ref["INDIRECT"][cup.name], m) - 1.0 for m in (inside, outside)]
        got[caster].append(report["near_field"]["crowded"])
    print(got)
    (before, _, crowded_before), (after, outside_after, crowded_after) = got[False], got[True]
    assert crowded_before > inside.sum() // 2 and crowded_after < crowded_before, got
    assert abs(after) < 0.08 and abs(before) > abs(after) + 0.3, got
    assert abs(outside_after) < 0.08, got


def test_a_dark_glossy_rooms_specular_layer_lights_the_room_as_in_cycles(empty_scene, cubegi, monkeypatch):
    """Every surface of the box a Principled BSDF of base colour 0.1 at Specular IOR Level 1
    (Roughness 1): its specular layer sends on about a third as much light again as the base
    colour, and Cycles counts it in every other surface's indirect light. Read as its Base
    Color alone, the box's indirect light is too dark by a quarter (-25.7%); with the layer
    as a furnace measures it (light from every direction) +6.3%: the layer reflects less of
    the lamp's light, which meets the floor head-on (cubegi_engine.specular)."""
    scenes.cornell(light=True)
    obs = [ob for ob in bpy.context.scene.objects if ob.type == "MESH"]
    for mat in bpy.data.materials:
        bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
        bsdf.inputs["Base Color"].default_value = (0.1, 0.1, 0.1, 1.0)
        bsdf.inputs["Specular IOR Level"].default_value = 1.0
    with_layer = _bake_both(cubegi, obs, ("INDIRECT",), samples=128)["INDIRECT"]
    monkeypatch.setattr(cubegi.cubegi_addon.read_materials, "layer", lambda f0, roughness: (0.0, 0.0))
    cubegi.cubegi_addon.session.forget()
    without = _bake_both(cubegi, obs, ("INDIRECT",), samples=128)["INDIRECT"]
    print(with_layer, without)
    assert abs(with_layer["rel_bias"]) < SPECULAR_BIAS_TOL, with_layer
    assert without["rel_bias"] < -0.15, without
