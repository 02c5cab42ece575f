"""A failure at any stage of a bake leaves every mesh's attributes and the materials exactly
as they were (forced here by making each stage raise)."""

import bpy
import pytest
import scenes
from state import scene_state as _state


class Boom(Exception):
    pass


@pytest.fixture
def baked_once(empty_scene, cubegi):
    """The Cornell box with a user attribute and a first bake in place."""
    scenes.cornell(light=True)
    bpy.data.objects["Tall"].data.attributes.new("user_data", "FLOAT", "POINT").data[0].value = 7.0
    assert bpy.ops.cubegi.bake(bounces=2, grid=(2, 2, 2), cube_size=8) == {"FINISHED"}
    return cubegi


def _fail_at(monkeypatch, cubegi, stage):
    pipeline = cubegi.cubegi_addon.pipeline
    capture = __import__("cubegi.cubegi_engine.capture", fromlist=["x"])
    direct = __import__("cubegi.cubegi_engine.direct", fromlist=["x"])
    transport = __import__("cubegi.cubegi_engine.transport", fromlist=["x"])
    gpu_capture = __import__("cubegi.cubegi_addon.gpu_capture", fromlist=["x"])

    def boom(*a, **k):
        raise Boom(stage)

    if stage == "collect":
        monkeypatch.setattr(pipeline.scene_data, "_assemble", boom)  # in the thread that makes the arrays
    elif stage == "gpu":
        monkeypatch.setattr(gpu_capture, "_batch_steps", boom)  # the scene's upload
    elif stage == "capture":
        monkeypatch.setattr(capture, "capture_cubes", boom)
    elif stage == "direct":
        monkeypatch.setattr(direct, "light_direct_steps", boom)
    elif stage == "bounce":
        monkeypatch.setattr(transport.Transport, "gather_project", boom)
    elif stage == "reference":
        monkeypatch.setattr(pipeline.reference, "reference_layers", boom)
    elif stage == "write":  # the first mesh is written, the second fails
        real = pipeline.attributes.write
        calls = []

        def second_fails(mesh, layers):
            calls.append(mesh.name)
            if len(calls) == 2:
                raise Boom("write")
            real(mesh, layers)

        monkeypatch.setattr(pipeline.attributes, "write", second_fails)


@pytest.mark.parametrize("stage", ["collect", "gpu", "capture", "direct", "bounce", "reference", "write"])
def test_a_failed_bake_changes_nothing(baked_once, monkeypatch, stage):
    before = _state()
    _fail_at(monkeypatch, baked_once, stage)
    with pytest.raises((Boom, RuntimeError)):
        bpy.ops.cubegi.bake(bounces=3, grid=(3, 3, 3), cube_size=8, reference_samples=2)
    assert _state() == before
