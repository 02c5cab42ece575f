"""Rays against a scene's triangles through Blender's BVH tree (``mathutils.bvhtree``): the
add-on's :class:`~cubegi_engine.rays.RayCaster`."""

import numpy as np
from mathutils.bvhtree import BVHTree

from ..cubegi_engine import working
from ..cubegi_engine.geometry import corner_triangles
from ..cubegi_engine.rays import Hits, hits_from_distances, near_hits_again

# Resident memory of Blender's BVH tree per triangle (measured: about 160 MB for a million).
TREE_BYTES = 160
# Shadow rays cast at a time: each answer is a tuple of Python objects (about 3 KB a ray
# held until read: seven million rays at once took 24 GB).
RAYS_AT_ONCE = 65_536


class BvhRays:
    """Each ray's nearest hit among ``triangles (k, 3)`` over ``points (s, 3)`` (both sides of
    a triangle are met; :class:`~cubegi_engine.rays.Hits` says which).

    The tree works in float32: it holds the points less the centre of their box, and rays
    start less it too, so a scene a kilometre from the origin keeps the precision of one at
    it (a ray lifted a millionth of the scene's size off its surface, there, met that surface
    again 987 times in 1024)."""

    def __init__(self, points, triangles):
        self.points = np.asarray(points, dtype=np.float64)
        self.triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        # The tree holds only the points its triangles use (marked, not sorted: a million
        # vertices' np.unique took most of a second).
        used = np.flatnonzero(np.bincount(self.triangles.ravel(), minlength=len(self.points)))
        renumber = np.zeros(len(self.points), dtype=np.int64)
        renumber[used] = np.arange(len(used))
        local = renumber[self.triangles]
        kept = self.points[used]
        self.centre = 0.5 * (kept.min(axis=0) + kept.max(axis=0)) if len(kept) else np.zeros(3)
        self.scale = float(np.max(kept.max(axis=0) - kept.min(axis=0))) if len(kept) else 0.0
        self.tree = BVHTree.FromPolygons((kept - self.centre).tolist(), local.tolist(), all_triangles=True)

    @property
    def nbytes(self) -> int:
        """Memory held: its triangles, the tree (about TREE_BYTES a triangle, measured) and the
        triangles at each point, once made."""
        return int(self.triangles.nbytes + TREE_BYTES * len(self.triangles) + sum(a.nbytes for a in self.__dict__.get("_corners", ())))

    def cast(self, origins, dirs, reach=None) -> Hits:
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        n = len(origins)
        local = origins - self.centre
        t = np.full(n, np.inf)
        which = np.full(n, -1, dtype=np.int64)
        for k, (_, _, index, distance) in enumerate(self._found(local, dirs, reach)):
            if index is not None:
                t[k], which[k] = distance, index
        # (a float32 tree: its near hits taken again in float64, as the GPU's are)
        which, t = near_hits_again(self.points, self.triangles, self._corners, self.scale, origins, dirs, reach, which, t)
        return hits_from_distances(self.points, self.triangles, origins, dirs, t, which)

    @working.once
    def _corners(self):
        """The triangles at each point (:func:`~cubegi_engine.rays.near_hits_again`), made when
        first asked."""
        return corner_triangles(self.triangles, len(self.points))

    def blocked(self, origins, dirs, reach=None) -> np.ndarray:
        """``(n,)`` bool: whether each ray meets a triangle within its reach (a shadow ray:
        no more asked of the hit)."""
        local = np.asarray(origins, dtype=np.float64).reshape(-1, 3) - self.centre
        dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        reach = None if reach is None else np.broadcast_to(np.asarray(reach, dtype=np.float64), (len(local),))
        out = np.empty(len(local), dtype=bool)
        for at in range(0, len(local), RAYS_AT_ONCE):  # the tree's answers are Python objects: a few at a time
            working.checkpoint()  # (a cancelled bake's rays stop here)
            part = slice(at, at + RAYS_AT_ONCE)
            found = self._found(local[part], dirs[part], None if reach is None else reach[part])
            out[part] = np.fromiter((f[2] is not None for f in found), dtype=bool, count=len(found))
        return out

    def _found(self, local, dirs, reach):
        """The tree's answers for rays from ``local`` (tree frame) along ``dirs``."""
        cast = self.tree.ray_cast
        if reach is None:
            return list(map(cast, local.tolist(), dirs.tolist()))
        limit = np.broadcast_to(np.asarray(reach, dtype=np.float64), (len(local),)).tolist()
        return list(map(cast, local.tolist(), dirs.tolist(), limit))
