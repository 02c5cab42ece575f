"""CubeGI's benchmarks, run from the source tree (never in the extension): the error-time
sweep against Cycles (:mod:`.sweep`, analysed by :mod:`.analysis`), the scaling runs
(:mod:`.scaling`), the scenes built in code (:mod:`.scenes`) and the public scenes
(:mod:`.public_scenes`); the ``bench_*.py`` scripts time single stages.
"""

import tools  # noqa: F401  (loads the source tree as the package ``cubegi``)
