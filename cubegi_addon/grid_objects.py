"""Probe grid objects: Empties whose cube is a CubeGI probe grid, and the probe light a bake
keeps on them.

A grid object is an Empty with ``Object.cubegi.is_probe_grid``; its cube (display size 1,
scaled and placed) is the grid's box, ``Object.cubegi.resolution`` its probes along X, Y, Z.
A bake stores each grid object's probe light as hidden ID properties
(``_cubegi_probe_light``: ``p * 9 * 3`` SH radiance coefficients; ``_cubegi_probe_valid``:
``p`` flags, 0 for a probe found inside geometry; ``_cubegi_probe_offset``: ``p * 3``, where
probes were moved out of geometry, if any was), saved with the file.
"""

import bpy
import numpy as np

from ..cubegi_engine.errors import BakeError
from ..cubegi_engine.grid import GridSet, ProbeGrid, fit_bounds

LIGHT_KEY = "_cubegi_probe_light"
VALID_KEY = "_cubegi_probe_valid"
OFFSET_KEY = "_cubegi_probe_offset"  # p * 3: where each probe was moved (out of geometry), if any was
# A grid fitted to the scene has at most this many probes (see fit_bounds).
MAX_FITTED_PROBES = 4096
# A fitted grid's box is the scene's box grown by this share of its size on every side.
FITTED_PAD = 1e-3


def probe_grid_objects(scene):
    """The scene's probe grid objects, by name: the order of a bake's grids and probes."""
    return sorted(
        (ob for ob in scene.objects if ob.type == "EMPTY" and getattr(ob, "cubegi", None) and ob.cubegi.is_probe_grid),
        key=lambda ob: ob.name,
    )


def new_probe_grid(collection, lo, hi, resolution, name="CubeGI Probe Grid"):
    """Link a probe grid Empty whose cube spans ``lo``..``hi``; returns the object."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    ob = bpy.data.objects.new(name, None)
    ob.empty_display_type = "CUBE"
    ob.empty_display_size = 1.0
    ob.location = tuple(0.5 * (lo + hi))
    ob.scale = tuple(np.maximum(0.5 * (hi - lo), 1e-6))
    collection.objects.link(ob)
    ob.cubegi.is_probe_grid = True
    ob.cubegi.resolution = tuple(int(r) for r in resolution)
    return ob


def world_bounds(objects):
    """World-space axis-aligned box ``(lo, hi)`` of the objects' bounding boxes, or None."""
    corners = [np.array([list(c) + [1.0] for c in ob.bound_box]) @ np.array(ob.matrix_world).T for ob in objects]
    if not corners:
        return None
    pts = np.concatenate(corners)[:, :3]
    return pts.min(axis=0), pts.max(axis=0)


def grid_bounds_of(ob):
    """World-space axis-aligned box of a probe grid object's cube (rotation is ignored)."""
    s = ob.empty_display_size
    corners = np.array([[x, y, z, 1.0] for x in (-s, s) for y in (-s, s) for z in (-s, s)])
    world = corners @ np.array(ob.matrix_world, dtype=np.float64).T
    return world[:, :3].min(axis=0), world[:, :3].max(axis=0)


def probe_grid(ob, resolution=None):
    """The :class:`ProbeGrid` of a grid object as it stands."""
    lo, hi = grid_bounds_of(ob)
    return ProbeGrid(lo, hi, resolution or tuple(ob.cubegi.resolution))


