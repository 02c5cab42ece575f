#!/usr/bin/env bash
# Build the installable extension zip (into dist/, or the folder given). Sets up first.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
"${CUBEGI_VENV:-$ROOT/.venv}/bin/python" "$ROOT/scripts/build_extension.py" "$@"
