"""Cube-map capture with Blender's ``gpu`` module: the one place CubeGI draws.

Implements the :class:`cubegi_engine.bake.Renderer` protocol. Every view of a call is drawn
into one atlas (a float RGBA target with a depth attachment) and read back once.

The triangles are drawn indexed, so a vertex shared by triangles is transformed once (on
llvmpipe 1.6x faster than three vertices of its own per triangle): a vertex carries its
position and, as a flat value, the number ``k`` of the one drawn triangle it is the
provoking vertex of (each triangle is given one of its own; see :func:`provoking_layout`).
Per texel the id pass writes ``(+-(k + 1), x, y, z)``, the point hit; the triangle, its
twin, the barycentric weights and the distance are worked out from them after the
read-back. The sign marks a back face, 0 means nothing was hit; numbers are exact in
float32 up to 2^24. Depth maps write ``(+-(k + 1), distance)``. (``gl_PrimitiveID`` would
serve without the layout, but llvmpipe draws then as slowly as without indices.)
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

from ..cubegi_engine.cubemap import no_barycentrics
from ..cubegi_engine.errors import BakeError
from ..cubegi_engine.working import in_background, run
from . import compat
from .bvh_rays import BvhRays
from .draw_layout import barycentric, barycentric_rows, boxes_in_frusta, prepare
from .gpu_rays import GpuRays

# Largest atlas edge in texels; 2048^2 RGBA32F is 64 MiB.
ATLAS_EDGE = 2048
FAR_AWAY = 3.0e38

_gpu_ready = False
# Rays through the GPU module's compute shaders (gpu_rays), else through Blender's BVH tree.
GPU_RAYS = True


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
  v_pos = pos;
  gl_Position = view_proj * vec4(pos, 1.0);
}
"""
# A sheet's triangle whose twin is drawn for it reports itself from behind; the twin is found
# after the read-back. A sheet's triangle with no twin is drawn with back faces culled (see
# GpuRenderer._draw).
_ID_FRAG = """
void main() {
  float id = v_id + 1.0;
  out_texel = vec4(gl_FrontFacing ? id : -id, v_pos);
}
"""
_DEPTH_FRAG = """
void main() {
  float id = v_id + 1.0;
  float dist = ortho > 0.5 ? dot(v_pos - eye, axis) : length(v_pos - eye);
  out_texel = vec2(gl_FrontFacing ? id : -id, dist);
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


# Shaders drawn with once, kept until exit (see below): a shader freed while the process
# draws on let a later shader, made at its address, draw batches with the freed one's vertex
# layout (render_colour read world positions from another column now and then, after the
# provoking-vertex test's shader was freed).
_kept_shaders = []
# The shaders are made once per process and kept. Making and freeing one per renderer let a
# later draw pick up the wrong vertex layout now and then (colours read from the position
# buffer, seen on llvmpipe after other GPU work in the same process).
@functools.cache
def _id_shader(with_bary=True):
    """The id pass: ``(+-(k + 1), x, y, z)`` per texel into RGBA32F (see the module), or with
    ``with_bary=False`` ``(+-(k + 1), distance)`` into RG32F (shadow maps: half the texels'
    bytes to write and read back)."""
    iface = gpu.types.GPUStageInterfaceInfo("cubegi_id_iface" if with_bary else "cubegi_depth_iface")
    iface.flat("FLOAT", "v_id")
    iface.smooth("VEC3", "v_pos")
    info = gpu.types.GPUShaderCreateInfo()
    info.push_constant("MAT4", "view_proj")
    if not with_bary:  # the id pass's distances are worked out after the read-back
        info.push_constant("VEC3", "eye")
        info.push_constant("VEC3", "axis")
        info.push_constant("FLOAT", "ortho")
    info.vertex_in(0, "VEC3", "pos")
    info.vertex_in(1, "FLOAT", "tid")
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


@functools.cache
def _last_vertex_provokes():
    """Whether a flat value comes from a triangle's last vertex (OpenGL's rule) or its first
    (Vulkan's and Metal's): one triangle drawn into one texel tells, once per process."""
    iface = gpu.types.GPUStageInterfaceInfo("cubegi_provoke_iface")
    iface.flat("FLOAT", "v_which")
    info = gpu.types.GPUShaderCreateInfo()
    info.vertex_in(0, "VEC2", "pos")
    info.vertex_in(1, "FLOAT", "which")
    info.vertex_out(iface)
    info.fragment_out(0, "VEC4", "out_texel")
    info.vertex_source("void main() { v_which = which; gl_Position = vec4(pos, 0.0, 1.0); }")
    info.fragment_source("void main() { out_texel = vec4(v_which, 0.0, 0.0, 1.0); }")
    shader = gpu.shader.create_from_info(info)
    batch = batch_for_shader(shader, "TRIS", {"pos": [(-4.0, -4.0), (4.0, -4.0), (0.0, 4.0)], "which": [0.0, 1.0, 2.0]})
    colour = gpu.types.GPUTexture((1, 1), format="RGBA32F")
    fb = gpu.types.GPUFrameBuffer(color_slots=(colour,))
    with fb.bind():
        fb.clear(color=(-1.0, 0.0, 0.0, 0.0))
        gpu.state.face_culling_set("NONE")
        gpu.state.viewport_set(0, 0, 1, 1)
        batch.draw(shader)
    which = float(read_texture(colour, 1, 1)[0, 0, 0])
    del fb, colour
    _kept_shaders.append(shader)  # see _kept_shaders
    if which not in (0.0, 2.0):
        raise BakeError(f"this GPU takes a triangle's flat values from its vertex {which:g}, not its first or last")
    return which == 2.0


def _free_shaders():
    """Free the kept shaders while the GPU context still exists (at exit, before bpy's own
    exit handler, which runs later because it was registered earlier)."""
    _id_shader.cache_clear()
    _colour_shader.cache_clear()
    _kept_shaders.clear()


atexit.register(_free_shaders)


def _column_major(matrices):
    """Each of ``matrices (v, 4, 4)`` as the 16 floats of a mat4 push constant (GLSL reads
    it column by column)."""
    return np.asarray(matrices, dtype=np.float64).transpose(0, 2, 1).reshape(-1, 16).tolist()


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
        run(self._uploaded(prepare(points, triangles, drawn, sheet, _last_vertex_provokes())))

    @classmethod
    def steps(cls, points, triangles, working, sheet=None):
        """The renderer, made in steps: its arrays in a thread, then each vertex column
        uploaded in a step of its own (a generator yielding ``working``, a Progress)."""
        ensure_gpu()
        prepared = yield from in_background(prepare, working, points, triangles, None, sheet, _last_vertex_provokes())
        renderer = cls.__new__(cls)
        yield from renderer._uploaded(prepared, working)
        return renderer

    def _uploaded(self, prepared, working=None):
        # The vertex columns and indices, kept only until uploaded (the GPU keeps its own copy).
        columns = {name: prepared.pop(name) for name in ("pos", "tid")}
        indices = prepared.pop("indices")
        self.__dict__.update(prepared)
        self.id_shader = _id_shader()
        self.id_batch = yield from _batch_steps(self.id_shader, columns, working, indices)
        self._colour_shader = None

    @staticmethod
    def rays(points, triangles):
        """A ray caster over ``triangles (k, 3)`` of ``points`` (the engine's
        :class:`~cubegi_engine.rays.RayCaster`): the GPU module's compute shader
        (:class:`~.gpu_rays.GpuRays`, Blender's BVH tree where that cannot run), or Blender's
        BVH tree alone where GPU_RAYS is off. Static: what holds it holds no renderer."""
        return GpuRays(points, triangles) if GPU_RAYS else BvhRays(points, triangles)

    def with_geometry(self, points, triangles, drawn=None, sheet=None):
        """A renderer of other triangles (the probes' simplified copy of the scene), drawing
        those ``drawn`` (indices; all by default); ``sheet``: as for the constructor."""
        return GpuRenderer(points, triangles, drawn, sheet)

    def _local(self, view_projs):
        """World view-projections ``(v, 4, 4)`` as ones for unit-frame positions, each scaled
        to entries <= 1 (a uniform scale of a projective matrix does not change what it
        draws)."""
        to_world = np.diag([self.unit, self.unit, self.unit, 1.0])
        to_world[:3, 3] = self.centre
        m = np.asarray(view_projs, dtype=np.float64).reshape(-1, 4, 4) @ to_world
        return m / np.abs(m).max(axis=(1, 2), keepdims=True)

    def _ranges(self, local_vps):
        """Per view, the ``(first index, count)`` runs of chunks it may see (see CULL_CHUNK;
        every chunk where the scene is small); a run never spans the start of the
        one-sided triangles (see :meth:`_draw`)."""
        starts, ends = self.chunk_starts, self.chunk_ends
        if self.chunk_boxes is None:
            return [[(3 * int(a), 3 * int(b - a)) for a, b in zip(starts, ends)]] * len(local_vps)
        seen = boxes_in_frusta(self.chunk_boxes, local_vps)  # (v, c)
        opens = np.isin(starts, (0, self.lone_from))  # a chunk that starts a part
        out = []
        for row in seen:
            begin = np.flatnonzero(row & (opens | ~np.concatenate([[False], row[:-1]])))
            end = np.flatnonzero(row & (np.append(opens[1:], True) | ~np.append(row[1:], False)))
            out.append([(3 * int(starts[a]), 3 * int(ends[b] - starts[a])) for a, b in zip(begin, end)])
        return out

    def _draw(self, batch, shader, ranges, k):
        """Draw view ``k``'s share of ``batch`` (all of it where ``ranges`` is None: a batch
        of its own). The id batch's triangles of a sheet with no twin (the last part) are
        drawn with back faces culled."""
        if ranges is None:
            batch.draw(shader)
            return
        culled = False
        for first, count in ranges[k]:
            if (first >= 3 * self.lone_from) != culled:
                culled = not culled
                gpu.state.face_culling_set("BACK" if culled else "NONE")
            batch.draw_range(shader, elem_start=int(first), elem_count=int(count))
        if culled:
            gpu.state.face_culling_set("NONE")

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
        local = self._local(view_projs)
        ranges, columns = self._ranges(local), _column_major(local)
        shader.bind()

        local_eyes = (np.asarray(eyes, dtype=np.float64).reshape(-1, 3) - self.centre) / self.unit
        axes = None if axes is None else np.asarray(axes, dtype=np.float64).reshape(-1, 3)

        def draw_one(k):
            shader.uniform_float("view_proj", columns[k])
            if not with_bary:
                shader.uniform_float("eye", tuple(float(x) for x in local_eyes[k]))
                shader.uniform_float("axis", (0.0, 0.0, 1.0) if axes is None else tuple(float(x) for x in axes[k]))
                shader.uniform_float("ortho", 0.0 if axes is None else 1.0)
            self._draw(batch, shader, ranges, k)

        texels = size * size
        for first, tiles in self._draw_views(view_projs, size, draw_one, 4 if with_bary else 2):
            sl = slice(first, first + len(tiles))
            self._triangles_seen(tiles[..., 0], tid[sl], back[sl])
            d = dist[sl]
            if with_bary:
                hit = np.flatnonzero(tid[sl] >= 0)  # (flat: one index array, not three)
                pos = tiles.reshape(-1, 4)[hit, 1:4].astype(np.float64)
                views = first + hit // texels
                rel = pos - local_eyes[views]
                along = np.sqrt(np.einsum("kc,kc->k", rel, rel)) if axes is None else np.einsum("kc,kc->k", rel, axes[views])
                d.fill(np.inf)  # nothing drawn: no distance
                d.reshape(-1)[hit] = along * self.unit
                bary[sl].reshape(-1, 3)[hit] = self._barycentric(tid[sl].reshape(-1)[hit], pos)
            else:
                with np.errstate(over="ignore"):
                    np.multiply(tiles[..., -1], np.float32(self.unit), out=d)
                d[tid[sl] < 0] = np.inf  # nothing drawn: the clear value, not a distance
        return tid, bary, dist, back

    @functools.cached_property
    def _seen_table(self):
        """``(drawn + 1,)`` int32: the triangle drawn as number ``k`` at ``k + 1``, -1 at 0
        (nothing drawn)."""
        return np.concatenate([[-1], self.order]).astype(np.int32)

    def _barycentric(self, seen, at):
        """The weights of the triangles ``seen (k,)`` at the points ``at (k, 3)``: each
        triangle's rows made once for the batch (none kept: a renderer of a whole scene lives
        on for its shadow maps)."""
        mark = np.zeros(len(self.triangles), dtype=bool)
        mark[seen] = True
        place = np.cumsum(mark, dtype=np.int64) - 1
        return barycentric(barycentric_rows(self.unit_points, self.triangles[mark]), place[seen], at)

    def _triangles_seen(self, code, tid, back):
        """From the texels' codes ``+-(k + 1)`` (k: the drawn triangle's number, 0: none),
        into ``tid`` and ``back``: the triangle each texel sees (-1: none) and whether from
        behind. A sheet's triangle seen from behind is its twin, seen from the front."""
        np.less(code, 0.0, out=back)
        np.take(self._seen_table, np.abs(code).astype(np.int32), out=tid)  # exact small integers in float32
        flat_tid, flat_back = tid.reshape(-1), back.reshape(-1)
        behind = np.flatnonzero(flat_back)  # (a texel seeing nothing has code 0: never behind)
        twin = self.twin[flat_tid[behind]]
        turned = behind[twin >= 0]
        flat_tid[turned] = twin[twin >= 0]
        flat_back[turned] = False

    def render_colour(self, view_projs, size, point_radiance):
        if self._colour_shader is None:
            self._colour_shader = _colour_shader()
        shader = self._colour_shader
        corners = self.triangles[self.all_drawn]  # every triangle, both twins of a sheet
        colour = np.asarray(point_radiance, dtype=np.float32)[corners].reshape(-1, 3)
        batch = batch_for_shader(shader, "TRIS", {"pos": self.unit_points[corners].reshape(-1, 3), "colour": colour,
                                                  "sheet": np.repeat(self.sheet_all[self.all_drawn].astype(np.float32), 3)})
        out = np.empty((len(view_projs), size, size, 3), dtype=np.float32)
        columns = _column_major(self._local(view_projs))
        ranges = None  # every triangle, both twins of a sheet (a check in the tests, not a bake's path)
        shader.bind()

        def draw_one(k):
            shader.uniform_float("view_proj", columns[k])
            self._draw(batch, shader, ranges, k)

        for first, tiles in self._draw_views(view_projs, size, draw_one):
            # Where nothing is drawn the clear colour's alpha (FAR_AWAY) marks sky: black.
            rgb = np.where(tiles[..., 3:4] == FAR_AWAY, 0.0, tiles[..., :3])
            out[first : first + len(tiles)] = rgb
        return out


def _batch_steps(shader, columns, working=None, indices=None):
    """``batch_for_shader(shader, "TRIS", columns, indices=indices)`` (its vertex format),
    filling one column at a time and yielding ``working`` between them (none if it is None)."""
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
    if indices is None:
        return gpu.types.GPUBatch(type="TRIS", buf=vbo)
    if working is not None:
        yield working
    return gpu.types.GPUBatch(type="TRIS", buf=vbo, elem=gpu.types.GPUIndexBuf(type="TRIS", seq=indices))
