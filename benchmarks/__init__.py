"""CubeGI's benchmarks, run from the source tree (never in the extension): the error-time
sweep against Cycles (:mod:`.sweep`, analysed by :mod:`.analysis`), the scaling runs
(:mod:`.scaling`), the scenes built in code (:mod:`.scenes`) and the public scenes
(:mod:`.public_scenes`); the ``bench_*.py`` scripts time single stages.
"""

import tools  # noqa: F401  (loads the source tree as the package ``cubegi``)


def in_child(module, call, timeout):
    """``benchmarks.<module>.<call>`` run in a fresh Python with the extension loaded (a bake's
    peak memory and its Blender state are its own); the JSON record it prints."""
    import json
    import os
    import subprocess
    import sys

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    tag = module.upper() + " "
    code = (
        "import json, sys; sys.path.insert(0, %r)\n"
        "from tools import load_extension; load_extension()\n"
        "from benchmarks import %s\n"
        "print(%r + json.dumps(%s.%s))\n" % (root, module, tag, module, call)
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout)
    for line in done.stdout.splitlines():
        if line.startswith(tag):
            return json.loads(line[len(tag):])
    raise RuntimeError(f"the {module} bake {call} failed:\n{done.stderr[-2000:]}")
