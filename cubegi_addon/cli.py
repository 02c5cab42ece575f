"""Command line: ``bake IN.blend -o OUT.blend ...``, ``bake-animation`` and ``batch``, from
``blender -c cubegi`` (:mod:`.command`) and ``python -m cubegi_engine`` (the source tree's
``tools/cli.py``, which adds ``demo`` and ``benchmark``).

Arguments, settings and every path are checked before bpy is imported, so bad input fails
fast with one line (exit status 2) and writes nothing. The bake runs the add-on's pipeline
inside the ``bpy`` module on a copy of the input opened with its UI; the input is never
written. Outputs are written whole or not at all (:mod:`.files`).
"""

import argparse
import importlib
import json
import os
import signal
import sys
from collections.abc import Callable
from dataclasses import dataclass

from ..cubegi_engine.errors import ERROR_PREFIX, BakeError, Interrupted
from ..cubegi_engine.settings import OPTIONS, QUALITY, BakeSettings
from . import files, interrupts
from .attributes import LitMode

# Set to 1 to see the traceback of a failure that is CubeGI's own defect.
DEBUG_ENV = "CUBEGI_DEBUG"
# Compressed .blend files start with a gzip (older Blender) or zstd (4.x, 5.x) header.
BLEND_MAGIC, GZIP_MAGIC, ZSTD_MAGIC = b"BLENDER", b"\x1f\x8b", b"\x28\xb5\x2f\xfd"


def _parser(prog, more=None):
    p = argparse.ArgumentParser(prog=prog, description="CubeGI: cube-map probe global illumination for Blender")
    sub = p.add_subparsers(dest="command", required=True)
    b = sub.add_parser("bake", help="bake a .blend file's light into CubeGI colour attributes")
    b.add_argument("input", help="the .blend file to bake (never written)")
    b.add_argument("-o", "--output", required=True, help="where to write the baked .blend")
    b.add_argument("--gltf", metavar="OUT.glb", help="also export the baked scene as glTF binary with its light kept above 1 "
                   "(float attributes _CUBEGI_LIGHT, _CUBEGI_INDIRECT; see docs/export.md)")
    bake_options(b)
    a = sub.add_parser("bake-animation", help="bake every frame's light into a cache folder beside the output (OUT.cubegi/)")
    a.add_argument("input", help="the .blend file to bake (never written)")
    a.add_argument("-o", "--output", required=True, help="where to write the baked .blend (its cache: OUT.cubegi/ beside it)")
    a.add_argument("--frames", nargs=2, type=int, metavar=("FIRST", "LAST"), help="frames to bake (default: the scene's range)")
    a.add_argument("--cache-dir", help=argparse.SUPPRESS)  # a chunk of a distributed run writes into the shared cache
    bake_options(a)
    _cluster_options(a)
    c = sub.add_parser("batch", help="bake many files on Dask (a local pool of processes, or a running scheduler)")
    c.add_argument("inputs", nargs="+", help="the .blend files to bake (never written)")
    c.add_argument("--out-dir", required=True, help="folder for NAME.blend and NAME.json per input, and batch.json")
    bake_options(c)
    _cluster_options(c)
    if more:
        more.parsers(sub)
    return p


