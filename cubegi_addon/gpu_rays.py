"""Rays against a scene's triangles in a compute shader of the GPU module: the add-on's
:class:`~cubegi_engine.rays.RayCaster` where the GPU module runs compute shaders.

The engine's :mod:`~cubegi_engine.boxtree` (a tree of boxes, flat) and each batch of rays go
to the GPU as float images, and one invocation walks the tree for each ray. Images, not
storage buffers: bpy 4.5 and 5.0 have no storage buffers in Python, and the images' loads
(``imageLoad``) gave the same answers on every supported version (a sampler's
``texelFetch`` read wrong texels in a compute shader on bpy 5.3).

Blender's BVH tree (:class:`~.bvh_rays.BvhRays`) casts one ray per Python call and holds
the GIL for a whole batch; here a batch is one dispatch, on the GPU, or on llvmpipe's
threads where there is none. The GPU context is the main thread's: a bake's threads hand
their batches to it (:func:`~cubegi_engine.working.on_main`), which runs them while it
waits for their work or between batches of its own (the probes' drawing). Where it takes
none within its time (a thread of one's own), that
call's rays go through Blender's BVH tree; where the GPU module cannot run the shader, every
call's do.

The uploaded images stay with the GPU, keyed by caster, and are freed on the main thread
(at its next batch after the caster is gone, or at exit): a GPU texture freed in another
thread has no context to be freed in.
"""

import atexit
import functools
import itertools
import threading
import weakref

import gpu
import numpy as np

from ..cubegi_engine import boxtree, working
from ..cubegi_engine.geometry import corner_triangles
from ..cubegi_engine.rays import Hits, hits_from_distances, near_hits_again
from . import compat
from .bvh_rays import BvhRays

# Texels a row of every image holds (a power of two; the tree's rows stay under the GPU's
# largest texture).
ROW = 4096
# Rays a dispatch takes (its images: 8 MiB in, 2 MiB out; a GPU that takes seconds over one
# dispatch may be stopped by its driver).
RAYS_PER_DISPATCH = 1 << 18
# Invocations per work group.
GROUP = 64

_SHADER = """
vec4 tree_at(int k) { return imageLoad(tree, ivec2(k % ROW, k / ROW)); }

void main() {
  int i = int(gl_GlobalInvocationID.x);
  if (i >= ray_count) { return; }
  vec4 o4 = imageLoad(rays_in, ivec2((2 * i) % ROW, (2 * i) / ROW));
  vec3 o = o4.xyz;
  vec3 d = imageLoad(rays_in, ivec2((2 * i + 1) % ROW, (2 * i + 1) / ROW)).xyz;
  vec3 inv = 1.0 / d;
  int best = -1;  /* the caller's index of the nearest triangle met (ties: the lowest) */
  float best_t = o4.w;
  int node = 0;
  while (node < node_count) {
    vec4 low = tree_at(2 * node);  /* w: an inner node's skip, a leaf's first slot */
    vec4 high = tree_at(2 * node + 1);  /* w: a leaf's triangle count (0: an inner node) */
    vec3 t0 = (low.xyz - o) * inv;
    vec3 t1 = (high.xyz - o) * inv;
    vec3 tn = min(t0, t1);
    vec3 tf = max(t0, t1);
    float enter = max(max(tn.x, tn.y), max(tn.z, 0.0));
    float leave = min(min(tf.x, tf.y), min(tf.z, best_t));
    int count = int(high.w);
    if (enter <= leave && count == 0) {
      node += 1;
      continue;
    }
    if (enter <= leave) {
      int first = int(low.w);
      for (int k = first; k < first + count; k++) {
        int c = corner_base + 3 * k;
        vec4 a4 = tree_at(c);  /* w: the caller's index of the triangle */
        vec3 a = a4.xyz;
        vec3 e1 = tree_at(c + 1).xyz;
        vec3 e2 = tree_at(c + 2).xyz;
        vec3 p = cross(d, e2);
        float det = dot(e1, p);
        if (abs(det) < 1e-30) { continue; }
        vec3 s = o - a;
        float u = dot(s, p) / det;
        vec3 q = cross(s, e1);
        float v = dot(d, q) / det;
        float t = dot(e2, q) / det;
        int index = int(a4.w);
        if (u >= -edge && v >= -edge && u + v <= 1.0 + edge && t > 0.0 && (t < best_t || (t == best_t && (best < 0 || index < best)))) {
          best = index;
          best_t = t;
        }
      }
      if (any_hit != 0 && best >= 0) { break; }
    }
    node = count == 0 ? int(low.w) : node + 1;
  }
  imageStore(hits_out, ivec2(i % ROW, i / ROW), vec4(float(best + 1), best_t, 0.0, 0.0));
}
"""


