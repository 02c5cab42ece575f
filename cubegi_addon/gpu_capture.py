"""Cube-map capture with Blender's ``gpu`` module: the one place CubeGI draws.

Implements the :class:`cubegi_engine.bake.Renderer` protocol. Every view of a call is drawn
into one atlas (a float RGBA target with a depth attachment) and read back once.
Per texel the id pass writes ``(+-(triangle + 1), b1, b2, distance)``: the sign marks a
back face, 0 means nothing was hit; triangle ids are exact in float32 up to 2^24.
"""

import atexit
import contextlib
import functools
import math
import os
import sys

import bpy
import gpu
import numpy as np
from gpu_extras.batch import batch_for_shader

from ..cubegi_engine import geometry
from ..cubegi_engine.errors import BakeError
from ..cubegi_engine.transport import no_barycentrics
from ..cubegi_engine.working import in_background, run
from . import compat
from .bvh_rays import BvhRays

# Largest atlas edge in texels; 2048^2 RGBA32F is 64 MiB.
ATLAS_EDGE = 2048
# Per-view culling: the triangles are uploaded in spatial order (a Morton curve through
# their centroids) and cut into chunks of CULL_CHUNK; a view draws only the chunks whose
# bounding box reaches into its frustum (a cube face sees about a sixth of the scene
# around a probe). A scene of at most one chunk is drawn whole.
CULL_CHUNK = 2048
MAX_TRIANGLES = (1 << 24) - 1
FAR_AWAY = 3.0e38

_gpu_ready = False


@contextlib.contextmanager
def _quiet_stderr():
    """Send what C code prints on stderr to /dev/null for the block (Python's own errors
    still raise). Only around the one render that brings the GPU up."""
    sys.stderr.flush()
    saved = os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


def ensure_gpu():
    """Bring up the GPU module in background mode, where no public call does it.

    A Workbench render of a 1x1 image from a throw-away scene holding only a camera starts
    the GPU backend for the rest of the process. Everything it creates is removed again,
    so the user's file is unchanged.
    """
    global _gpu_ready
    if _gpu_ready or not bpy.app.background:
        _gpu_ready = True
        return
    had_render_result = {im.name for im in bpy.data.images if im.type == "RENDER_RESULT"}
    scene = bpy.data.scenes.new("CubeGI_gpu_init")
    cam_data = bpy.data.cameras.new("CubeGI_gpu_init")
    cam = bpy.data.objects.new("CubeGI_gpu_init", cam_data)
    try:
        scene.collection.objects.link(cam)
        scene.camera = cam
        scene.render.engine = "BLENDER_WORKBENCH"
        scene.render.resolution_x = scene.render.resolution_y = 1
        with _quiet_stderr():  # Mesa's EGL prints EGL_BAD_MATCH while it probes configs; harmless
            bpy.ops.render.render(scene=scene.name)
    finally:
        bpy.data.objects.remove(cam)
        bpy.data.cameras.remove(cam_data)
        bpy.data.scenes.remove(scene)
        for im in list(bpy.data.images):
            if im.type == "RENDER_RESULT" and im.name not in had_render_result:
                bpy.data.images.remove(im)
    _gpu_ready = True


