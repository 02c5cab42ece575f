"""Cube-map texel geometry: face frames, texel directions, exact solid angles, look-ups.

Pure numpy; must not import bpy, gpu or mathutils.

Conventions (fixed here, used by the GPU capture and by every look-up):

* Faces are ordered +X, -X, +Y, -Y, +Z, -Z. Each face has an orthonormal frame
  (forward, right, up) with ``right = forward x up``, so a camera looking along
  ``forward`` with ``up`` as its screen-up is an ordinary right-handed OpenGL camera
  (front faces keep their winding).
* Side faces use world +Z as up; the +Z face uses +Y and the -Z face -Y as up.
* Texel ``(face, row, col)`` of an ``n x n`` face has its centre at
  ``u = 2 (col + 0.5) / n - 1`` along ``right`` and ``v = 2 (row + 0.5) / n - 1`` along
  ``up``; row 0 is the bottom row, as OpenGL writes it and as the atlas read-back stores it.
  Its unnormalised direction is ``forward + u right + v up``.
* The solid angle of a texel is exact (the projected area formula of the unit cube,
  ``atan2(u v, sqrt(u^2 + v^2 + 1))`` evaluated at the texel corners), so the texel solid
  angles of a whole cube sum to 4 pi up to rounding.
"""

from dataclasses import dataclass

import numpy as np

__all__ = ["sample_image", "equirect_uv", "texel_uv", "texel_directions", "texel_solid_angles", "direction_to_texel", "perspective_90", "orthographic", "look_matrix", "cube_view_projections", "any_perpendicular", "square_filter", "texels_around",
           "CubeCapture", "capture_cubes", "clip_planes", "no_barycentrics"]

