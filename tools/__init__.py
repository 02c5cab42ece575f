"""What runs from CubeGI's source tree and never ships in the extension: the loader of the
source tree (:mod:`.launch`), the command line's source-tree commands (:mod:`.cli`: ``demo``,
``benchmark``) and the demo scene (:mod:`.demo`). The benchmarks and their scenes are in
``benchmarks/``.

Importing this package loads the source tree as the extension package ``cubegi`` (without
registering it, so without bpy): every module here imports CubeGI as ``cubegi.*``.
"""

from .launch import load_extension

load_extension(register=False)
