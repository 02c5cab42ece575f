#!/usr/bin/env bash
# Set-up shared by the demo and test commands: system packages for headless OpenGL (Mesa
# llvmpipe through EGL) when missing, and a virtual environment with bpy 5.0.1 and pytest.
# Safe to run again: it only installs what is missing.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${CUBEGI_VENV:-$ROOT/.venv}"
PY="${PYTHON:-python3.11}"
command -v "$PY" >/dev/null 2>&1 || PY=python3

SYSTEM_PACKAGES="libx11-6 libxext6 libxfixes3 libxi6 libxrender1 libxkbcommon0 libsm6 libxt6 \
libgl1 libopengl0 libegl1 libegl-mesa0 libgl1-mesa-dri"

missing=()
if command -v dpkg-query >/dev/null 2>&1; then
  for p in $SYSTEM_PACKAGES; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
fi
if ((${#missing[@]})); then
  echo "setup: installing system packages: ${missing[*]}"
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -c 'import sys; assert sys.version_info[:2] == (3, 11), "bpy 5.0.1 needs CPython 3.11"' \
    || { echo "setup: CPython 3.11 is needed (bpy 5.0.1 is built for it only)"; exit 1; }
  echo "setup: creating $VENV"
  "$PY" -m venv "$VENV"
fi
if ! "$VENV/bin/python" -c 'import bpy, pytest, hypothesis, matplotlib, dask, distributed' >/dev/null 2>&1; then
  echo "setup: installing Python packages into $VENV"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check -r "$ROOT/requirements-dev.txt"
fi