def bake_options(p, demo=False):
    """The bake options (every setting in :data:`OPTIONS`, and what is not a setting)."""
    p.add_argument("--grid", nargs=3, type=int, metavar=("NX", "NY", "NZ"), help="probes along X, Y and Z")
    p.add_argument(
        "--quality", choices=[q.lower() for q in QUALITY],
        help="a preset for --cells, --cube-size and --bounces (each still overrides it): draft (4 cells, 16, 3 bounces), "
        "balanced (8, 16, 5), final (12, 32, 5). Every option not given takes the file's own CubeGI settings",
    )
    for o in OPTIONS:
        text = (o.help[0].lower() + o.help[1:]).replace("%", "%%")
        if o.switch:
            p.add_argument(o.flag, dest=o.name, action="store_const", const=not o.default, default=None,
                           help=f"turn {o.label} {'off' if o.default else 'on'}: {text}")
        else:
            default = "none" if o.default is None else f"{o.default:,}" if o.kind is int else o.default
            p.add_argument(o.flag, dest=o.name, type=o.kind, metavar=o.metavar or o.kind.__name__.upper(), default=None,
                           help=f"{text} (default: the file's setting; {default} in a new file)")
    p.add_argument("--reference", choices=["cycles"], help="also bake a path-traced reference and report CubeGI's error against it")
    p.add_argument("--reference-samples", type=int, default=256, help="Cycles samples for --reference (default 256)")
    if not demo:
        p.add_argument("--report", help="write the bake report (JSON) here")
        p.add_argument(
            "--lit", nargs="?", const="all", choices=[m.lower() for m in LitMode if m],
            help="also write CubeGI_lit: albedo x all light (all, the default) or x indirect light only",
        )
        p.add_argument(
            "--dynamic", nargs="+", metavar="NAME", default=[],
            help="objects left out of the capture and lit from the probe field (they move without a new bake)",
        )
        p.add_argument(
            "--only", nargs="+", metavar="NAME",
            help="write light into these mesh objects only; the others light and shadow them as in a full bake and keep "
            "the light they have (as Bake Selected)",
        )


def _cluster_options(p):
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, help="bake on a local Dask pool of this many worker processes")
    g.add_argument("--scheduler", metavar="ADDRESS", help="bake on a running Dask scheduler (tcp://host:8786)")


def _forwarded(args):
    """The bake options given in ``args`` as command-line words, for the bakes a cluster runs
    (each bake takes the rest from its file)."""
    words = ["--quality", args.quality] if args.quality else []
    for o in OPTIONS:
        if getattr(args, o.name) is not None:
            words += o.words(getattr(args, o.name))
    if args.grid:
        words += ["--grid", *map(str, args.grid)]
    if args.reference:
        words += ["--reference", args.reference, "--reference-samples", str(args.reference_samples)]
    if getattr(args, "lit", None):
        words += ["--lit", args.lit]
    if getattr(args, "dynamic", None):
        words += ["--dynamic", *args.dynamic]
    if getattr(args, "only", None):
        words += ["--only", *args.only]
    return words


def cmd_batch(args):
    checked_settings(args)
    if args.workers is not None and args.workers < 1:
        raise BakeError(f"--workers must be 1 or more, got {args.workers}")
    # A file that cannot be baked (missing, not a .blend) is reported in the summary, as a
    # file that fails to bake is; the others are baked.
    inputs, refused = [], {}
    for f in args.inputs:
        try:
            inputs.append(_check_input(f)[0])
        except BakeError as exc:
            inputs.append(os.path.realpath(f))
            refused[inputs[-1]] = str(exc)
    out_dir = os.path.abspath(args.out_dir)
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise BakeError(f"--out-dir {args.out_dir!r} is a file; give a folder")
    os.makedirs(out_dir, exist_ok=True)
    for src in inputs:
        name = os.path.splitext(os.path.basename(src))[0]
        files.writable_target(os.path.join(out_dir, f"{name}.blend"), "output", [(s, "an input") for s in inputs])
    from . import cluster

    summary = cluster.batch(inputs, out_dir, _forwarded(args), workers=args.workers or (None if args.scheduler else 2),
                            scheduler=args.scheduler, log=lambda m: print(f"cubegi: {m}", flush=True), refused=refused)
    for line in cluster.summary_lines(summary):
        print(f"cubegi: {line}", flush=True)
    print(f"cubegi: wrote {os.path.join(out_dir, 'batch.json')}", flush=True)
    failed = summary.count(cluster.BatchStatus.FAILED)
    if failed:
        raise BakeError(f"{failed} of {len(summary.files)} files failed; the rest are baked")


