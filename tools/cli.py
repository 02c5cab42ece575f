"""The command line run from the source tree (``python -m cubegi_engine ...``): the add-on's
commands (:mod:`cubegi_addon.cli`: ``bake``, ``bake-animation``, ``batch``), and ``demo`` and
``benchmark``, which need the source tree's demo scene and benchmarks."""

import os

from cubegi.cubegi_addon import cli, files
from cubegi.cubegi_engine.errors import BakeError


def _parsers(sub):
    d = sub.add_parser("demo", help="build, bake and render the demo Room")
    d.add_argument("--out", default="out/demo", help="folder for room.blend, room.png and report.json")
    d.add_argument("--no-render", action="store_true", help="skip the PNG")
    cli.bake_options(d, demo=True)
    m = sub.add_parser("benchmark", help="measure CubeGI's error against run time, and Cycles' (writes results.json/.md and a plot)")
    m.add_argument("--out", default="out/benchmark", help="folder for the results (and the cached Cycles references)")
    m.add_argument("--quick", action="store_true", help="a small sweep that runs in a few minutes (a smoke test)")
    m.add_argument("--scenes", nargs="+", help="only these scenes (default: all; with --quick, the scenes built in code, not the public ones)")
    m.add_argument(
        "--scaling", action="store_true",
        help="instead: bake the Room subdivided to 6K-1M vertices and with 50-2,000 probes, and The Breakfast Room (where the "
        "public scenes are here) subdivided to 1.2M vertices, each in its own process, and write scaling.json and "
        "scaling.png (time per stage, peak memory)",
    )
    m.add_argument(
        "--lights", action="store_true",
        help="instead: bake a hall lit by one area lamp and by thirteen (default quality, each in its own process, against "
        "Cycles) and write lights.json and lights.md (what many lights cost)",
    )
    m.add_argument(
        "--machine", action="store_true",
        help="instead: the figures that compare two machines (a GPU's beside this one's): the Breakfast Room's default bake "
        "stage by stage against its reference, Cycles at 16 and 64 samples, the scaling target (1M vertices) and its 95K "
        "point; writes machine.json",
    )


def cmd_demo(args):
    settings = cli.checked_settings(args)
    out = os.path.abspath(args.out)
    if os.path.exists(out) and not os.path.isdir(out):
        raise BakeError(f"--out {args.out!r} is a file; give a folder")
    os.makedirs(out, exist_ok=True)
    blend = files.writable_target(os.path.join(out, "room.blend"), "demo file")
    report_path = files.writable_target(os.path.join(out, "report.json"), "report")
    bpy = cli.blender()
    from cubegi.cubegi_addon import pipeline

    from . import demo

    demo.build_room()
    report = pipeline.bake(bpy.context, settings, tuple(args.grid) if args.grid else None, lit="ALL",
                           reference_samples=args.reference_samples if args.reference else None, progress=cli.print_progress)
    files.write_all([(blend, cli.save_blend(False)), (report_path, files.text(report.to_json()))])
    cli.print_summary(report)
    print(f"cubegi: wrote {blend} and {report_path}")
    if not args.no_render:
        png = os.path.join(out, "room.png")
        demo.render_png(png, attribute="CubeGI_lit")
        print(f"cubegi: wrote {png}")


def cmd_benchmark(args):
    os.makedirs(args.out, exist_ok=True)
    if not os.access(args.out, os.W_OK):
        raise BakeError(f"output folder is not writable: {args.out}")

    def log(message):
        print(f"cubegi: {message}", flush=True)

    if args.lights:
        from benchmarks import lights

        lights.run(args.out, log=log)
        print(f"cubegi: wrote {os.path.join(args.out, 'lights.json')}, {os.path.join(args.out, 'lights.md')}")
        return
    if args.machine:
        cli.blender()
        from benchmarks import machine

        machine.run(args.out, log=log)
        print(f"cubegi: wrote {os.path.join(args.out, 'machine.json')}")
        return
    if args.scaling:
        from benchmarks import scaling

        scaling.run(args.out, quick=args.quick, log=log)
        return
    cli.blender()
    from benchmarks import sweep

    sweep.run(args.out, quick=args.quick, scenes=args.scenes, log=log)
    print(f"cubegi: wrote {', '.join(os.path.join(args.out, f) for f in ('results.json', 'results.md', 'error_vs_time.png'))}")


def main(argv=None):
    """The exit status of the command line with the source tree's commands (see
    :func:`cubegi_addon.cli.main`)."""
    return cli.main(argv, more=cli.Commands(_parsers, {"demo": cmd_demo, "benchmark": cmd_benchmark}))