FACE_FORWARD = np.array(
    [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64
)
FACE_UP = np.array(
    [[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 1, 0], [0, -1, 0]], dtype=np.float64
)
FACE_RIGHT = np.cross(FACE_FORWARD, FACE_UP)
FACE_NAMES = ("+X", "-X", "+Y", "-Y", "+Z", "-Z")


def texel_uv(n):
    """Texel-centre coordinates of one face: ``(u, v)``, each ``(n, n)`` float64, [row, col]."""
    c = (np.arange(n, dtype=np.float64) + 0.5) * (2.0 / n) - 1.0
    v, u = np.meshgrid(c, c, indexing="ij")
    return u, v


def texel_directions(n):
    """Unit directions of every texel centre: ``(6, n, n, 3)`` float64."""
    u, v = texel_uv(n)
    d = (
        FACE_FORWARD[:, None, None, :]
        + u[None, :, :, None] * FACE_RIGHT[:, None, None, :]
        + v[None, :, :, None] * FACE_UP[:, None, None, :]
    )
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _area_element(x, y):
    # Solid angle of the face rectangle [0, x] x [0, y] at distance 1 (signed).
    return np.arctan2(x * y, np.sqrt(x * x + y * y + 1.0))


def texel_solid_angles(n):
    """Exact solid angle of every texel of one face: ``(n, n)`` float64, same for all faces."""
    e = np.linspace(-1.0, 1.0, n + 1)
    y0, x0 = np.meshgrid(e[:-1], e[:-1], indexing="ij")
    y1, x1 = np.meshgrid(e[1:], e[1:], indexing="ij")
    return _area_element(x1, y1) - _area_element(x0, y1) - _area_element(x1, y0) + _area_element(x0, y0)


def direction_to_texel(dirs, n):
    """Face, row and column of the texel each direction falls in.

    dirs: ``(..., 3)`` directions (need not be unit, must be non-zero).
    Returns ``(face, row, col)``, each ``(...)`` int64, and ``(u, v)`` face coordinates.
    """
    d = np.asarray(dirs, dtype=np.float64)
    a = np.abs(d)
    axis = np.argmax(a, axis=-1)
    sign_neg = np.take_along_axis(d, axis[..., None], axis=-1)[..., 0] < 0
    face = axis * 2 + sign_neg
    fwd = FACE_FORWARD[face]
    depth = np.einsum("...i,...i->...", d, fwd)
    depth = np.where(depth > 0, depth, 1.0)
    u = np.einsum("...i,...i->...", d, FACE_RIGHT[face]) / depth
    v = np.einsum("...i,...i->...", d, FACE_UP[face]) / depth
    col = np.clip(((u + 1.0) * 0.5 * n).astype(np.int64), 0, n - 1)
    row = np.clip(((v + 1.0) * 0.5 * n).astype(np.int64), 0, n - 1)
    return face, row, col, u, v


def perspective_90(near, far):
    """OpenGL projection matrix (4x4 float64) of a 90-degree square frustum."""
    p = np.zeros((4, 4))
    p[0, 0] = p[1, 1] = 1.0
    p[2, 2] = -(far + near) / (far - near)
    p[2, 3] = -2.0 * far * near / (far - near)
    p[3, 2] = -1.0
    return p


def orthographic(half_width, near, far):
    """OpenGL projection matrix (4x4 float64) of a square orthographic box."""
    p = np.zeros((4, 4))
    p[0, 0] = p[1, 1] = 1.0 / half_width
    p[2, 2] = -2.0 / (far - near)
    p[2, 3] = -(far + near) / (far - near)
    p[3, 3] = 1.0
    return p


def look_matrix(eye, forward, up):
    """World-to-view matrix (4x4 float64) of a camera at ``eye`` looking along ``forward``."""
    f = np.asarray(forward, dtype=np.float64)
    f = f / np.linalg.norm(f)
    u = np.asarray(up, dtype=np.float64)
    r = np.cross(f, u)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = r, u, -f
    m[:3, 3] = -m[:3, :3] @ np.asarray(eye, dtype=np.float64)
    return m


def cube_view_projections(eye, near, far):
    """The six face view-projection matrices of a cube map at ``eye``: ``(6, 4, 4)`` float64."""
    proj = perspective_90(near, far)
    return np.stack([proj @ look_matrix(eye, FACE_FORWARD[f], FACE_UP[f]) for f in range(6)])


def cube_view_projections_many(eyes, nears, far, turns=None):
    """:func:`cube_view_projections` of many eyes ``(k, 3)`` with near planes ``(k,)`` at
    once: ``(6k, 4, 4)`` float64, eye after eye. ``turns``: ``(k, 3, 3)`` rotations, one per
    eye, of its cube's frame (world direction = turn @ cube direction; see :func:`turned`)."""
    eyes = np.asarray(eyes, dtype=np.float64).reshape(-1, 3)
    nears = np.broadcast_to(np.asarray(nears, dtype=np.float64), (len(eyes),))
    rot = np.broadcast_to(_FACE_ROTATIONS, (len(eyes), 6, 3, 3))  # (k, 6, 3, 3)
    if turns is not None:
        rot = np.einsum("fij,klj->kfil", _FACE_ROTATIONS, np.asarray(turns, dtype=np.float64))
    views = np.zeros((len(eyes), 6, 4, 4))
    views[:, :, :3, :3] = rot
    views[:, :, :3, 3] = -np.einsum("kfij,kj->kfi", rot, eyes)
    views[:, :, 3, 3] = 1.0
    proj = np.zeros((len(eyes), 4, 4))
    proj[:, 0, 0] = proj[:, 1, 1] = 1.0
    proj[:, 2, 2] = -(far + nears) / (far - nears)
    proj[:, 2, 3] = -2.0 * far * nears / (far - nears)
    proj[:, 3, 2] = -1.0
    return np.einsum("kij,kfjl->kfil", proj, views).reshape(-1, 4, 4)


def turns(count, seed=0):
    """``(count, 3, 3)`` rotations spread uniformly over all orientations (Shoemake's unit
    quaternions from a seeded generator): turning each of many shadow cube maps its own way
    makes their texel edges fall in different places, so their errors at a silhouette
    average out instead of adding up."""
    u1, u2, u3 = np.random.default_rng(seed).random((3, count))
    a, b = np.sqrt(1.0 - u1), np.sqrt(u1)
    w, x = a * np.sin(2 * np.pi * u2), a * np.cos(2 * np.pi * u2)
    y, z = b * np.sin(2 * np.pi * u3), b * np.cos(2 * np.pi * u3)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=-1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=-1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=1)


