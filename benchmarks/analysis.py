"""Benchmark analysis: Cycles' time to reach an error, the best trade-off, the tables.

Pure numpy; must not import bpy. The runs themselves are made by
``benchmarks.sweep``; each is a record::

    {"scene": str, "method": "cubegi" | "cycles", "settings": {...}, "seconds": float,
     "seconds_by_part": {"indirect": s, "total": s},
     "errors": {"direct": {...}, "indirect": {...}, "total": {...}}}

``seconds_by_part`` is the time a method needs for that part alone: CubeGI computes both
parts in one bake, so both are its total time; Cycles bakes direct and indirect light as
separate passes, so its indirect time is the indirect pass alone (which favours Cycles).
"""

import math

PARTS = ("indirect", "total")
MEASURES = ("rel_rmse", "rel_bias", "p95_rel")


def _seconds(record, part):
    return record.get("seconds_by_part", {}).get(part, record["seconds"])


def cycles_time_at(error, cycles_records, part="indirect", measure="rel_rmse"):
    """Seconds Cycles needs for ``error`` (of ``part``, ``measure``), and how it was found.

    The curve is Cycles' runs at increasing samples; between two runs the time is
    interpolated on log-log axes. Below the lowest error measured it is extrapolated with
    Monte Carlo's error ~ 1 / sqrt(time) ("extrapolated"); above the highest, Cycles'
    cheapest run already reaches it and its time is an upper bound ("at most").
    """
    pts = sorted((_seconds(r, part), abs(r["errors"][part][measure])) for r in cycles_records)
    if not pts:
        return math.nan, "no Cycles runs"
    pts = [(t, e) for t, e in pts if t > 0 and e > 0]
    if not pts or error <= 0:
        return math.nan, "no error to match"
    if error >= pts[0][1]:
        return pts[0][0], "at most"
    for (t0, e0), (t1, e1) in zip(pts, pts[1:]):
        if e0 >= error >= e1 and e0 > e1:
            f = (math.log(e0) - math.log(error)) / (math.log(e0) - math.log(e1))
            return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0))), "interpolated"
    t_last, e_last = min(pts, key=lambda p: p[1])
    if error >= e_last:  # a non-monotone curve: the first run at or below the error
        return next(t for t, e in pts if e <= error), "measured"
    return t_last * (e_last / error) ** 2, "extrapolated"


def speedups(records, part="indirect", measure="rel_rmse"):
    """Per CubeGI record of each scene: Cycles' time at its error over its time."""
    out = []
    for scene in sorted({r["scene"] for r in records}):
        cyc = [r for r in records if r["scene"] == scene and r["method"] == "cycles"]
        for r in records:
            if r["scene"] != scene or r["method"] != "cubegi":
                continue
            err = abs(r["errors"][part][measure])
            t_cyc, how = cycles_time_at(err, cyc, part, measure)
            t = _seconds(r, part)
            out.append({"scene": scene, "record": r, "error": err, "seconds": t, "cycles_seconds": t_cyc,
                        "how": how, "speedup": t_cyc / t if t > 0 else math.nan})
    return out


def pareto(points):
    """The (seconds, error) points no other point beats on both; sorted by seconds."""
    front, best = [], math.inf
    for p in sorted(points, key=lambda p: (p["seconds"], p["error"])):
        if p["error"] < best:
            front.append(p)
            best = p["error"]
    return front


def best_tradeoffs(records, part="indirect", measure="rel_rmse"):
    """Per scene, the CubeGI setting on the error-time front with the largest speed-up over
    Cycles at equal error (one whose speed-up is only an upper bound, "at most", is taken
    only if no other setting has a measured one)."""
    by_scene = {}
    for s in speedups(records, part, measure):
        by_scene.setdefault(s["scene"], []).append(s)
    best = {}
    for scene, items in by_scene.items():
        front = pareto(items)
        solid = [s for s in front if s["how"] != "at most"]
        pool = solid or front
        best[scene] = max(pool, key=lambda s: (s["speedup"] if math.isfinite(s["speedup"]) else -1.0))
    return best


def defaults(records, part="indirect", measure="rel_rmse"):
    """Per scene and per default (``settings["default"]``: "before", "after"), the speed-up
    entry (see :func:`speedups`) of the bake a new user gets without options."""
    out = {}
    for s in speedups(records, part, measure):
        which = s["record"]["settings"].get("default")
        if which:
            out.setdefault(s["scene"], {})[which] = s
    return out


def describe(settings):
    return ", ".join(f"{k} {v}" for k, v in settings.items())


def _pct(x):
    return f"{100 * x:.1f}%"


