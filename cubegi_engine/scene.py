"""The scene as CubeGI sees it (a snapshot of arrays), and a fingerprint of its geometry.

Pure numpy; must not import bpy. The add-on's ``scene_data.collect`` makes a
:class:`SceneArrays` from Blender's evaluated scene; everything after it works on arrays.

The :class:`GeometryFingerprint` says whether two snapshots have the same geometry (the
capture of one is then valid for the other) and, if not, which objects changed.
Materials, lights and the world are not part of it: a capture stays valid across them.
"""

import hashlib
from dataclasses import dataclass, field

import numpy as np

__all__ = ["SceneArrays", "GeometryFingerprint", "Sheets", "same_sky_map"]


@dataclass(frozen=True)
class GeometryFingerprint:
    """Per object (in ``SceneArrays.point_object`` order): its name and a digest of its
    points, normals and triangles."""

    objects: tuple  # ((name, digest hex), ...)
    # ((name, point count, digest of the triangles), ...): the layout of the arrays; equal
    # layouts index every point and triangle alike, so captures can be patched in place.
    layout: tuple = ()

    def changed(self, other: "GeometryFingerprint") -> set:
        """Names of the objects added, removed or changed between ``other`` and this one."""
        mine, theirs = dict(self.objects), dict(other.objects)
        return {n for n in mine.keys() | theirs.keys() if mine.get(n) != theirs.get(n)}

    def same_geometry(self, other: "GeometryFingerprint") -> bool:
        """True if the objects' geometry is alike, object for object in the same order,
        whatever their names (a renamed object is the same geometry)."""
        return [d for _, d in self.objects] == [d for _, d in other.objects]

    def same_layout(self, other: "GeometryFingerprint") -> bool:
        """True if only positions and normals differ (objects, order, counts, triangles alike)."""
        return self.layout == other.layout