def any_perpendicular(v):
    """A unit vector perpendicular to ``v`` (3,)."""
    v = np.asarray(v, dtype=np.float64)
    helper = np.array([0.0, 0.0, 1.0]) if abs(v[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    p = np.cross(v, helper)
    return p / np.linalg.norm(p)


def sample_image(rgb, uv):
    """Bilinear, repeating look-up of ``rgb (h, w, 3)`` (row 0 at v = 0, as Blender stores
    images) at ``uv (k, 2)``."""
    h, w, _ = rgb.shape
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, x1 = x0 % w, (x0 + 1) % w
    y0, y1 = y0 % h, (y0 + 1) % h
    top = rgb[y0, x0] * (1 - fx) + rgb[y0, x1] * fx
    bottom = rgb[y1, x0] * (1 - fx) + rgb[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def equirect_uv(dirs):
    """Cycles' equirectangular coordinates of unit directions ``(k, 3)``: u = 1/2 -
    atan2(y, x) / 2 pi (+X at the image's centre, +Y a quarter to the left), v = 1 - acos(z)
    / pi (+Z, up, at the top row)."""
    d = np.asarray(dirs, dtype=np.float64)
    u = 0.5 - np.arctan2(d[:, 1], d[:, 0]) / (2.0 * np.pi)
    v = 1.0 - np.arccos(np.clip(d[:, 2], -1.0, 1.0)) / np.pi
    return np.stack([u, v], axis=1)


# The rotation part of each face's view matrix (the same at every eye).
_FACE_ROTATIONS = np.stack([look_matrix(np.zeros(3), FACE_FORWARD[f], FACE_UP[f])[:3, :3] for f in range(6)])


def texels_around(row, col, n, reach=1):
    """``(rows, cols)``, each ``(m, (2 reach + 1)^2)``: the texels within ``reach`` of each
    texel ``row, col (m,)`` on its face of edge ``n``, row by row (the texel itself in the
    middle column), held at the face's edges."""
    steps = np.arange(-reach, reach + 1)
    dr, dc = np.repeat(steps, len(steps)), np.tile(steps, len(steps))
    return np.clip(np.asarray(row)[:, None] + dr, 0, n - 1), np.clip(np.asarray(col)[:, None] + dc, 0, n - 1)


def square_filter(values, reach, pick):
    """``pick`` (``np.minimum`` or ``np.maximum``) over each texel of ``values (f, n, n)`` and
    those within ``reach`` of it on its face, one axis at a time (texels past the edge count
    as seeing nothing: infinitely far)."""
    out = values
    for axis in (1, 2):
        n = out.shape[axis]
        pad = [(0, 0)] * 3
        pad[axis] = (reach, reach)
        padded = np.pad(out, pad, constant_values=np.inf)
        acc = out.copy()
        for shift in range(2 * reach + 1):
            window = [slice(None)] * 3
            window[axis] = slice(shift, shift + n)
            pick(acc, padded[tuple(window)], out=acc)
        out = acc
    return out


@dataclass
class CubeCapture:
    """What every texel of a set of cube maps sees; arrays are ``(k, 6, n, n, ...)``.

    tid: int32 triangle index (-1 where the texel sees sky); bary: float32 ``(..., 3)``
    barycentric weights of the hit point; dist: float32 distance to it (inf for sky);
    backface: bool, the texel sees a triangle from behind.
    """

    tid: np.ndarray
    bary: np.ndarray
    dist: np.ndarray
    backface: np.ndarray

    @property
    def size(self):
        return self.tid.shape[-1]


def no_barycentrics(shape) -> np.ndarray:
    """Zero barycentric weights of ``shape`` that take no memory (read-only): a depth map's."""
    return np.broadcast_to(np.zeros((), dtype=np.float32), shape)


def capture_cubes(renderer, eyes, size, near, far, with_bary=True, turns=None):
    """Render cube maps at ``eyes`` ``(k, 3)`` with ``renderer`` and return a CubeCapture.
    ``near``: one distance, or one per eye ``(k,)``. ``with_bary=False``: depth maps alone
    (the barycentrics come back zero; shadow tests do not read them). ``turns``: each
    cube's rotation ``(k, 3, 3)`` (see :func:`cubemap.turns`)."""
    eyes = np.asarray(eyes, dtype=np.float64).reshape(-1, 3)
    vps = cube_view_projections_many(eyes, near, far, turns)
    tid, bary, dist, back = renderer.render(vps, np.repeat(eyes, 6, axis=0), None, size, with_bary=with_bary)
    shape = (len(eyes), 6, size, size)
    bary = bary.reshape(shape + (3,)) if with_bary else no_barycentrics(shape + (3,))
    return CubeCapture(tid.reshape(shape), bary, dist.reshape(shape), back.reshape(shape))


# Near planes: a ten-thousandth of the scene's size, or less where the geometry that matters
# is smaller: a hundredth of a probe's cell, a hundredth of a light's distance to the
# nearest point. (A large ground plane under a small room must not clip the room away.)
NEAR_OF_SCALE, NEAR_OF_LOCAL = 1e-4, 1e-2


def clip_planes(scale, local=None):
    """Near and far distances for captures in a scene of size ``scale`` (its diagonal);
    ``local``: the size of what is around the eye (a cell, a distance), one or ``(k,)``."""
    near = NEAR_OF_SCALE * scale
    if local is not None:
        near = np.minimum(near, NEAR_OF_LOCAL * np.maximum(np.asarray(local, dtype=np.float64), 1e-30))
    return near, 4.0 * scale