def resolve_grid(scene, arrays, resolution=None, cells=8, spacing=None, notes=None):
    """The probe grid(s) of a bake, where they came from, and the share of points outside.

    ``resolution`` (3 ints) overrides the resolution (of every grid); a fitted grid has about
    ``cells`` cells along its longest side, or with ``spacing`` (scene units) probes about
    that far apart (one grid; capped at MAX_FITTED_PROBES probes, with a note in ``notes``).
    The bounds come from the
    scene's probe grid objects if it has any, else from the geometry's bounding box. With
    several grid objects each point uses the finest grid whose box contains it (see
    :class:`cubegi_engine.grid.GridSet`); points outside every grid get the light of the
    nearest grid's nearest probes (trilinear weights clamped at its faces). A grid object
    with no geometry inside is refused.
    """
    objects = probe_grid_objects(scene)
    if objects:
        grids, inside_any = [], np.zeros(len(arrays.points), dtype=bool)
        for ob in objects:
            grid = probe_grid(ob, resolution)
            inside = np.all((arrays.points >= grid.lo) & (arrays.points <= grid.hi), axis=1)
            if not inside.any():
                raise BakeError(f"probe grid {ob.name!r} contains no geometry; move or scale it over the scene")
            inside_any |= inside
            grids.append(grid)
        names = ", ".join(repr(ob.name) for ob in objects)
        grid = grids[0] if len(grids) == 1 else GridSet(grids)
        source = f"probe grid object{'s' if len(grids) > 1 else ''} {names}"
        return grid, source, float(1.0 - inside_any.mean())
    lo, hi = _padded(*arrays.bounds(), arrays.scale)
    if resolution:
        return ProbeGrid(lo, hi, resolution), "scene bounds", 0.0
    if spacing:
        res = fit_bounds(lo, hi, float(spacing), max_probes=MAX_FITTED_PROBES)
        wanted = np.maximum(1, np.round((hi - lo) / float(spacing)))
        if notes is not None and np.prod(res) < np.prod(wanted):
            notes.append(f"a probe spacing of {spacing:g} would need {int(np.prod(wanted)):,} probes over the scene; "
                         f"{int(np.prod(res)):,} are used (at most {MAX_FITTED_PROBES:,} in a fitted grid): add a probe "
                         "grid object over the part that needs them")
        return ProbeGrid(lo, hi, res), f"fitted to scene bounds, probes {float(spacing):g} apart", 0.0
    whole = ProbeGrid(lo, hi, fit_bounds(lo, hi, float(np.max(hi - lo)) / cells, max_probes=MAX_FITTED_PROBES))
    dense = dense_region(arrays)
    if dense is not None and np.max(dense[1] - dense[0]) < DENSE_SHARE * np.max(hi - lo):
        dlo, dhi = _padded(dense[0], dense[1], arrays.scale)
        if dense[2]:
            # A solid seen from outside (a block on a room's floor): the finer grid reaches a
            # coarse cell beyond it, so its probes stand round it, not all inside it (fitted
            # tight, every probe was inside the block, and the block, lit by none, went black).
            dlo, dhi = np.maximum(dense[0] - whole.cell_size, lo), np.minimum(dense[1] + whole.cell_size, hi)
        fine = ProbeGrid(dlo, dhi, fit_bounds(dlo, dhi, float(np.max(dhi - dlo)) / cells, max_probes=MAX_FITTED_PROBES))
        return GridSet([whole, fine]), "fitted to scene bounds, and finer over where most of its geometry is", 0.0
    return whole, "fitted to scene bounds", 0.0


# A fitted grid gets a second, finer grid over the region where most of the geometry is
# when that region's longest side is under this share of the scene's (a room on a large
# ground plane): the probes go where the light changes, not over empty ground.
DENSE_SHARE = 0.25
# The region: the objects with at least half of their points inside the box of the middle
# 90% of all points (per axis).
DENSE_QUANTILES = (0.05, 0.95)
# Dense geometry is a solid where its faces enclose, outward, at least this share of its box.
SOLID_SHARE = 0.05


