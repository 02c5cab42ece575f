"""A collected scene made ready for a bake on a grid: where its light is gathered by rays,
and how finely its surfaces are sampled (numpy alone)."""

from ..cubegi_engine.gather import large_points
from ..cubegi_engine.refine import refine_for_grid


def sampled(collected, grid):
    """``collected`` made ready for a bake on ``grid``: the points that stand for a large
    share of the surface marked to be gathered by rays (:func:`cubegi_engine.gather.large_points`,
    on the meshes as they are), then its long triangles cut so that light is sampled about a
    cell of ``grid`` apart everywhere (:func:`cubegi_engine.refine.refine_for_grid`): its
    arrays replaced and its targets' corners pointed at their points' new places; in place,
    returned. The same scene and grid give the same arrays (an update's reading compares
    with the bake's)."""
    collected.arrays.gathered = large_points(collected.arrays)
    arrays, moved = refine_for_grid(collected.arrays, grid)
    if arrays is not collected.arrays:
        for target in collected.targets:
            target.loop_point = moved[target.loop_point]
        collected.arrays = arrays
    return collected
