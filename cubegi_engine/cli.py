"""Command line: ``python -m cubegi_engine bake IN.blend -o OUT.blend ...``, ``demo`` and
``benchmark``.

Argument checks run before bpy is imported, so bad input fails fast with one line. The bake
itself runs the add-on's operator code inside the ``bpy`` module.
"""

import argparse
import importlib.util
import os
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGE = "cubegi"


class CliError(Exception):
    """Bad input: reported as one line, exit status 2."""


def load_extension():
    """Import the extension package (this source tree) as ``cubegi`` and register it."""
    if PACKAGE in sys.modules:
        return sys.modules[PACKAGE]
    spec = importlib.util.spec_from_file_location(
        PACKAGE, os.path.join(ROOT, "__init__.py"), submodule_search_locations=[ROOT]
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules[PACKAGE] = module
    spec.loader.exec_module(module)
    module.register()
    return module


def _parser():
    p = argparse.ArgumentParser(prog="python -m cubegi_engine", description="CubeGI: cube-map probe global illumination for Blender")
    sub = p.add_subparsers(dest="command", required=True)
    b = sub.add_parser("bake", help="bake a .blend file's light into CubeGI colour attributes")
    b.add_argument("input", help="the .blend file to bake")
    b.add_argument("-o", "--output", required=True, help="where to write the baked .blend")
    _bake_options(b)
    d = sub.add_parser("demo", help="build, bake and render the demo Room")
    d.add_argument("--out", default="out/demo", help="folder for room.blend, room.png and report.json")
    d.add_argument("--no-render", action="store_true", help="skip the PNG")
    _bake_options(d, demo=True)
    m = sub.add_parser("benchmark", help="measure CubeGI's error against run time, and Cycles' (writes results.json/.md and a plot)")
    m.add_argument("--out", default="out/benchmark", help="folder for the results (and the cached Cycles references)")
    m.add_argument("--quick", action="store_true", help="a small sweep that runs in a few minutes (a smoke test)")
    m.add_argument("--scenes", nargs="+", help="only these scenes (default: all)")
    return p


def _bake_options(p, demo=False):
    p.add_argument("--grid", nargs=3, type=int, metavar=("NX", "NY", "NZ"), help="probes along X, Y and Z")
    p.add_argument("--cube-size", type=int, default=32, help="cube-map face size in texels (default 32)")
    p.add_argument("--bounces", type=int, default=5, help="indirect bounces (default 5)")
    p.add_argument("--no-visibility", action="store_true", help="plain trilinear interpolation (lets light leak)")
    p.add_argument(
        "--tolerance", type=float,
        help="stop once the estimated missing share of the indirect light is below this (e.g. 0.01); --bounces stays the cap",
    )
    p.add_argument("--no-tail", action="store_true", help="do not add the estimated light after the last bounce to CubeGI")
    p.add_argument(
        "--no-energy-conservation", action="store_true",
        help="leave each bounce's total as interpolated (for comparison; see the README)",
    )
    p.add_argument("--reference", choices=["cycles"], help="also bake a path-traced reference and report CubeGI's error against it")
    p.add_argument("--reference-samples", type=int, default=256, help="Cycles samples for --reference (default 256)")
    if not demo:
        p.add_argument("--report", help="write the bake report (JSON) here")
        p.add_argument(
            "--lit", nargs="?", const="all", choices=("all", "indirect"),
            help="also write CubeGI_lit: albedo x all light (all, the default) or x indirect light only",
        )


def _check_bake_args(args):
    if args.grid is not None and min(args.grid) < 1:
        raise CliError(f"--grid needs three integers >= 1, got {' '.join(map(str, args.grid))}")
    from .bake import MAX_CUBE_SIZE, MIN_CUBE_SIZE

    if not MIN_CUBE_SIZE <= args.cube_size <= MAX_CUBE_SIZE:
        raise CliError(f"--cube-size must be between {MIN_CUBE_SIZE} and {MAX_CUBE_SIZE}, got {args.cube_size}")
    if args.bounces < 0:
        raise CliError(f"--bounces must be 0 or more, got {args.bounces}")
    if args.tolerance is not None and not 0.0 < args.tolerance < 1.0:
        raise CliError(f"--tolerance must be between 0 and 1 (a share of the light), got {args.tolerance}")
    if args.reference and args.reference_samples < 1:
        raise CliError(f"--reference-samples must be 1 or more, got {args.reference_samples}")


def _check_io(args):
    src = os.path.abspath(args.input)
    if not os.path.isfile(src):
        raise CliError(f"input file does not exist: {args.input}")
    with open(src, "rb") as fh:
        magic = fh.read(7)
    if magic != b"BLENDER" and magic[:2] not in (b"\x1f\x8b", b"\x28\xb5"):
        raise CliError(f"input is not a .blend file: {args.input}")
    dst = os.path.abspath(args.output)
    if dst == src:
        raise CliError("output would overwrite the input; give another path")
    folder = os.path.dirname(dst)
    if not os.path.isdir(folder):
        raise CliError(f"output folder does not exist: {folder}")
    if not os.access(folder, os.W_OK):
        raise CliError(f"output folder is not writable: {folder}")
    if args.report:
        rfolder = os.path.dirname(os.path.abspath(args.report))
        if not os.path.isdir(rfolder) or not os.access(rfolder, os.W_OK):
            raise CliError(f"report folder is missing or not writable: {rfolder}")
    return src, dst


def save_atomically(bpy, path):
    """Save the open file as ``path`` through a temporary file in the same folder."""
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(suffix=".blend", dir=folder)
    os.close(fd)
    try:
        bpy.ops.wm.save_as_mainfile(filepath=tmp, copy=True, check_existing=False, compress=False)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def _print_progress(step):
    print(f"cubegi: [{step.done}/{step.total}] {step.message}", flush=True)


def bake_open_file(settings, resolution, lit=False, reference_samples=None, progress=_print_progress):
    """Bake the file open in bpy with the extension loaded; returns the report."""
    import bpy

    from .bake import run

    ext = load_extension()
    steps = ext.cubegi_addon.pipeline.bake_steps(bpy.context, settings, resolution, lit=lit, reference_samples=reference_samples)
    return run(steps, progress)


def _settings(args):
    from .bake import BakeSettings

    return BakeSettings(
        cube_size=args.cube_size, bounces=args.bounces, visibility=not args.no_visibility,
        tolerance=args.tolerance, add_tail=not args.no_tail, conserve_energy=not args.no_energy_conservation,
    )


def _reference_samples(args):
    return args.reference_samples if args.reference else None


def cmd_bake(args):
    _check_bake_args(args)
    src, dst = _check_io(args)
    import bpy

    load_extension()
    bpy.ops.wm.open_mainfile(filepath=src, load_ui=False)
    report = bake_open_file(
        _settings(args), tuple(args.grid) if args.grid else None, lit=args.lit.upper() if args.lit else False, reference_samples=_reference_samples(args)
    )
    report["input"], report["output"] = src, dst
    save_atomically(bpy, dst)
    if args.report:
        load_extension().cubegi_addon.pipeline.write_report(report, args.report)
    _summary(report)


def _summary(report):
    from .report import summary_lines

    for line in summary_lines(report):
        print(f"cubegi: {line}", flush=True)


def cmd_demo(args):
    _check_bake_args(args)
    os.makedirs(args.out, exist_ok=True)
    import bpy

    ext = load_extension()
    demo = importlib.import_module(f"{PACKAGE}.cubegi_addon.demo")
    demo.build_room()
    resolution = tuple(args.grid) if args.grid else None
    report = bake_open_file(_settings(args), resolution, lit=True, reference_samples=_reference_samples(args))
    blend = os.path.join(args.out, "room.blend")
    save_atomically(bpy, blend)
    ext.cubegi_addon.pipeline.write_report(report, os.path.join(args.out, "report.json"))
    _summary(report)
    print(f"cubegi: wrote {blend} and {os.path.join(args.out, 'report.json')}")
    if not args.no_render:
        png = os.path.join(args.out, "room.png")
        demo.render_png(png, attribute="CubeGI_lit")
        print(f"cubegi: wrote {png}")


def cmd_benchmark(args):
    os.makedirs(args.out, exist_ok=True)
    if not os.access(args.out, os.W_OK):
        raise CliError(f"output folder is not writable: {args.out}")
    load_extension()
    bench = importlib.import_module(f"{PACKAGE}.cubegi_addon.benchmark")
    bench.run(args.out, quick=args.quick, scenes=args.scenes, log=lambda m: print(f"cubegi: {m}", flush=True))
    print(f"cubegi: wrote {', '.join(os.path.join(args.out, f) for f in ('results.json', 'results.md', 'error_vs_time.png'))}")


def main(argv=None):
    args = _parser().parse_args(argv)
    try:
        {"bake": cmd_bake, "demo": cmd_demo, "benchmark": cmd_benchmark}[args.command](args)
    except CliError as exc:
        print(f"cubegi: error: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"cubegi: error: {exc}", file=sys.stderr)
        return 1
    return 0
