#!/usr/bin/env bash
# Set up (if needed), then run the test suite in background bpy on the GPU module. Extra
# arguments go to pytest (for example `-m smoke` for the smoke set). CUBEGI_BLENDER picks the
# Blender version (scripts/blender.sh).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
source "$ROOT/scripts/blender.sh"
cd "$ROOT"
# Two worker processes, each test file in one (its module fixtures and scenes shared): the
# whole suite 1118 -> 742 s on a 2-core machine, where a bake's threads and llvmpipe leave a
# core idle much of the time. `-n 0` after these runs it in one process (`-s` needs that).
# The whole of tests/ unless a path among the arguments names what to run.
where=tests
for arg in "$@"; do
  [ -e "${arg%%::*}" ] && where=
done
exec "$VENV/bin/python" -m pytest -q -n 2 --dist loadfile $where "$@"