def dense_region(arrays):
    """``(lo, hi, solid)`` of the objects most of whose points lie where most of the scene's
    points are, or None (see DENSE_SHARE); ``solid``: they enclose a volume with their faces
    outward (a block, not a room seen from inside nor open sheets, whose twins cancel)."""
    if arrays.point_object is None or len(arrays.points) < 16:
        return None
    q_lo, q_hi = np.quantile(arrays.points, DENSE_QUANTILES, axis=0)
    inside = np.all((arrays.points >= q_lo) & (arrays.points <= q_hi), axis=1)
    owner = arrays.point_object
    count = int(owner.max()) + 1
    share = np.bincount(owner, inside, minlength=count) / np.maximum(np.bincount(owner, minlength=count), 1)
    kept = share >= 0.5
    if not kept.any():
        return None
    lo, hi = arrays.points[kept[owner]].min(axis=0), arrays.points[kept[owner]].max(axis=0)
    # A room round them whose walls lie outside the middle of the points (a cup of 2,000
    # points on its counter holds half of them) is kept too, where it is small enough for a
    # region: else the region is its furniture, a solid, grown by a coarse cell of the ground's.
    o_lo, o_hi = np.full((count, 3), np.inf), np.full((count, 3), -np.inf)
    np.minimum.at(o_lo, owner, arrays.points)
    np.maximum.at(o_hi, owner, arrays.points)
    extent = float(np.max(arrays.points.max(axis=0) - arrays.points.min(axis=0)))
    kept |= np.all(o_lo <= lo, axis=1) & np.all(o_hi >= hi, axis=1) & (np.max(o_hi - o_lo, axis=1) < DENSE_SHARE * extent)
    keep = kept[owner]
    if keep.all():
        return None
    pts = arrays.points[keep]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    tri = arrays.triangles[keep[arrays.triangles[:, 0]]]
    p = arrays.points
    volume = float(np.einsum("ij,ij->i", p[tri[:, 0]], np.cross(p[tri[:, 1]], p[tri[:, 2]])).sum()) / 6.0
    return lo, hi, volume > SOLID_SHARE * float(np.prod(np.maximum(hi - lo, 0.0)))


def _padded(lo, hi, scale):
    pad = np.maximum(hi - lo, 1e-9 * max(scale, 1e-30)) * FITTED_PAD
    return lo - pad, hi + pad


def grids_of(grid):
    """The ProbeGrids of a grid (of the whole grid under a probe subset), and each one's
    first probe index."""
    parts = grid.parts()
    return tuple(g for g, _ in parts), tuple(first for _, first in parts)


def grid_report(grid):
    """The grid part of a report: every grid's resolution and box (the first's at top level)."""
    grids, _ = grids_of(grid)
    each = [{"resolution": list(g.resolution), "lo": list(g.lo), "hi": list(g.hi), "probes": g.count} for g in grids]
    return dict(each[0], probes=grid.count, grids=each)


def store_probe_light(objects, probe_field):
    """Keep each grid object's share of a bake's probe field (grids in ``objects`` order)."""
    grids, offsets = grids_of(probe_field.grid)
    # A whole field's probes, each where the bake placed it (zeros: at its cell centre). A
    # grid set's first probe indices were once read here as moves: a bogus property.
    moved = probe_field.grid.displacements()
    for ob, g, start in zip(objects, grids, offsets):
        ob[LIGHT_KEY] = np.asarray(probe_field.coeffs[start : start + g.count], dtype=np.float64).ravel().tolist()
        ob[VALID_KEY] = [int(v) for v in probe_field.valid[start : start + g.count]]
        mine = moved[start : start + g.count]
        if np.any(mine):
            ob[OFFSET_KEY] = np.asarray(mine, dtype=np.float64).ravel().tolist()
        elif OFFSET_KEY in ob:
            del ob[OFFSET_KEY]


def forget_probe_light(ob):
    """Drop a grid object's stored probe light."""
    for key in (LIGHT_KEY, VALID_KEY, OFFSET_KEY):
        if key in ob:
            del ob[key]


def stored_probe_light(ob):
    """``(coeffs (p, 9, 3), valid (p,) bool)`` from the last bake, or None if there is none
    or the grid's resolution changed since."""
    if LIGHT_KEY not in ob or VALID_KEY not in ob:
        return None
    count = int(np.prod(ob.cubegi.resolution))
    coeffs = np.array(ob[LIGHT_KEY], dtype=np.float64)
    valid = np.array(ob[VALID_KEY], dtype=bool)
    if coeffs.size != count * 27 or valid.size != count:
        return None
    return coeffs.reshape(count, 9, 3), valid


def stored_probe_offsets(ob):
    """``(p, 3)``: where the last bake moved each probe of the grid object (out of
    geometry), zeros for the rest; zeros if it moved none or the resolution changed."""
    count = int(np.prod(ob.cubegi.resolution))
    moved = np.array(ob[OFFSET_KEY], dtype=np.float64) if OFFSET_KEY in ob else np.zeros(0)
    return moved.reshape(count, 3) if moved.size == count * 3 else np.zeros((count, 3))
