"""Tests in real Blender: the extension registered, each scene test from an empty factory
file. Skipped as a whole where bpy cannot be imported."""

import os
import sys

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # scenes, state, golden

try:
    import bpy  # noqa: F401
except ImportError:
    collect_ignore_glob = ["test_*.py"]


@pytest.fixture(scope="session")
def cubegi():
    """The extension package (``cubegi``), registered."""
    from tools import load_extension

    return load_extension()


@pytest.fixture
def empty_scene(cubegi):
    """An empty factory file with the extension registered."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene
