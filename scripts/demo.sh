#!/usr/bin/env bash
# Set up (if needed), then build, bake and render the demo Room into out/demo.
# CUBEGI_BLENDER picks the Blender version (scripts/blender.sh).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
source "$ROOT/scripts/blender.sh"
cd "$ROOT"
exec "$VENV/bin/python" -m cubegi_engine demo --out out/demo "$@"
