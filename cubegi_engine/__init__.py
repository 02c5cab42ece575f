"""CubeGI's engine: the mathematics of cube-map probe global illumination.

Spherical harmonics (``sh``), cube-map texel geometry (``cubemap``), the probe grid
(``grid``), light formulas (``lights``), the bounce operators (``transport``) and the bake
pipeline (``bake``). None of these import bpy, gpu or mathutils; the GPU is passed in as a
renderer object. ``python -m cubegi_engine`` is the command line, which needs bpy.
"""

__version__ = "0.1.0"
