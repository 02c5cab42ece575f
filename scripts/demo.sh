#!/usr/bin/env bash
# Set up (if needed), then build, bake and render the demo Room into out/demo.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
cd "$ROOT"
exec "${CUBEGI_VENV:-$ROOT/.venv}/bin/python" -m cubegi_engine demo --out out/demo "$@"