def markdown(records, meta=None):
    """``results.md``: the summary of best trade-offs, then a table per scene."""
    lines = ["# CubeGI benchmark", ""]
    if meta:
        lines += [f"- {k}: {v}" for k, v in meta.items()] + [""]
    lines += [
        "Errors are per vertex, weighted by area, against the scene's high-sample Cycles reference: "
        "relative RMSE, relative mean bias and the 95th percentile of the relative error "
        "(see `cubegi_engine/metrics.py`); vertices of black materials are left out (Cycles' Diffuse bake "
        "reports no light on them). Cycles' indirect time is its indirect pass alone.",
        "",
    ]
    for part in PARTS:
        best = best_tradeoffs(records, part)
        lines += [
            f"## Best trade-off, {part} light (relative RMSE)",
            "",
            "| scene | CubeGI setting | CubeGI time | error | Cycles time at that error | speed-up |",
            "|---|---|---|---|---|---|",
        ]
        for scene, s in sorted(best.items()):
            how = "" if s["how"] == "interpolated" else f" ({s['how']})"
            lines.append(
                f"| {scene} | {describe(s['record']['settings'])} | {s['seconds']:.2f} s | {_pct(s['error'])} | "
                f"{s['cycles_seconds']:.2f} s{how} | {s['speedup']:.1f}x |"
            )
        lines.append("")
    table = defaults(records)
    if table:
        lines += [
            "## The default setting, indirect light (relative RMSE)",
            "",
            "before: the Balanced preset (8 cells along the longest side, 16^2 faces, 5 bounces + tail) without the near "
            "field; after: the same with it (the default). Both as a new user gets them (the fitted grid, probes that light "
            "no vertex left out).",
            "",
            "| scene | before: time | error | speed-up over Cycles | after: time | error | Cycles at that error | speed-up |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for scene, d in sorted(table.items()):
            b, a = d.get("before"), d.get("after")
            if not (a and b):
                continue
            lines.append(
                f"| {scene} | {b['seconds']:.2f} s | {_pct(b['error'])} | {b['speedup']:.1f}x | {a['seconds']:.2f} s | "
                f"{_pct(a['error'])} | {a['cycles_seconds']:.2f} s | {a['speedup']:.1f}x |"
            )
        lines += [
            "",
            "What each part of the default buys: the default without the near field (before), with its probes inside "
            "geometry left at their cell centres (probes in place: the capture then leaves them out), the default, and, "
            "where the scene has a sky, the default with the sky's direct light per vertex (sky per vertex, an option).",
            "",
            "| scene | default | time | indirect error | direct error | speed-up over Cycles |",
            "|---|---|---|---|---|---|",
        ]
        for scene, d in sorted(table.items()):
            for which in ("before", "probes in place", "after", "sky per vertex"):
                if which in d:
                    x = d[which]
                    lines.append(
                        f"| {scene} | {which} | {x['seconds']:.2f} s | {_pct(x['error'])} | "
                        f"{_pct(x['record']['errors']['direct']['rel_rmse'])} | {x['speedup']:.1f}x |"
                    )
        lines.append("")
    lines += _stages(records) + _surfaces(records)
    for scene in sorted({r["scene"] for r in records}):
        lines += [
            f"## {scene}",
            "",
            "| method | settings | seconds | indirect RMSE | indirect bias | indirect p95 | total RMSE | total bias | direct RMSE |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        rows = [r for r in records if r["scene"] == scene]
        rows.sort(key=lambda r: (r["method"], r["seconds"]))
        for r in rows:
            e = r["errors"]
            lines.append(
                f"| {r['method']} | {describe(r['settings'])} | {r['seconds']:.2f} | {_pct(e['indirect']['rel_rmse'])} | "
                f"{_pct(e['indirect']['rel_bias'])} | {_pct(e['indirect']['p95_rel'])} | {_pct(e['total']['rel_rmse'])} | "
                f"{_pct(e['total']['rel_bias'])} | {_pct(e['direct']['rel_rmse'])} |"
            )
        lines.append("")
    return "\n".join(lines)


# The bake's stages in the order they run (BakeReport.timings); "tables" holds the near field.
STAGES = ("collect", "placement", "simplify", "gpu_setup", "capture", "tables", "near_field", "direct", "bounces", "tail", "write")


def _default_after(records):
    return {r["scene"]: r for r in records if r["method"] == "cubegi" and r["settings"].get("default") == "after"}


def _stages(records):
    """The default bake's time per stage, per scene, with each stage's share of the bake."""
    rows = {s: r["timings"] for s, r in _default_after(records).items() if r.get("timings")}
    if not rows:
        return []
    lines = ["## The default bake, stage by stage (seconds, share of the bake)", "",
             "| scene | total | " + " | ".join(STAGES) + " |", "|---|---|" + "---|" * len(STAGES)]
    for scene, t in sorted(rows.items()):
        total = t.get("total") or sum(t.get(k, 0.0) for k in STAGES)
        cells = [f"{t[k]:.2f} ({100 * t[k] / total:.0f}%)" if k in t and total > 0 else "" for k in STAGES]
        lines.append(f"| {scene} | {total:.2f} | " + " | ".join(cells) + " |")
    return lines + ["", "The near field's time is part of the tables': what they waited for its rays (traced beside the "
                        "drawing of the probes) and spent deciding what its hits take.", ""]


def _surfaces(records, shown=12):
    """Per scene, the largest surfaces' mean light against the reference's (the default bake)."""
    lines = []
    for scene, r in sorted(_default_after(records).items()):
        surfaces = r.get("surfaces")
        if not surfaces:
            continue
        lines += [f"## {scene}: the default bake per surface (area-weighted mean, the {shown} largest, then the "
                  f"{shown} others holding the most squared indirect error)", "",
                  "| object | area share | direct: CubeGI | Cycles | difference | share of the squared error "
                  "| indirect: CubeGI | Cycles | difference | share of the squared error | indirect: Cycles, more samples |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        total = sum(x["area"] for x in surfaces.values())
        largest = sorted(surfaces, key=lambda n: -surfaces[n]["area"])[:shown]
        others = sorted((n for n in surfaces if n not in largest), key=lambda n: -surfaces[n].get("indirect_error_share", 0.0))
        for name in largest + others[:shown]:
            x = surfaces[name]
            cells = []
            for part in ("direct", "indirect"):
                ours, theirs = x[part]
                diff = f"{100 * (ours - theirs) / theirs:+.1f}%" if theirs > 0 else "n/a"
                share = x.get(f"{part}_error_share")
                cells += [f"{ours:.4g}", f"{theirs:.4g}", diff, "" if share is None else f"{100 * share:.1f}%"]
            fine = x.get("fine")
            if fine and fine["indirect"] > 0:
                cells.append(f"{fine['indirect']:.4g} at {fine['samples']} ({100 * (x['indirect'][0] - fine['indirect']) / fine['indirect']:+.1f}%)")
            else:
                cells.append("")
            lines.append(f"| {name} | {100 * x['area'] / total:.1f}% | " + " | ".join(cells) + " |")
        lines += ["", "A large surface of few vertices (a wall of a few quads) takes its mean from a handful of the "
                  "reference's vertices: it is baked again alone at more samples, and CubeGI's difference from that is "
                  "in brackets."] if any(surfaces[n].get("fine") for n in largest + others[:shown]) else []
        lines.append("")
        holders = r.get("error_holders")
        if holders:
            lines += [" ".join(f"Half of the squared {part} error is held by {h['points']:,} vertices "
                               f"({100 * h['area_share']:.1f}% of the area)." for part, h in holders.items()), ""]
    return lines


def plot(records, path):
    """``error_vs_time.png``: per scene, error against time on log-log axes, CubeGI's
    settings as points and Cycles as a curve; top row indirect, bottom row total light.
    Needs matplotlib (an optional dependency of the benchmark only); returns False
    without it."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    scenes = sorted({r["scene"] for r in records})
    fig, axes = plt.subplots(len(PARTS), len(scenes), figsize=(4.2 * len(scenes), 7.5), squeeze=False)
    for col, scene in enumerate(scenes):
        for row, part in enumerate(PARTS):
            ax = axes[row][col]
            cyc = sorted((r for r in records if r["scene"] == scene and r["method"] == "cycles"), key=lambda r: r["settings"]["samples"])
            cub = [r for r in records if r["scene"] == scene and r["method"] == "cubegi"]
            if cyc:
                ax.plot([_seconds(r, part) for r in cyc], [r["errors"][part]["rel_rmse"] for r in cyc], "o-", color="tab:red",
                        label="Cycles (samples)")
                for r in cyc:
                    ax.annotate(str(r["settings"]["samples"]), (_seconds(r, part), r["errors"][part]["rel_rmse"]), fontsize=7, color="tab:red")
            if cub:
                ax.scatter([_seconds(r, part) for r in cub], [r["errors"][part]["rel_rmse"] for r in cub], color="tab:blue", s=18,
                           label="CubeGI settings", zorder=3)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.grid(True, which="both", alpha=0.3)
            ax.set_title(f"{scene}: {part} light", fontsize=10)
            ax.set_xlabel("seconds")
            if col == 0:
                ax.set_ylabel("relative RMSE")
            if row == 0 and col == 0:
                ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True
