"""Build the installable extension zip with nothing but Python's standard library.

Usage: python3 scripts/build_extension.py [OUT_DIR]   (default: dist/; Python 3.11 or later,
for example the one inside Blender: ``blender --background --python-expr`` is not needed)

It writes what Blender's own tool (``blender --command extension build``) writes: the
files of the source tree that ``[build] paths_exclude_pattern`` in blender_manifest.toml
does not exclude, under the same names, deflated, as ``OUT_DIR/ID-VERSION.zip``; the tests
compare the two builds file for file, and validate the manifest with Blender's tool. No
Blender, bpy or virtual environment is needed. Prints the zip's path.

The patterns are read as Blender reads them (gitignore style): a leading ``/`` anchors a
pattern at the source folder, a trailing ``/`` matches folders only (and all they hold),
a pattern with no ``/`` inside matches a name at any depth; ``*``, ``?`` and ``[...]`` are
wildcards within one name.
"""

import fnmatch
import os
import sys
import tempfile
import tomllib
import zipfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MANIFEST = "blender_manifest.toml"
# Blender's tool excludes these when the manifest gives no patterns.
DEFAULT_EXCLUDE = ["__pycache__/", ".*", "/*.zip", "*.blend[1-9]"]


def excluded(rel, is_dir, patterns):
    """True if the source-relative path ``rel`` ("/"-separated) matches one of ``patterns``."""
    parts = rel.split("/")
    for pattern in patterns:
        dir_only = pattern.endswith("/")
        pat = pattern.rstrip("/")
        if dir_only and not is_dir:
            continue
        if pat.startswith("/") or "/" in pat:
            if fnmatch.fnmatchcase(rel, pat.lstrip("/")):
                return True
        elif fnmatch.fnmatchcase(parts[-1], pat):
            return True
    return False


def files(root, patterns):
    """The source-relative paths that go into the zip, sorted."""
    out = []
    for folder, dirs, names in os.walk(root):
        base = os.path.relpath(folder, root).replace(os.sep, "/")
        base = "" if base == "." else base + "/"
        dirs[:] = sorted(d for d in dirs if not excluded(base + d, True, patterns))
        out += [base + n for n in names if not excluded(base + n, False, patterns)]
    return sorted(out)


def build(out_dir, root=ROOT):
    with open(os.path.join(root, MANIFEST), "rb") as fh:
        manifest = tomllib.load(fh)
    for field in ("id", "version", "name", "tagline", "maintainer", "type", "blender_version_min", "license"):
        if field not in manifest:
            raise SystemExit(f"build: {MANIFEST} has no {field!r}")
    if not os.path.isfile(os.path.join(root, "__init__.py")):
        raise SystemExit("build: not a Python package: no __init__.py")
    patterns = manifest.get("build", {}).get("paths_exclude_pattern", DEFAULT_EXCLUDE)
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, f"{manifest['id']}-{manifest['version']}.zip")
    fd, tmp = tempfile.mkstemp(prefix=".cubegi-build-", suffix=".zip", dir=out_dir)
    os.close(fd)
    try:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as zf:
            for rel in files(root, patterns):
                zf.write(os.path.join(root, *rel.split("/")), rel)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


if __name__ == "__main__":
    print(build(os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "dist"))))