@dataclass
class SceneArrays:
    """The scene as CubeGI sees it: shading points, triangles over them, lights and sky.

    points, normals: ``(s, 3)`` float64 world space, normals unit; albedo: ``(s, 3)``
    diffuse colour in [0, 1] (what a point's baked light is lit by: its colour in a render);
    reflectance: ``(s, 3)`` what a point sends on of the light reaching it, where that is more
    than its albedo (a Principled BSDF's specular layer, :mod:`cubegi_engine.specular`), or
    None (its albedo: :meth:`sent_on`); emission: ``(s, 3)`` emitted radiance; triangles: ``(t, 3)``
    int64 point indices; sky: ``(3,)`` radiance of the world background (its mean over the
    sphere); sky_map: None for a uniform sky, or its pattern: an equirectangular image ``(h,
    w, 3)`` (Cycles' mapping, :func:`cubegi_engine.cubemap.equirect_uv`) of the radiance
    over ``sky``, mean 1 over the sphere per channel; lights: list of
    :class:`cubegi_engine.lights.Light`.
    """

    points: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    triangles: np.ndarray
    sky: np.ndarray = field(default_factory=lambda: np.zeros(3))
    lights: list = field(default_factory=list)
    point_object: np.ndarray | None = None  # (s,) int: which object each point belongs to
    dark: np.ndarray | None = None  # (s,) bool: points that get no light (bad input set aside)
    object_names: list = field(default_factory=list)  # per point_object index
    sky_map: np.ndarray | None = None  # see above
    # (s,) bool: the back side of a sheet (an open mesh): points that twin the object's own,
    # facing the other way, and the triangles over them (wound the other way). They get and
    # pass on light like any point, and are not written. None: every surface one-sided.
    back: np.ndarray | None = None
    # (s,) bool: points that stand for a large share of the surface, whose light is gathered
    # by rays at the point itself (:mod:`cubegi_engine.gather`); None: none.
    gathered: np.ndarray | None = None
    # (objects,) int: per object, the front triangles that cutting long ones for the bake
    # added (:mod:`cubegi_engine.refine`): the probes' triangle budget is of the scene as
    # modelled (:func:`cubegi_engine.proxy.simplify`). None: none added.
    sampled_triangles: np.ndarray | None = None
    reflectance: np.ndarray | None = None  # see above
    # (e, 3) int: the emissive triangles as modelled that the bake cut into smaller ones to
    # sample the light they reflect (:func:`cubegi_engine.refine.refine_near_emitters`), by point
    # indices, and (t,) bool: which of ``triangles`` are their pieces. Their light is that of
    # the triangles as modelled (:func:`cubegi_engine.emitters.emissive_triangles`). None: none cut.
    emitting: np.ndarray | None = None
    emitter_pieces: np.ndarray | None = None
    # The fingerprint of the arrays before the cuts by emitters (:func:`cubegi_engine.refine.
    # refine_near_emitters`), or None: an edit that makes a surface close in front of another
    # start or stop emitting changes the cuts (the fingerprint), not this.
    cut_from: object = None

    def sent_on(self) -> np.ndarray:
        """``(s, 3)``: what each point sends on of the light reaching it (:attr:`reflectance`,
        else the albedo), zero at the dark points."""
        out = self.albedo if self.reflectance is None else self.reflectance
        return np.where(self.dark[:, None], 0.0, out) if self.dark is not None else out

    def zero_dark_points_inplace(self, light: np.ndarray) -> np.ndarray:
        """``light (s, 3)`` with the dark points' rows set to zero, in place; returned."""
        if self.dark is not None:
            light[self.dark] = 0.0
        return light

    def bounds(self) -> tuple:
        """``(lo (3,), hi (3,))`` of the points; made once per snapshot."""
        cached = self.__dict__.get("_bounds")
        if cached is None or cached[0] != id(self.points):
            cached = (id(self.points), (self.points.min(axis=0), self.points.max(axis=0)))
            self.__dict__["_bounds"] = cached
        lo, hi = cached[1]
        return lo.copy(), hi.copy()

    @property
    def scale(self) -> float:
        """The length of the scene's bounding-box diagonal (at least a tiny positive number)."""
        lo, hi = self.bounds()
        return max(float(np.linalg.norm(hi - lo)), 1e-30)

    def triangle_areas(self) -> np.ndarray:
        return triangle_areas(self.points, self.triangles)

    def triangle_object(self) -> np.ndarray:
        """Which object each triangle belongs to (its first corner's), ``(t,)`` int64; all 0
        without objects."""
        if self.point_object is None or not len(self.triangles):
            return np.zeros(len(self.triangles), dtype=np.int64)
        return np.asarray(self.point_object, dtype=np.int64)[self.triangles[:, 0]]

    def sheets(self) -> "Sheets | None":
        """The scene's two-sided objects (see :attr:`back`), or None where there are none;
        made once per snapshot."""
        if self.back is None or not self.back.any():
            return None
        key = (id(self.back), id(self.triangles), id(self.point_object))
        cached = self.__dict__.get("_sheets")
        if cached is None or cached[0] != key:
            cached = (key, Sheets(np.asarray(self.back, dtype=bool), np.asarray(self.point_object, dtype=np.int64), self.triangles))
            self.__dict__["_sheets"] = cached
        return cached[1]

    def sides(self):
        """``(triangle side (t,), point side (s,))`` int8 (0: one-sided, 1: a sheet's front,
        2: its back) for the shadow tests (``lights.shadow_visibility``), or None."""
        sheets = self.sheets()
        return None if sheets is None else sheets.sides

    def sheet_triangles(self) -> np.ndarray | None:
        """``(t,)`` bool: the triangles of two-sided objects (both twins), whose back faces are
        not drawn (the twin stands there); None where there are none."""
        sheets = self.sheets()
        return None if sheets is None else sheets.triangles

    def twins(self) -> np.ndarray | None:
        """``(s,)``: each point's twin on the other side of its sheet (-1: none); None
        without sheets."""
        sheets = self.sheets()
        return None if sheets is None else sheets.twins

    def back_triangles(self) -> np.ndarray:
        """``(t,)`` bool: the twins over the back side (all False without sheets)."""
        if self.back is None:
            return np.zeros(len(self.triangles), dtype=bool)
        return self.back[self.triangles[:, 0]]

    def point_areas(self) -> np.ndarray:
        """Each point's share of the surface: a third of its triangles' areas, ``(s,)``; made
        once per snapshot (read-only)."""
        key = (id(self.points), id(self.triangles))
        cached = self.__dict__.get("_point_areas")
        if cached is None or cached[0] != key:
            areas = np.bincount(self.triangles.ravel(), np.repeat(self.triangle_areas() / 3.0, 3), minlength=len(self.points))
            areas.flags.writeable = False
            cached = (key, areas)
            self.__dict__["_point_areas"] = cached
        return cached[1]

    def fingerprint(self) -> GeometryFingerprint:
        """The geometry's fingerprint (see :class:`GeometryFingerprint`), made once per
        snapshot (the geometry of a snapshot does not change after it is collected)."""
        cached = self.__dict__.get("_fingerprint")
        if cached is not None and cached[0] == (id(self.points), id(self.normals), id(self.triangles)):
            return cached[1]
        made = self._fingerprint()
        self.__dict__["_fingerprint"] = ((id(self.points), id(self.normals), id(self.triangles)), made)
        return made

    def _fingerprint(self) -> GeometryFingerprint:
        owner = self.point_object if self.point_object is not None else np.zeros(len(self.points), dtype=np.int64)
        count = int(owner.max()) + 1 if len(owner) else 0
        names = list(self.object_names) or [f"object {k}" for k in range(count)]
        tri_owner = owner[self.triangles[:, 0]] if len(self.triangles) else np.zeros(0, dtype=np.int64)
        # Each object's points and triangles, in order: one stable sort each (a mask per
        # object took 1.2 s for 53 objects at 1.2M points).
        (points, normals), at, first = _by_owner(owner, count, self.points, self.normals)
        (triangles,), tri_at, _ = _by_owner(tri_owner, count, self.triangles)
        out, layout = [], []
        for k in range(count):
            h, t = hashlib.blake2b(digest_size=16), hashlib.blake2b(digest_size=16)
            h.update(np.ascontiguousarray(points[at[k] : at[k + 1]]).tobytes())
            h.update(np.ascontiguousarray(normals[at[k] : at[k + 1]]).tobytes())
            t.update(np.ascontiguousarray(triangles[tri_at[k] : tri_at[k + 1]] - int(first[k])).tobytes())
            h.update(t.digest())
            out.append((names[k], h.hexdigest()))
            layout.append((names[k], int(at[k + 1] - at[k]), t.hexdigest()))
        return GeometryFingerprint(tuple(out), tuple(layout))


def _by_owner(owner, count, *arrays):
    """``(arrays' rows grouped by owner, each group in its order; bounds (count + 1,) of each
    owner's rows; the first row of each owner in the given order, 0 for none)``."""
    if len(owner) and np.any(owner[1:] < owner[:-1]):
        order = np.argsort(owner, kind="stable")
        owner, arrays = owner[order], tuple(a[order] for a in arrays)
    else:
        order = np.arange(len(owner))
    bounds = np.searchsorted(owner, np.arange(count + 1))
    first = np.zeros(count, dtype=np.int64)
    some = bounds[1:] > bounds[:-1]
    first[some] = order[bounds[:-1][some]]  # (a stable sort puts each owner's first row first)
    return arrays, bounds, first


def triangle_areas(points, triangles) -> np.ndarray:
    """``(t,)`` the area of each triangle ``(t, 3)`` of ``points (s, 3)`` (the cross product
    written out over the coordinates' columns: ``np.cross`` is five times slower on millions
    of rows, and the rows' strided columns twice)."""
    x, y, z = np.ascontiguousarray(np.asarray(points, dtype=np.float64).T)
    corners = [triangles[:, k] for k in range(3)]
    x0, y0, z0 = x[corners[0]], y[corners[0]], z[corners[0]]
    x1, y1, z1 = x[corners[1]] - x0, y[corners[1]] - y0, z[corners[1]] - z0
    x2, y2, z2 = x[corners[2]] - x0, y[corners[2]] - y0, z[corners[2]] - z0
    cx, cy, cz = y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2
    return 0.5 * np.sqrt(cx * cx + cy * cy + cz * cz)


class Sheets:
    """The two-sided objects of a scene: ``back (s,)`` the points on a sheet's back side,
    ``point_object (s,)``, over ``triangles (t, 3)``. A sheet object's points are its own
    followed by their twins, in the same order."""

    def __init__(self, back, point_object, triangles):
        self.back, self.point_object = back, point_object
        owner = point_object[triangles[:, 0]] if len(triangles) else np.zeros(0, dtype=np.int64)
        two_sided = np.zeros(int(point_object.max(initial=0)) + 1, dtype=bool)
        two_sided[point_object[back]] = True
        self.triangle_object = owner
        self.triangle_back = back[triangles[:, 0]] if len(triangles) else np.zeros(0, dtype=bool)
        self.triangles = two_sided[owner]  # (t,) bool: triangles of two-sided objects
        self.point_sheet = two_sided[point_object]  # (s,) bool: points of two-sided objects
        self.twins = np.full(len(back), -1, dtype=np.int64)  # (s,): each point's twin, -1: none
        ids = np.flatnonzero(back)
        half = (np.bincount(point_object, minlength=len(two_sided)) // 2)[point_object[ids]]
        self.twins[ids] = ids - half
        self.twins[ids - half] = ids
        point_side = np.where(back, 2, np.where(self.point_sheet, 1, 0)).astype(np.int8)
        self.sides = (point_side[triangles[:, 0]] if len(triangles) else np.zeros(0, dtype=np.int8), point_side)

    def other_side(self, pair_p, pair_t) -> np.ndarray:
        """``(m,)`` bool: whether triangle ``pair_t`` lies on the other side of the sheet that
        point ``pair_p`` lies on (a ray from a sheet never meets its own far side)."""
        return (self.point_sheet[pair_p] & (self.triangle_object[pair_t] == self.point_object[pair_p])
                & (self.triangle_back[pair_t] != self.back[pair_p]))


def same_sky_map(a, b) -> bool:
    """Whether two sky patterns (``SceneArrays.sky_map``; None: a uniform sky) are the same."""
    if a is None or b is None:
        return a is None and b is None
    return a.shape == b.shape and np.array_equal(a, b)