def _given(args):
    """The bake settings the arguments set (name -> value); a file's own settings give the rest."""
    given = {o.name: o.given(getattr(args, o.name)) for o in OPTIONS if getattr(args, o.name) is not None}
    if args.quality:
        given["quality"] = args.quality
    return given


def _validated(make):
    """``make()``'s BakeSettings, validated; a BakeError names the option."""
    try:
        return make().validate()
    except BakeError as exc:
        option = f"--{exc.setting.replace('_', '-')}: " if getattr(exc, "setting", None) else ""
        raise BakeError(f"{option}{exc}") from None


def checked_settings(args):
    """The arguments checked before Blender starts: the settings they give over the defaults,
    validated (a BakeError names the option)."""
    if args.grid is not None and min(args.grid) < 1:
        raise BakeError(f"--grid needs three integers >= 1, got {' '.join(map(str, args.grid))}")
    if args.reference and args.reference_samples < 1:
        raise BakeError(f"--reference-samples must be 1 or more, got {args.reference_samples}")
    given = _given(args)
    quality = given.pop("quality", "balanced")
    return _validated(lambda: BakeSettings.preset(quality, **given))


def _file_settings(bpy, args):
    """The settings of a bake of the open file: the arguments given, then the file's own
    CubeGI settings (Quality, Near Field, shadow-map sizes, ...): one file bakes the same on
    every machine."""
    from . import props

    return _validated(lambda: props.bake_settings(bpy.context.scene, _given(args)))


def _file_lit(bpy, args):
    """The lit colour to write: ``--lit``'s, else the file's Lit Color setting (None: none)."""
    return LitMode.of(getattr(args, "lit", None) or bpy.context.scene.cubegi.lit)


def _check_input(path):
    src = os.path.realpath(path)
    if not os.path.isfile(src):
        raise BakeError(f"input file does not exist: {path}")
    with open(src, "rb") as fh:
        magic = fh.read(7)
    if magic != BLEND_MAGIC and not magic.startswith(GZIP_MAGIC) and not magic.startswith(ZSTD_MAGIC):
        raise BakeError(f"input is not a .blend file: {path}")
    return src, magic != BLEND_MAGIC


def _check_io(args):
    """``(input, compressed, output, report)``: resolved paths, every one checked."""
    src, compressed = _check_input(args.input)
    dst = files.writable_target(args.output, "output", [(src, "input")])
    report = None
    if args.report:
        report = files.writable_target(args.report, "report", [(src, "input"), (dst, "output")])
    return src, compressed, dst, report


def print_progress(step):
    interrupts.check()  # an interrupt that came in a Blender handler
    print(f"cubegi: [{step.done}/{step.total}] {step.message}", flush=True)


def save_blend(compress):
    import bpy

    def write(tmp):
        result = bpy.ops.wm.save_as_mainfile(filepath=tmp, copy=True, check_existing=False, compress=compress)
        if result != {"FINISHED"}:
            raise RuntimeError("Blender did not save the file")

    return write


def blender():
    """bpy, with the extension registered (a file's probe grids and settings are read
    through its properties) until the process ends."""
    import bpy

    if not hasattr(bpy.types.Scene, "cubegi"):  # the bpy module: no Blender start-up enabled the extension
        importlib.import_module(__package__.rpartition(".")[0]).register_in_process()
    return bpy


def _open_for_baking(bpy, path):
    """Open the input with its UI (so the output keeps the user's layout), in Object Mode
    (a file saved in Edit Mode is baked as its edit data stands)."""
    try:
        bpy.ops.wm.open_mainfile(filepath=path, load_ui=True)
    except RuntimeError as exc:
        reason = str(exc).strip().splitlines()[-1].removeprefix("Error: ")
        raise BakeError(f"cannot read the input: {reason}") from None
    ob = bpy.context.view_layer.objects.active
    if ob is not None and ob.mode != "OBJECT":
        bpy.ops.object.mode_set(mode="OBJECT")