_ID_VERT = """
void main() {
  v_id = tid;
  v_twin = twin;
  v_bary = bary;
  v_twin_bary = twin_bary;
  v_pos = pos;
  gl_Position = view_proj * vec4(pos, 1.0);
}
"""
# A triangle of a two-sided object (see SceneArrays.back) is drawn once for itself and its
# twin facing the other way, which stands in the same place: ``twin`` >= 0 is the twin's
# index, reported (with the hit's weights of the twin's corners, ``twin_bary``) where the
# triangle is seen from behind. One with no twin comes as tid = -(triangle + 1): its back face
# is not drawn.
_ID_FRAG = """
void main() {
  bool front = gl_FrontFacing;
  float id = v_id < 0.0 ? -v_id - 1.0 : v_id;
  vec2 bary = v_bary;
  if (!front && v_twin >= 0.0) {
    id = v_twin;
    bary = v_twin_bary;
    front = true;
  }
  else if (v_id < 0.0 && !front) {
    discard;
  }
  float dist = ortho > 0.5 ? dot(v_pos - eye, axis) : length(v_pos - eye);
  out_texel = vec4(front ? id + 1.0 : -(id + 1.0), bary, dist);
}
"""
_DEPTH_FRAG = """
void main() {
  bool front = gl_FrontFacing;
  float id = v_id < 0.0 ? -v_id - 1.0 : v_id;
  if (!front && v_twin >= 0.0) {
    id = v_twin;
    front = true;
  }
  else if (v_id < 0.0 && !front) {
    discard;
  }
  float dist = ortho > 0.5 ? dot(v_pos - eye, axis) : length(v_pos - eye);
  out_texel = vec2(front ? id + 1.0 : -(id + 1.0), dist);
}
"""
_COLOUR_VERT = """
void main() {
  v_colour = colour;
  v_sheet = sheet;
  gl_Position = view_proj * vec4(pos, 1.0);
}
"""
_COLOUR_FRAG = """
void main() {
  if (v_sheet > 0.5 && !gl_FrontFacing) discard;
  out_texel = gl_FrontFacing ? vec4(v_colour, 1.0) : vec4(0.0, 0.0, 0.0, 1.0);
}
"""


# The shaders are made once per process and kept. Making and freeing one per renderer let a
# later draw pick up the wrong vertex layout now and then (colours read from the position
# buffer, seen on llvmpipe after other GPU work in the same process).
@functools.cache
def _id_shader(with_bary=True):
    """The id pass: ``(+-(triangle + 1), b1, b2, distance)`` per texel into RGBA32F, or with
    ``with_bary=False`` ``(+-(triangle + 1), distance)`` into RG32F (shadow maps: half the
    texels' bytes to write and read back)."""
    iface = gpu.types.GPUStageInterfaceInfo("cubegi_id_iface" if with_bary else "cubegi_depth_iface")
    iface.flat("FLOAT", "v_id")
    iface.flat("FLOAT", "v_twin")
    iface.smooth("VEC2", "v_bary")
    iface.smooth("VEC2", "v_twin_bary")
    iface.smooth("VEC3", "v_pos")
    info = gpu.types.GPUShaderCreateInfo()
    info.push_constant("MAT4", "view_proj")
    info.push_constant("VEC3", "eye")
    info.push_constant("VEC3", "axis")
    info.push_constant("FLOAT", "ortho")
    info.vertex_in(0, "VEC3", "pos")
    info.vertex_in(1, "VEC2", "bary")
    info.vertex_in(2, "FLOAT", "tid")
    info.vertex_in(3, "FLOAT", "twin")
    info.vertex_in(4, "VEC2", "twin_bary")
    info.vertex_out(iface)
    info.fragment_out(0, "VEC4" if with_bary else "VEC2", "out_texel")
    info.vertex_source(_ID_VERT)
    info.fragment_source(_ID_FRAG if with_bary else _DEPTH_FRAG)
    return gpu.shader.create_from_info(info)


@functools.cache
def _colour_shader():
    iface = gpu.types.GPUStageInterfaceInfo("cubegi_colour_iface")
    iface.smooth("VEC3", "v_colour")
    iface.flat("FLOAT", "v_sheet")
    info = gpu.types.GPUShaderCreateInfo()
    info.push_constant("MAT4", "view_proj")
    info.vertex_in(0, "VEC3", "pos")
    info.vertex_in(1, "VEC3", "colour")
    info.vertex_in(2, "FLOAT", "sheet")
    info.vertex_out(iface)
    info.fragment_out(0, "VEC4", "out_texel")
    info.vertex_source(_COLOUR_VERT)
    info.fragment_source(_COLOUR_FRAG)
    return gpu.shader.create_from_info(info)


