"""A bake report (the dict the pipeline returns) as a few lines of text, for the command
line and the add-on's panel. Pure Python."""


def summary_lines(report):
    """The report in a few lines of text (the CLI prints them; the add-on shows them)."""
    tail = report["tail"]
    lines = [
        f"baked {len(report['scene']['meshes_baked'])} meshes, {report['grid']['probes']} probes, "
        f"{len(report['bounces'])} bounces in {report['total_seconds']:.3f} s"
    ]
    for rec in report["bounces"]:
        lines.append(
            f"  bounce {rec['bounce']}: {rec['seconds'] * 1e3:.1f} ms, mean light {rec['mean']:.4g}, "
            f"x{rec['ratio_mean']:.3f} of the one before"
        )
    missing = f"estimated missing indirect light after bounce {len(report['bounces'])}: {100 * report['estimated_remaining_error']:.3g}%"
    if tail.get("added"):
        missing += f" ({tail['method']}, added to CubeGI)"
    elif tail.get("method", "none") != "none":
        missing += " (not added)"
    lines.append(missing)
    ref = report.get("reference")
    if ref:
        lines.append(f"Cycles reference, {ref['samples']} samples: {ref['seconds']:.2f} s against CubeGI's {ref['cubegi_seconds']:.2f} s")
        for part in ("direct", "indirect", "total"):
            e = ref["errors"][part]
            lines.append(
                f"  {part:8s} rel. RMSE {100 * e['rel_rmse']:6.2f}%  bias {100 * e['rel_bias']:+6.2f}%  p95 {100 * e['p95_rel']:6.2f}%"
            )
    lines += [f"warning: {w}" for w in report.get("warnings", [])]
    lines += [f"note: {n}" for n in report["scene"]["notes"]]
    return lines
