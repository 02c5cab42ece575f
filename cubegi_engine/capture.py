"""The probe capture: what every probe's cube map sees, and the tables built from it.

Pure numpy; must not import bpy. A :class:`ProbeCapture` is drawn once per geometry and
grid and stays valid across edits of lights, materials and the world (its tables do not
depend on them); :meth:`ProbeCapture.valid_for` says whether it still applies to a scene.
"""

import time
from dataclasses import dataclass

import numpy as np

from .scene import GeometryFingerprint
from .transport import CubeCapture, Transport, capture_cubes, clip_planes

__all__ = ["ProbeCapture"]


@dataclass
class ProbeCapture:
    """Cube maps of every probe of ``grid`` (``cubes``: texel -> triangle, barycentrics,
    distance, back face) and the transport tables built from them (``transport``), for the
    geometry whose fingerprint is ``fingerprint``."""

    grid: object  # ProbeGrid or GridSet
    cube_size: int
    visibility: bool
    fingerprint: GeometryFingerprint
    cubes: CubeCapture
    transport: Transport
    capture_seconds: float = 0.0
    tables_seconds: float = 0.0

    @classmethod
    def take(cls, scene, grid, renderer, cube_size: int, visibility: bool = True) -> "ProbeCapture":
        """Draw every probe's cube map of ``scene`` and build the tables."""
        near, far = clip_planes(scene.scale)
        t = time.perf_counter()
        cubes = capture_cubes(renderer, grid.positions(), cube_size, near, far)
        t_capture = time.perf_counter() - t
        t = time.perf_counter()
        transport = Transport(scene, grid, cubes, visibility=visibility)
        return cls(grid, int(cube_size), bool(visibility), scene.fingerprint(), cubes, transport, t_capture, time.perf_counter() - t)

    def valid_for(self, scene, grid, cube_size: int, visibility: bool) -> bool:
        """True if this capture applies to ``scene`` baked on ``grid`` at these settings."""
        return (
            self.cube_size == int(cube_size) and self.visibility == bool(visibility)
            and _same_grid(self.grid, grid) and not self.fingerprint.changed(scene.fingerprint())
        )

    @property
    def probe_valid(self) -> np.ndarray:
        return self.transport.probe_valid

    def probes_seeing(self, objects) -> np.ndarray:
        """``(p,)`` bool: the probes whose cube maps show any triangle of the objects with
        these indices (``SceneArrays.point_object``); what a change of them invalidates."""
        tid = self.cubes.tid.reshape(len(self.cubes.tid), -1)
        owner = self.transport.triangle_object
        if owner is None:
            return np.ones(len(tid), dtype=bool)
        hit = np.isin(owner[np.maximum(tid, 0)], np.asarray(list(objects), dtype=np.int64)) & (tid >= 0)
        return hit.any(axis=1)

    @property
    def nbytes(self) -> int:
        """Memory held, in bytes."""
        arrays = [self.cubes.tid, self.cubes.bary, self.cubes.dist, self.cubes.backface, *self.transport.arrays()]
        return int(sum(a.nbytes for a in arrays))


def _same_grid(a, b) -> bool:
    ga, gb = getattr(a, "grids", (a,)), getattr(b, "grids", (b,))
    return len(ga) == len(gb) and all(x == y for x, y in zip(ga, gb))
