#!/usr/bin/env bash
# Set-up shared by the demo, test and build commands: system packages for headless OpenGL
# (Mesa llvmpipe through EGL) when missing, and a virtual environment with the chosen
# Blender's bpy module and the test tools (see scripts/blender.sh: CUBEGI_BLENDER picks the
# version, the newest this machine can run by default; `.venv` links to the default's).
# Safe to run again: it only installs what is missing.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ASKED="${CUBEGI_BLENDER:-}"
source "$ROOT/scripts/blender.sh"

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
  echo "setup: creating $VENV (bpy $CUBEGI_BLENDER on $("$CUBEGI_PYTHON" --version))"
  "$CUBEGI_PYTHON" -m venv "$VENV"
fi
have="$("$VENV/bin/python" -c 'import importlib.metadata as m; print(m.version("bpy"))' 2>/dev/null || true)"
if [ "$have" != "$CUBEGI_BLENDER" ] \
  || ! "$VENV/bin/python" -c 'import pytest, xdist, hypothesis, matplotlib, dask, distributed, ruff, mypy' >/dev/null 2>&1; then
  echo "setup: installing bpy==$CUBEGI_BLENDER and the test tools into $VENV"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check "bpy==$CUBEGI_BLENDER" -r "$ROOT/requirements-dev.txt"
fi

# `.venv` names the default version's environment (the README's commands use it).
if [ -z "$ASKED" ] && [ -z "${CUBEGI_VENV:-}" ]; then
  if [ -L "$ROOT/.venv" ] || [ ! -e "$ROOT/.venv" ]; then
    ln -sfn "$VENV" "$ROOT/.venv"
  elif [ "$(readlink -f "$ROOT/.venv")" != "$(readlink -f "$VENV")" ]; then
    echo "setup: note: .venv is an older environment of its own; remove it to have it name $VENV"
  fi
fi
