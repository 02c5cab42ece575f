#!/usr/bin/env bash
# Build the installable extension zip into dist/ (or the folder given) with Python's standard
# library alone: no Blender, no bpy, no set-up; Python 3.11 or later ($PYTHON, or the first
# python3 on the PATH that is new enough). Blender's own tool makes the same zip:
#   blender --command extension build --source-dir PATH/TO/cubegi
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
for py in "${PYTHON:-}" python3 python3.13 python3.12 python3.11 /usr/bin/python3; do
  if [ -n "$py" ] && "$py" -c 'import sys; sys.exit(sys.version_info < (3, 11))' >/dev/null 2>&1; then
    exec "$py" "$ROOT/scripts/build_extension.py" "$@"
  fi
done
echo "build: needs Python 3.11 or later; or build with Blender: blender --command extension build --source-dir $ROOT" >&2
exit 2
