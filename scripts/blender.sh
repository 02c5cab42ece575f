# Sourced by the set-up, test, demo and build scripts: which Blender (the `bpy` module from
# PyPI) to use, the CPython it needs, and its own virtual environment.
#
#   CUBEGI_BLENDER   a supported bpy version (see SUPPORTED below) or a line ("4.5", "5.3");
#                    default: the newest release this machine has a CPython for
#   CUBEGI_VENV      the virtual environment (default: .venvs/bpy-VERSION in the source tree)
#
# Sets CUBEGI_BLENDER (the exact version), CUBEGI_PYTHON (the interpreter to make the venv
# with) and VENV.

# Newest first: "bpy version:CPython it is built for". bpy 4.5 and 5.0 are built for CPython
# 3.11, 5.1 and later for 3.13. Keep docs/blender-versions.md and the manifest in step.
SUPPORTED="5.3.0:3.13 5.2.3:3.13 5.1.2:3.13 5.0.1:3.11 4.5.15:3.11"

# An interpreter of CPython X.Y, or nothing: $PYTHON if it is one, pythonX.Y on the PATH,
# a pyenv install, or Debian's /usr/bin/pythonX.Y.
cubegi_find_python() {
  local want="$1" cand prefix
  for cand in "${PYTHON:-}" "python$want" "/usr/bin/python$want"; do
    [ -n "$cand" ] || continue
    if "$cand" -c "import sys; sys.exit(sys.version_info[:2] != tuple(map(int, '$want'.split('.'))))" >/dev/null 2>&1; then
      command -v "$cand"
      return 0
    fi
  done
  if command -v pyenv >/dev/null 2>&1; then
    for cand in $(pyenv versions --bare 2>/dev/null | grep -E "^${want//./\\.}(\.[0-9]+)?$" | sort -V -r); do
      prefix="$(pyenv prefix "$cand" 2>/dev/null)" || continue
      if [ -x "$prefix/bin/python$want" ]; then
        echo "$prefix/bin/python$want"
        return 0
      fi
    done
  fi
  return 1
}

cubegi_choose_blender() {
  local asked="${CUBEGI_BLENDER:-}" entry version py found=""
  for entry in $SUPPORTED; do
    version="${entry%%:*}"
    py="${entry##*:}"
    if [ -n "$asked" ]; then
      # An exact version, or a line: its newest supported release.
      [ "$asked" = "$version" ] || [ "$asked" = "${version%.*}" ] || continue
    fi
    if CUBEGI_PYTHON="$(cubegi_find_python "$py")"; then
      found="$version"
      break
    fi
    if [ -n "$asked" ]; then
      echo "setup: bpy $version needs CPython $py, which this machine lacks (set PYTHON to one)" >&2
      return 1
    fi
  done
  if [ -z "$found" ]; then
    if [ -n "$asked" ]; then
      echo "setup: CUBEGI_BLENDER=$asked is not a supported version; supported: $(cubegi_supported_list)" >&2
    else
      echo "setup: no CPython for any supported Blender (3.13 for bpy 5.1+, 3.11 for 4.5 and 5.0)" >&2
    fi
    return 1
  fi
  CUBEGI_BLENDER="$found"
  VENV="${CUBEGI_VENV:-$ROOT/.venvs/bpy-$CUBEGI_BLENDER}"
  export CUBEGI_BLENDER CUBEGI_PYTHON VENV
}

cubegi_supported_list() {
  local entry out=""
  for entry in $SUPPORTED; do out="$out ${entry%%:*}"; done
  echo "${out# }"
}

cubegi_choose_blender || exit 2