def _mark_dynamic(bpy, names):
    """Set Object > CubeGI > Dynamic on the named objects of the loaded copy."""
    missing = [n for n in names if n not in bpy.data.objects or bpy.data.objects[n].type != "MESH"]
    if missing:
        raise BakeError(f"--dynamic: no mesh object named {', '.join(map(repr, missing))} in the file")
    for name in names:
        bpy.data.objects[name].cubegi.dynamic = True


def _only(bpy, names):
    """The ``--only`` objects as a set of ``session_uid`` (None without the option), each a mesh
    object of the file."""
    if not names:
        return None
    missing = [n for n in names if n not in bpy.data.objects or bpy.data.objects[n].type != "MESH"]
    if missing:
        raise BakeError(f"--only: no mesh object named {', '.join(map(repr, missing))} in the file")
    return {bpy.data.objects[n].session_uid for n in names}


def cmd_bake(args):
    settings = checked_settings(args)
    src, compressed, dst, report_path = _check_io(args)
    gltf_path = None
    if args.gltf:
        gltf_path = files.writable_target(args.gltf, "glTF export", [(src, "input"), (dst, "output"), (report_path, "report")])
    bpy = blender()

    from . import pipeline

    _open_for_baking(bpy, src)
    _mark_dynamic(bpy, args.dynamic)
    settings, lit = _file_settings(bpy, args), _file_lit(bpy, args)
    from .animation import detach_cache

    detach_cache(bpy.context.scene)  # the output shows this bake's light, not an older animation's
    report = pipeline.bake(bpy.context, settings, tuple(args.grid) if args.grid else None, lit=lit,
                           reference_samples=args.reference_samples if args.reference else None, progress=print_progress,
                           only=_only(bpy, args.only))
    report.input, report.output = src, dst
    jobs = [(dst, save_blend(compressed))]
    if report_path:
        jobs.append((report_path, files.text(report.to_json())))
    if gltf_path:
        from . import export

        jobs.append((gltf_path, lambda tmp: export.write_glb(bpy.context, tmp)))
    files.write_all(jobs)
    print_summary(report)


def print_summary(report):
    for line in report.summary_lines():
        print(f"cubegi: {line}", flush=True)


def cmd_bake_animation(args):
    settings = checked_settings(args)
    src, compressed, dst, report_path = _check_io(args)
    from .animation import cache_folder, cache_link, check_cache_folder

    folder = os.path.abspath(args.cache_dir) if args.cache_dir else cache_folder(dst)
    check_cache_folder(folder, "move it or give another output")
    if args.frames and args.frames[1] < args.frames[0]:
        raise BakeError(f"--frames: the last frame comes before the first ({args.frames[0]} {args.frames[1]})")
    if args.workers is not None or args.scheduler:
        return _bake_animation_on_cluster(args, src, dst, report_path)
    bpy = blender()
    from ..cubegi_engine.bake import run
    from .animation import bake_animation_steps

    _open_for_baking(bpy, src)
    _mark_dynamic(bpy, args.dynamic)
    scene = bpy.context.scene
    first, last = args.frames or (scene.frame_start, scene.frame_end)
    settings, lit = _file_settings(bpy, args), _file_lit(bpy, args)
    try:
        result = run(bake_animation_steps(bpy.context, settings, range(first, last + 1), folder,
                                          tuple(args.grid) if args.grid else None, lit, only=_only(bpy, args.only)), print_progress)
    except KeyboardInterrupt as exc:
        kept = getattr(exc, "kept", None)
        raise Interrupted.keeping(exc, kept and f"{kept}; {dst} was not written; a run again bakes every frame") from None
    scene.cubegi.animation_cache = folder
    scene.frame_set(first)  # the saved file shows the first frame's light
    scene.cubegi.animation_cache = cache_link(folder)  # beside the output
    jobs = [(dst, save_blend(compressed))]
    if report_path:
        text = json.dumps({"input": src, "output": dst, **result.to_dict()}, indent=2, allow_nan=False)
        jobs.append((report_path, files.text(text)))
    files.write_all(jobs)
    per = result.seconds / len(result.frames)
    print(f"cubegi: baked {len(result.frames)} frames in {result.seconds:.2f} s ({per * 1000:.0f} ms a frame; "
          + ", ".join(f"{n} {p}" for p, n in result.paths().items()) + f") into {folder}", flush=True)