def _free_shaders():
    """Free the kept shaders while the GPU context still exists (at exit, before bpy's own
    exit handler, which runs later because it was registered earlier)."""
    _id_shader.cache_clear()
    _colour_shader.cache_clear()


atexit.register(_free_shaders)


def _column_major(matrix):
    # GLSL reads a mat4 push constant column by column.
    return np.asarray(matrix, dtype=np.float64).T.ravel().tolist()


def read_texture(texture, width, height, channels=4):
    """A float texture (RGBA32F, RG32F) to a ``(height, width, channels)`` float32 array (row
    0 = bottom).

    The buffer's strides are declared differently across versions (see
    :func:`.compat.gpu_buffer_array`).
    """
    return compat.gpu_buffer_array(texture.read(), (height, width, channels))


class GpuRenderer:
    """Draws one fixed set of triangles into many square views (see the Renderer protocol).

    points: ``(s, 3)`` world positions; triangles: ``(t, 3)`` point indices; sheet: ``(t,)``
    bool, triangles whose back faces are not drawn (two-sided objects: see
    ``SceneArrays.back``).

    The GPU works in a unit frame: positions are uploaded as ``(p - centre) / size`` of the
    scene's bounding box, and every view is re-expressed in that frame (see :meth:`_local`).
    So a scene drawn at 1 mm or at 10 km gives the GPU the same float32 numbers, and the
    same texels, and distances come back in world units.
    """

    def __init__(self, points, triangles, drawn=None, sheet=None):
        ensure_gpu()
        run(self._uploaded(_prepared(points, triangles, drawn, sheet)))

    @classmethod
    def steps(cls, points, triangles, working, sheet=None):
        """The renderer, made in steps: its arrays in a thread, then each vertex column
        uploaded in a step of its own (a generator yielding ``working``, a Progress)."""
        ensure_gpu()
        prepared = yield from in_background(_prepared, working, points, triangles, None, sheet)
        renderer = cls.__new__(cls)
        yield from renderer._uploaded(prepared, working)
        return renderer

    # The vertex columns, kept only until they are uploaded (a million-vertex scene's are
    # hundreds of MB; the GPU keeps its own copy).
    UPLOADED = ("pos", "bary", "tid", "twin", "twin_bary")

    def _uploaded(self, prepared, working=None):
        columns = {name: prepared.pop(name) for name in self.UPLOADED}
        self.__dict__.update(prepared)
        self.id_shader = _id_shader()
        self.id_batch = yield from _batch_steps(self.id_shader, columns, working)
        self._colour_shader = None

    @staticmethod
    def rays(points, triangles):
        """A ray caster over ``triangles (k, 3)`` of ``points`` (the engine's
        :class:`~cubegi_engine.rays.RayCaster`): Blender's BVH tree. Static: what holds it
        holds no renderer."""
        return BvhRays(points, triangles)

    def with_geometry(self, points, triangles, drawn=None, sheet=None):
        """A renderer of other triangles (the probes' simplified copy of the scene), drawing
        those ``drawn`` (indices; all by default); ``sheet``: as for the constructor."""
        return GpuRenderer(points, triangles, drawn, sheet)

    def _local(self, view_proj):
        """A world view-projection as one for unit-frame positions, scaled to entries <= 1
        (a uniform scale of a projective matrix does not change what it draws)."""
        to_world = np.diag([self.unit, self.unit, self.unit, 1.0])
        to_world[:3, 3] = self.centre
        m = np.asarray(view_proj, dtype=np.float64) @ to_world
        return m / np.abs(m).max()

    def _ranges(self, local_vps):
        """Per view, the ``(first vertex, count)`` runs of chunks it may see (see CULL_CHUNK);
        None where the scene is drawn whole."""
        if self.chunk_boxes is None:
            return None
        seen = _boxes_in_frusta(self.chunk_boxes, local_vps)  # (v, c)
        t = self.drawn_count
        out = []
        for row in seen:
            edges = np.diff(np.concatenate([[False], row, [False]]).astype(np.int8))
            starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
            out.append([(3 * CULL_CHUNK * a, 3 * (min(CULL_CHUNK * b, t) - CULL_CHUNK * a)) for a, b in zip(starts, ends)])
        return out

    def _draw(self, batch, shader, ranges, k):
        """Draw view ``k``'s share of ``batch`` (all of it where there is no culling)."""
        if ranges is None:
            batch.draw(shader)
            return
        for first, count in ranges[k]:
            batch.draw_range(shader, elem_start=int(first), elem_count=int(count))

    def _draw_views(self, view_projs, size, draw_one, channels=4):
        """Draw every view into atlas tiles; yields ``(first_view, tiles (k, n, n, channels))``."""
        per_row = max(1, ATLAS_EDGE // size)
        per_atlas = per_row * per_row
        v = len(view_projs)
        for first in range(0, v, per_atlas):
            count = min(per_atlas, v - first)
            cols = min(count, per_row)
            rows = math.ceil(count / cols)
            width, height = cols * size, rows * size
            colour = gpu.types.GPUTexture((width, height), format="RGBA32F" if channels == 4 else "RG32F")
            depth = gpu.types.GPUTexture((width, height), format="DEPTH_COMPONENT32F")
            # The framebuffer does not keep its attachments alive: hold both until read back.
            fb = gpu.types.GPUFrameBuffer(depth_slot=depth, color_slots=(colour,))
            with fb.bind():
                fb.clear(color=(0.0, 0.0, 0.0, FAR_AWAY) if channels == 4 else (0.0, FAR_AWAY, 0.0, 0.0), depth=1.0)
                gpu.state.depth_test_set("LESS")
                gpu.state.depth_mask_set(True)
                gpu.state.face_culling_set("NONE")
                gpu.state.blend_set("NONE")
                for k in range(count):
                    gpu.state.viewport_set((k % cols) * size, (k // cols) * size, size, size)
                    draw_one(first + k)
                gpu.state.depth_test_set("NONE")
                gpu.state.depth_mask_set(False)
            atlas = read_texture(colour, width, height, channels)
            del fb, depth, colour
            tiles = atlas.reshape(rows, size, cols, size, channels).transpose(0, 2, 1, 3, 4).reshape(rows * cols, size, size, channels)
            yield first, tiles[:count]

    def render(self, view_projs, eyes, axes, size, with_bary=True):
        v = len(view_projs)
        tid = np.empty((v, size, size), dtype=np.int32)
        bary = np.zeros((v, size, size, 3), dtype=np.float32) if with_bary else no_barycentrics((v, size, size, 3))
        dist = np.empty((v, size, size), dtype=np.float32)
        back = np.empty((v, size, size), dtype=bool)
        # The depth-only shader takes the same vertices (its inputs are the id shader's, at
        # the same locations): one batch, uploaded once, serves both.
        shader = self.id_shader if with_bary else _id_shader(False)
        batch = self.id_batch
        local = [self._local(vp) for vp in view_projs]
        ranges = self._ranges(local)
        shader.bind()

        def draw_one(k):
            shader.uniform_float("view_proj", _column_major(local[k]))
            shader.uniform_float("eye", tuple(float(x) for x in (np.asarray(eyes[k]) - self.centre) / self.unit))
            if axes is None:
                shader.uniform_float("axis", (0.0, 0.0, 1.0))
                shader.uniform_float("ortho", 0.0)
            else:
                shader.uniform_float("axis", tuple(float(x) for x in axes[k]))
                shader.uniform_float("ortho", 1.0)
            self._draw(batch, shader, ranges, k)

        for first, tiles in self._draw_views(view_projs, size, draw_one, 4 if with_bary else 2):
            sl = slice(first, first + len(tiles))
            code = tiles[..., 0]
            np.less(code, 0.0, out=back[sl])
            tid[sl] = np.abs(code)  # exact small integers in float32
            tid[sl] -= 1
            if with_bary:
                b1, b2 = tiles[..., 1], tiles[..., 2]
                bary[sl] = np.stack([1.0 - b1 - b2, b1, b2], axis=-1)
            d = dist[sl]
            with np.errstate(over="ignore"):
                np.multiply(tiles[..., -1], np.float32(self.unit), out=d)
            d[tid[sl] < 0] = np.inf  # nothing drawn: the clear value, not a distance
        return tid, bary, dist, back

    def render_colour(self, view_projs, size, point_radiance):
        if self._colour_shader is None:
            self._colour_shader = _colour_shader()
        shader = self._colour_shader
        corners = self.triangles[self.all_drawn]  # every triangle, both twins of a sheet
        colour = np.asarray(point_radiance, dtype=np.float32)[corners].reshape(-1, 3)
        batch = batch_for_shader(shader, "TRIS", {"pos": self.unit_points[corners].reshape(-1, 3), "colour": colour,
                                                  "sheet": np.repeat(self.sheet_all[self.all_drawn].astype(np.float32), 3)})
        out = np.empty((len(view_projs), size, size, 3), dtype=np.float32)
        local = [self._local(vp) for vp in view_projs]
        ranges = None  # every triangle, both twins of a sheet (a check in the tests, not a bake's path)
        shader.bind()

        def draw_one(k):
            shader.uniform_float("view_proj", _column_major(local[k]))
            self._draw(batch, shader, ranges, k)

        for first, tiles in self._draw_views(view_projs, size, draw_one):
            # Where nothing is drawn the clear colour's alpha (FAR_AWAY) marks sky: black.
            rgb = np.where(tiles[..., 3:4] == FAR_AWAY, 0.0, tiles[..., :3])
            out[first : first + len(tiles)] = rgb
        return out


def _prepared(points, triangles, drawn, sheet):
    """The arrays a GpuRenderer draws from (numpy alone: see the class)."""
    triangles = np.asarray(triangles)
    if len(triangles) > MAX_TRIANGLES:
        raise BakeError(f"the scene has {len(triangles)} triangles; capture supports up to {MAX_TRIANGLES}")
    pts = np.asarray(points, dtype=np.float64)
    lo, hi = (pts.min(axis=0), pts.max(axis=0)) if len(pts) else (np.zeros(3), np.ones(3))
    out = {"triangles": triangles, "centre": 0.5 * (lo + hi), "unit": max(float(np.max(hi - lo)), 1e-300)}
    unit_pts = ((pts - out["centre"]) / out["unit"]).astype(np.float32)
    drawn = np.arange(len(triangles)) if drawn is None else np.asarray(drawn, dtype=np.int64)
    sheet = np.zeros(len(triangles), dtype=bool) if sheet is None else np.asarray(sheet, dtype=bool)
    out["all_drawn"], out["sheet_all"], out["unit_points"] = drawn, sheet, unit_pts  # for render_colour
    twin, twin_bary = geometry.twin_triangles(unit_pts, triangles, sheet & np.isin(np.arange(len(triangles)), drawn))
    drawn = drawn[~(twin[drawn] >= 0) | (twin[drawn] > drawn)]  # a pair drawn once, as its first
    t = len(drawn)
    # Drawn in spatial order; each vertex carries its triangle's own index, so what a
    # texel reports does not depend on the order (nor on triangles left out).
    order = drawn[_spatial_order(unit_pts[triangles[drawn]].mean(axis=1))] if t > CULL_CHUNK else drawn
    out["drawn_count"] = t
    out["pos"] = unit_pts[triangles[order]].reshape(-1, 3)
    out["chunk_boxes"] = _chunk_boxes(out["pos"].reshape(-1, 3, 3), CULL_CHUNK) if t > CULL_CHUNK else None
    out["bary"] = np.tile(np.array([[0, 0], [1, 0], [0, 1]], dtype=np.float32), (t, 1))
    lone = sheet[order] & (twin[order] < 0)  # a sheet's triangle with no twin here: its back face is not drawn
    out["tid"] = np.repeat(np.where(lone, -(order + 1.0), order).astype(np.float32), 3)
    out["twin"] = np.repeat(twin[order].astype(np.float32), 3)
    out["twin_bary"] = twin_bary[order].reshape(-1, 2)
    return out


def _batch_steps(shader, columns, working=None):
    """``batch_for_shader(shader, "TRIS", columns)`` (its vertex format), filling one column
    at a time and yielding ``working`` between them (none if it is None)."""
    columns = compat.shader_columns(shader, columns)
    fmt = gpu.types.GPUVertFormat()
    for name, kind in shader.attrs_info_get():
        width = 1 if columns[name].ndim == 1 else columns[name].shape[1]
        comp = "F32" if kind in {"FLOAT", "VEC2", "VEC3", "VEC4"} else "I32"
        fmt.attr_add(id=name, comp_type=comp, len=width, fetch_mode="FLOAT" if comp == "F32" else "INT")
    vbo = gpu.types.GPUVertBuf(fmt, len(next(iter(columns.values()))))
    for i, (name, data) in enumerate(columns.items()):
        if i and working is not None:
            yield working
        vbo.attr_fill(name, data)
    return gpu.types.GPUBatch(type="TRIS", buf=vbo)


def _spatial_order(centres):
    """An order of points ``(t, 3)`` along a Morton (Z-order) curve of a 1024^3 grid over
    their box: neighbours in space end up near each other in the order."""
    lo, hi = centres.min(axis=0), centres.max(axis=0)
    q = ((centres - lo) / np.maximum(hi - lo, 1e-30) * 1023.0).astype(np.uint64)
    code = np.zeros(len(centres), dtype=np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")


def _chunk_boxes(corners, chunk):
    """The 8 corners ``(c, 8, 4)`` (homogeneous) of the box of each run of ``chunk``
    triangles ``corners (t, 3, 3)``."""
    t = len(corners)
    starts = np.arange(0, t, chunk)
    lo = np.minimum.reduceat(corners.min(axis=1), starts, axis=0)
    hi = np.maximum.reduceat(corners.max(axis=1), starts, axis=0)
    pick = np.array([[i >> 0 & 1, i >> 1 & 1, i >> 2 & 1] for i in range(8)], dtype=bool)  # (8, 3)
    xyz = np.where(pick[None], hi[:, None, :], lo[:, None, :]).astype(np.float64)
    return np.concatenate([xyz, np.ones(xyz.shape[:2] + (1,))], axis=2)


def _boxes_in_frusta(boxes, view_projs):
    """``(v, c)`` bool: whether box ``c`` (its corners ``(c, 8, 4)``) may reach into view
    ``v``'s clip volume. A box is left out only where all its corners lie beyond one and the
    same clip plane (exact for a convex box: each plane is linear in homogeneous space)."""
    vps = np.asarray(view_projs, dtype=np.float64)
    step = max(1, 4_000_000 // (32 * len(boxes)))  # views at a time: clip coordinates of <= 32 MB
    seen = np.empty((len(vps), len(boxes)), dtype=bool)
    for first in range(0, len(vps), step):
        clip = np.einsum("vij,ckj->vcki", vps[first : first + step], boxes)  # (v, c, 8, 4)
        x, y, z, w = clip[..., 0], clip[..., 1], clip[..., 2], clip[..., 3]
        out = (x > w).all(-1) | (x < -w).all(-1) | (y > w).all(-1) | (y < -w).all(-1) | (z > w).all(-1) | (z < -w).all(-1)
        seen[first : first + step] = ~out
    return seen