@functools.cache
def _shader():
    """The tree walk's compute shader, made once per process and kept (see
    :data:`.gpu_capture._kept_shaders`); None where the GPU module cannot make it."""
    try:
        info = gpu.types.GPUShaderCreateInfo()
        info.local_group_size(GROUP, 1, 1)
        info.image(0, "RGBA32F", "FLOAT_2D", "tree", qualifiers={"READ"})
        info.image(1, "RGBA32F", "FLOAT_2D", "rays_in", qualifiers={"READ"})
        info.image(2, "RG32F", "FLOAT_2D", "hits_out", qualifiers={"WRITE"})
        for name in ("ray_count", "node_count", "corner_base", "any_hit"):
            info.push_constant("INT", name)
        info.push_constant("FLOAT", "edge")
        info.define("ROW", str(ROW))
        info.compute_source(_SHADER)
        return gpu.shader.create_from_info(info)
    except Exception:  # no compute shaders, or a compiler that refuses it: Blender's tree does the work
        return None


def _padded(count):
    """``(k, 4)`` float32 zeros, ``k`` the least whole number of rows of ROW texels that hold
    ``count`` (at least one row)."""
    return np.zeros((max(1, -(-count // ROW)) * ROW, 4), dtype=np.float32)


def _image(full):
    """An RGBA32F texture of ``full`` (``_padded``'s texels), ROW to a row."""
    rows = len(full) // ROW
    return gpu.types.GPUTexture((ROW, rows), format="RGBA32F", data=gpu.types.Buffer("FLOAT", full.size, full.ravel()))


# Each caster's uploaded tree (key -> GPUTexture), and the keys of casters that are gone.
_resident: dict = {}
_gone: set = set()
_gone_lock = threading.Lock()
_keys = itertools.count()


def _forget(key):
    with _gone_lock:
        _gone.add(key)


def _free_gone():
    """Free the trees of casters that are gone (on the main thread, which owns the GPU)."""
    with _gone_lock:
        gone = list(_gone)
        _gone.clear()
    for key in gone:
        _resident.pop(key, None)


def _free_all():
    """Free the trees and the shader while the GPU context still exists (at exit, before
    bpy's own exit handler, which runs later because it was registered earlier)."""
    _resident.clear()
    _shader.cache_clear()


atexit.register(_free_all)


class GpuRays:
    """Each ray's nearest hit among ``triangles (k, 3)`` over ``points (s, 3)``, by a compute
    shader (both sides of a triangle are met; :class:`~cubegi_engine.rays.Hits` says which).
    Made in any thread (the tree is numpy's); its rays are cast on the main thread."""

    def __init__(self, points, triangles):
        self.points = np.asarray(points, dtype=np.float64)
        self.triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        self.tree = boxtree.build(self.points, self.triangles)
        self._key = next(_keys)
        weakref.finalize(self, _forget, self._key)
        self._fallback = None  # Blender's tree over the same triangles, made where it first answers
        self._unusable = False  # the shader cannot run, or the tree is over the GPU's largest image
        self._lock = threading.Lock()

    @property
    def nbytes(self) -> int:
        """Memory held: its triangles and the tree, here and again on the GPU, and the
        triangles at each point and Blender's tree, once made."""
        extra = sum(a.nbytes for a in self.__dict__.get("_corners", ())) + (self._fallback.nbytes if self._fallback is not None else 0)
        return int(self.triangles.nbytes + 2 * self.tree.nbytes + extra)

    def cast(self, origins, dirs, reach=None) -> Hits:
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        which, t = self._walk(origins, dirs, reach, any_hit=False)
        if which is None:
            return self._by_tree().cast(origins, dirs, reach)
        which, t = near_hits_again(self.points, self.triangles, self._corners, self.tree.scale, origins, dirs, reach, which, t)
        return hits_from_distances(self.points, self.triangles, origins, dirs, t, which)

    @working.once
    def _corners(self):
        """The triangles at each point (:func:`~cubegi_engine.rays.near_hits_again`), made when
        first asked."""
        return corner_triangles(self.triangles, len(self.points))

    def blocked(self, origins, dirs, reach=None) -> np.ndarray:
        """``(n,)`` bool: whether each ray meets a triangle within its reach (a shadow ray:
        the first hit found ends its walk)."""
        which, _ = self._walk(origins, dirs, reach, any_hit=True)
        return which >= 0 if which is not None else self._by_tree().blocked(origins, dirs, reach)

    def _by_tree(self):
        """Blender's BVH tree over the same triangles (where the shader cannot be used)."""
        with self._lock:
            if self._fallback is None:
                self._fallback = BvhRays(self.points, self.triangles)
        return self._fallback

    def _walk(self, origins, dirs, reach, any_hit):
        """``(which (n,), t (n,))`` as :func:`~cubegi_engine.boxtree.walk`, by the shader a
        dispatch at a time; ``(None, None)`` where the shader cannot be used."""
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        n = len(origins)
        if self._unusable or not len(self.triangles):
            return (None, None) if self._unusable else (np.full(n, -1), np.full(n, np.inf))
        rays = np.empty((n, 2, 4), dtype=np.float32)
        rays[:, 0, :3] = origins - self.tree.centre
        rays[:, 0, 3] = boxtree.FAR if reach is None else np.broadcast_to(np.asarray(reach, dtype=np.float64), (n,))
        rays[:, 1, :3] = np.where(np.abs(dirs) < 1e-30, 1e-30, dirs)  # (a zero component's inverse: no NaN)
        rays[:, 1, 3] = 0.0
        # A ray of no direction, or from or along NaN, meets nothing (as in Blender's tree).
        rays[~(np.isfinite(origins).all(axis=1) & np.isfinite(dirs).all(axis=1) & np.any(dirs != 0.0, axis=1)), 0, 3] = -1.0
        which, t = np.empty(n, dtype=np.int64), np.empty(n)
        for at in range(0, n, RAYS_PER_DISPATCH):
            working.checkpoint()  # (a cancelled bake's rays stop here)
            part = slice(at, at + RAYS_PER_DISPATCH)
            try:
                found = working.on_main(self._dispatch, rays[part], any_hit)
            except working.NotServed:  # (this call's rays alone: the next asks the main thread again)
                return None, None
            if found is None:
                self._unusable = True
                return None, None
            which[part], t[part] = found
        return which, t

    def _dispatch(self, rays, any_hit):
        """One batch of ``rays (n, 2, 4)`` (origin and reach, direction) through the shader,
        on the main thread: ``(which (n,), t (n,))``, or None where it cannot run."""
        shader = _shader()
        if shader is None:
            return None
        _free_gone()
        tree = self.tree
        image = _resident.get(self._key)
        m = len(tree.skip)
        if image is None:
            count = 2 * m + 3 * len(tree.corners)
            if -(-count // ROW) > gpu.capabilities.max_texture_size_get() or max(m, len(tree.corners)) >= boxtree.LARGEST:
                return None  # larger than the GPU's largest image: Blender's tree takes it
            texels = _padded(count)
            nodes = texels[: 2 * m].reshape(m, 2, 4)
            nodes[:, :, :3] = tree.boxes
            nodes[:, 0, 3] = np.where(tree.count > 0, tree.first, tree.skip)
            nodes[:, 1, 3] = tree.count
            corners = texels[2 * m:count].reshape(-1, 3, 4)
            corners[:, :, :3] = tree.corners
            corners[:, 0, 3] = tree.order
            image = _resident[self._key] = _image(texels)
        n = len(rays)
        texels = _padded(2 * n)
        texels[: 2 * n] = rays.reshape(-1, 4)
        rays_in = _image(texels)
        rows = max(1, -(-n // ROW))
        hits_out = gpu.types.GPUTexture((ROW, rows), format="RG32F")
        shader.bind()
        shader.uniform_int("ray_count", n)
        shader.uniform_int("node_count", m)
        shader.uniform_int("corner_base", 2 * m)
        shader.uniform_int("any_hit", int(any_hit))
        shader.uniform_float("edge", boxtree.EDGE_SLACK)
        shader.image("tree", image)
        shader.image("rays_in", rays_in)
        shader.image("hits_out", hits_out)
        gpu.compute.dispatch(shader, -(-n // GROUP), 1, 1)
        out = compat.gpu_buffer_array(hits_out.read(), (rows * ROW, 2))[:n]
        which = out[:, 0].astype(np.int64) - 1
        return which, np.where(which >= 0, out[:, 1].astype(np.float64), np.inf)
