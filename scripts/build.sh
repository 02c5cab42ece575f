#!/usr/bin/env bash
# Build the installable extension zip (into dist/, or the folder given). Sets up first.
# CUBEGI_BLENDER picks the Blender version whose extension tool builds it (scripts/blender.sh).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
source "$ROOT/scripts/blender.sh"
"$VENV/bin/python" "$ROOT/scripts/build_extension.py" "$@"
