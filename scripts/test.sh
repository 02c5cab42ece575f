#!/usr/bin/env bash
# Set up (if needed), then run the whole test suite in background bpy on the GPU module.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
cd "$ROOT"
exec "${CUBEGI_VENV:-$ROOT/.venv}/bin/python" -m pytest -q tests "$@"
