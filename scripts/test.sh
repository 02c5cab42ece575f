#!/usr/bin/env bash
# Set up (if needed), then run the test suite in background bpy on the GPU module. Extra
# arguments go to pytest (for example `-m smoke` for the smoke set). CUBEGI_BLENDER picks the
# Blender version (scripts/blender.sh).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
source "$ROOT/scripts/blender.sh"
cd "$ROOT"
exec "$VENV/bin/python" -m pytest -q tests "$@"
