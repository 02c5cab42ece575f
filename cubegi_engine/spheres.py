"""Small spheres that show each probe's light: geometry and colours for the viewport.

Pure numpy; must not import bpy. A sphere's colour at normal ``n`` is the diffuse light
(irradiance / pi, the value CubeGI bakes) that a surface facing ``n`` at the probe receives,
evaluated from the probe's 9 SH coefficients, so a sphere looks as a white diffuse ball
placed there would.
"""

import numpy as np

from . import sh

__all__ = ["icosphere", "probe_spheres"]

# The icosahedron: 12 unit vertices, 20 outward faces.
_T = (1.0 + 5.0**0.5) / 2.0
_ICO_VERTS = np.array(
    [[-1, _T, 0], [1, _T, 0], [-1, -_T, 0], [1, -_T, 0], [0, -1, _T], [0, 1, _T],
     [0, -1, -_T], [0, 1, -_T], [_T, 0, -1], [_T, 0, 1], [-_T, 0, -1], [-_T, 0, 1]],
    dtype=np.float64,
)
_ICO_FACES = np.array(
    [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6],
     [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
     [8, 6, 7], [9, 8, 1]],
    dtype=np.int64,
)


def icosphere(subdivisions=1):
    """A unit sphere: vertices ``(m, 3)`` float64 (also its normals) and faces ``(f, 3)`` int64."""
    verts = _ICO_VERTS / np.linalg.norm(_ICO_VERTS, axis=1, keepdims=True)
    faces = _ICO_FACES
    for _ in range(subdivisions):
        edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
        unique, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = verts[unique].mean(axis=1)
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = inverse.reshape(3, -1).T + len(verts)  # (f, 3): midpoints of edges 01, 12, 20
        a, b, c = faces.T
        faces = np.concatenate(
            [np.stack(t, axis=1) for t in ((a, m[:, 0], m[:, 2]), (b, m[:, 1], m[:, 0]), (c, m[:, 2], m[:, 1]), (m[:, 0], m[:, 1], m[:, 2]))]
        )
        verts = np.concatenate([verts, mid])
    return verts, faces


def probe_spheres(positions, coeffs, radius, subdivisions=1):
    """One sphere per probe, coloured by its light.

    positions: ``(p, 3)``; coeffs: ``(p, 9, 3)`` SH radiance; radius: world units. Returns
    ``(vertices (p*m, 3) float32, colours (p*m, 3) float32, faces (p*f, 3) int32)``.
    """
    unit, faces = icosphere(subdivisions)
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    coeffs = np.asarray(coeffs, dtype=np.float64).reshape(len(positions), 9, 3)
    verts = positions[:, None, :] + radius * unit[None, :, :]
    basis = sh.diffuse_basis(unit)  # (m, 9)
    colours = np.maximum(np.einsum("mk,pkc->pmc", basis, coeffs), 0.0)
    tris = faces[None, :, :] + (len(unit) * np.arange(len(positions)))[:, None, None]
    return verts.reshape(-1, 3).astype(np.float32), colours.reshape(-1, 3).astype(np.float32), tris.reshape(-1, 3).astype(np.int32)
