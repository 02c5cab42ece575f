"""The scene as Cycles renders it, one Blender feature at a time: a tiny scene per feature,
baked by CubeGI and by Cycles (its Diffuse bake of the same vertices), compared with a
tolerance per row; a feature CubeGI does not read is named by a note, which its row asserts.

Every row records what it measured in ``out/conformance.json`` (feature, support, error
against Cycles); ``scripts/support_table.py`` turns that into ``docs/blender-support.md``.

The scene: the Cornell-like box of ``bench_scenes.cornell`` (2 m, open at the front), lit by
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

from cubegi.cubegi_engine import metrics

import scenes

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
RESULTS = os.path.join(ROOT, "out", "conformance.json")
SAMPLES = 64
DIRECT_BIAS_TOL = 0.05
DIRECT_RMSE_TOL = 0.12
FAST = dict(bounces=1, grid=(3, 3, 3), cube_size=16)


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


def _direct_errors(cubegi, obs):
    """CubeGI's and Cycles' direct light on ``obs``: metrics.errors of ours against theirs."""
    reference, scene_data, attributes = (getattr(cubegi.cubegi_addon, m) for m in ("reference", "scene_data", "attributes"))
    assert bpy.ops.cubegi.bake(**FAST) == {"FINISHED"}
    theirs, _ = reference.bake_reference(bpy.context, obs, passes=("DIRECT",), samples=SAMPLES)
    areas = np.concatenate([scene_data.vertex_areas(o) for o in obs])
    ours = np.concatenate([attributes.read(o.data, "CubeGI_direct") for o in obs])
    return metrics.errors(ours, np.concatenate([theirs["DIRECT"][o.name] for o in obs]), areas), ours


def _light(kind="POINT", **props):
    place = {"POINT": (0.13, -0.27, 1.63), "AREA": (0.0, 0.0, 1.98), "SUN": (0, -3, 3), "SPOT": (0.07, 0.03, 1.91)}[kind]
    energy = {"POINT": 60.0, "AREA": 80.0, "SUN": 3.0, "SPOT": 150.0}[kind]
    return scenes.add_light(kind, place, energy, **props)


def _set_emission_node(light, strength, colour=(1.0, 1.0, 1.0)):
    light.data.use_nodes = True
    emission = next(n for n in light.data.node_tree.nodes if n.type == "EMISSION")
    emission.inputs["Strength"].default_value = strength
    emission.inputs["Color"].default_value = (*colour, 1.0)


def _point(energy):
    ob = _light("POINT")
    ob.data.energy = energy
    return ob


LIGHT_ROWS = {
    "Light Exposure": lambda: setattr(_point(240.0).data, "exposure", -2.0),
    "Area light, Normalize off": lambda: _area_not_normalised(),
    "Light node tree (Emission Strength 0.1, orange)": lambda: _set_emission_node(_point(600.0), 0.1, (1.0, 0.5, 0.2)),
}


def _area_not_normalised():
    ob = _light("AREA", shape="SQUARE", size=0.6)
    ob.data.energy = 80.0 / 0.36  # the same light as 80 W normalised, if the area is read
    ob.data.normalize = False


@pytest.mark.parametrize("feature", list(LIGHT_ROWS))
def test_light_options_are_read_as_cycles_reads_them(empty_scene, cubegi, feature):
    obs = _box()
    LIGHT_ROWS[feature]()
    err, _ = _direct_errors(cubegi, obs)
    _record(feature, "read exactly", direct_rel_bias=err["rel_bias"], direct_rel_rmse=err["rel_rmse"])
    assert abs(err["rel_bias"]) < DIRECT_BIAS_TOL, err
    assert err["rel_rmse"] < DIRECT_RMSE_TOL, err


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
    "Light Temperature": (lambda: (setattr(_point(60.0).data, "use_temperature", True), setattr(bpy.data.lights["point"], "temperature", 1800.0)),
                          "light point: Temperature (1800 K) is not read; baked with its Color alone"),
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
    make, note = NOTED[feature]
    make()
    assert bpy.ops.cubegi.bake(**FAST) == {"FINISHED"}
    found = [n for n in _notes() if note in n]
    _record(feature, "not supported", note=found[0] if found else None)
    assert found, _notes()