def _bake_animation_on_cluster(args, src, dst, report_path):
    if args.workers is not None and args.workers < 1:
        raise BakeError(f"--workers must be 1 or more, got {args.workers}")
    if not args.frames:
        raise BakeError("--frames FIRST LAST is needed with --workers or --scheduler")
    from . import cluster

    words = _forwarded(args)
    result = cluster.bake_animation(src, dst, args.frames[0], args.frames[1], words, workers=args.workers,
                                    scheduler=args.scheduler, log=lambda m: print(f"cubegi: {m}", flush=True))
    if report_path:
        text = json.dumps({"input": src, "output": dst, **result.to_dict()}, indent=2, allow_nan=False)
        files.write_all([(report_path, files.text(text))])
    if result.up_to_date:
        print(f"cubegi: {result.cache} is up to date: the input, the options and CubeGI are what its frames were "
              "baked from; nothing baked", flush=True)
        return
    print(f"cubegi: baked {len(result.frames)} frames in {len(result.chunks)} chunks in {result.seconds:.2f} s "
          f"into {result.cache}", flush=True)


def _written_before():
    """What an interrupted command had written (each file whole), in words."""
    if not files.written:
        return "nothing was written"
    return f"{', '.join(files.written)} {'was' if len(files.written) == 1 else 'were'} written (whole) before it stopped"


@dataclass(frozen=True)
class Commands:
    """Commands a caller adds to the command line: ``parsers(subparsers)`` adds their
    parsers, ``run`` maps each name to its function of the parsed arguments (the source
    tree's ``demo`` and ``benchmark``: ``tools/cli.py``)."""

    parsers: Callable
    run: dict[str, Callable]


def main(argv=None, prog="python -m cubegi_engine", more=None):
    """Run the command line; returns the exit status (0 done, 2 refused, 3 CubeGI failed,
    128 + the signal when interrupted). The same for ``python -m cubegi_engine`` and
    ``blender -c cubegi`` (:mod:`.command`); ``more``: :class:`Commands` added to these."""
    commands = {"bake": cmd_bake, "bake-animation": cmd_bake_animation, "batch": cmd_batch, **(more.run if more else {})}
    try:
        args = _parser(prog, more).parse_args(argv)
    except SystemExit as exc:  # --help, or a usage error argparse has printed
        return int(exc.code or 0)
    try:
        files.written.clear()
        with interrupts.interruptible():
            commands[args.command](args)
    except BakeError as exc:
        print(f"{ERROR_PREFIX}{exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        how = "interrupted" if signum == signal.SIGINT else f"stopped by {signal.Signals(signum).name}"
        print(f"cubegi: {how}; {getattr(exc, 'kept', None) or _written_before()}", file=sys.stderr)
        return 128 + signum
    except MemoryError:  # the scene is larger than this machine's memory: the user's situation, not a defect
        print(f"{ERROR_PREFIX}out of memory: the scene is too large for this machine at these settings; bake with fewer "
              "probes (--quality draft, --cells), a smaller --capture-triangles, or on a machine with more memory; "
              "nothing was written", file=sys.stderr)
        return 2
    except Exception as exc:  # a defect: one line, the traceback on request
        if os.environ.get(DEBUG_ENV):
            raise
        print(f"{ERROR_PREFIX}the bake failed ({type(exc).__name__}: {exc}); nothing was written. "
              f"Set {DEBUG_ENV}=1 for the traceback and please report it", file=sys.stderr)
        return 3
    return 0
