"""Small test scenes built in code: the benchmark's builders, and boxes from the demo's."""

from benchmarks.scenes import add_light, closed_box, cornell, material, mesh_object, set_world, thin_wall  # noqa: F401
from tools.demo import box, grid_patch  # noqa: F401


def box_mesh(lo, hi, cells, inward):
    return box(lo, hi, cells, inward=inward)
