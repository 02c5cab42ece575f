"""Every supported Blender gives the same light: the demo Room baked by the command line,
compared with the default version's bake of it (docs/blender-versions.md).

Each run writes its light to ``out/versions/bpy-VERSION.npz``; where ``CUBEGI_REFERENCE_LIGHT``
names another version's file (CI sets it to the default version's), this version's light must
equal it.
"""

import os
import subprocess
import sys

import bpy
import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# The same code on the same machine computes the same float32 numbers on every version (the
# capture, shaders and numpy calls do not depend on it; measured: identical on 4.5.15 to
# 5.3.0); 1e-4 of the peak allows for a GPU driver that rasterises an edge differently.
SAME_LIGHT = 1e-4


def _light(path):
    bpy.ops.wm.open_mainfile(filepath=str(path))
    read = __import__("cubegi").cubegi_addon.attributes.read
    return {f"{ob.name}:{name}": read(ob.data, name) for ob in bpy.data.objects if ob.type == "MESH"
            for name in ("CubeGI_direct", "CubeGI", "CubeGI_total")}


@pytest.mark.smoke
def test_the_demo_bakes_the_same_light_on_every_version(tmp_path, cubegi):
    r = subprocess.run([sys.executable, "-m", "cubegi_engine", "demo", "--out", str(tmp_path), "--no-render"],
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    light = _light(tmp_path / "room.blend")
    assert light and all(np.isfinite(v).all() for v in light.values())
    assert max(v.max() for v in light.values()) > 0
    mine = os.path.join(ROOT, "out", "versions", f"bpy-{bpy.app.version_string.split()[0]}.npz")
    os.makedirs(os.path.dirname(mine), exist_ok=True)
    np.savez(mine, **light)
    reference = os.environ.get("CUBEGI_REFERENCE_LIGHT")
    if not reference or os.path.abspath(reference) == mine:
        return
    with np.load(reference) as ref:
        assert sorted(ref.files) == sorted(light)
        peak = max(ref[k].max() for k in ref.files)
        for key in ref.files:
            np.testing.assert_allclose(light[key], ref[key], rtol=0, atol=SAME_LIGHT * peak, err_msg=key)
