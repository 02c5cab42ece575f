"""Write docs/blender-support.md from the conformance suite's last run.

Usage: python scripts/support_table.py [RESULTS.json] [OUT.md]
(defaults: out/conformance.json, written by tests/blender/test_conformance.py, and
docs/blender-support.md). Needs no bpy.
"""

import json
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

HEADER = """# What CubeGI reads of a Blender scene

CubeGI's answer is the diffuse light Cycles renders for the same file. Each row below is one
Blender feature, baked by CubeGI and by Cycles' Diffuse bake of the same tiny scene in the
conformance suite (`tests/blender/test_conformance.py`; this page is written from its last
run by `scripts/support_table.py`). *Read exactly*: CubeGI reads the feature; the error is
its direct light against Cycles' at 64 samples (Cycles' own noise there is about 1-3%), or
for a material its indirect light (which CubeGI bakes here with few probes and one bounce
plus the tail: -9% to -12% whatever the diffuse material; a Principled BSDF, whose specular
layer sends on light too, -5% to +1%).
*Approximated*: read, by the model named, with the error measured.
*Not supported*: CubeGI does not read it, and every bake of a file that uses it says so in a
note, quoted here, naming the object and what the bake does instead.

Last run: Blender {blender}.

| feature | support | measured against Cycles, or the note |
|---|---|---|
"""


def row(feature, r):
    if r["support"] != "not supported":
        if "direct_rel_bias" in r or "indirect_rel_bias" in r:
            part = "direct" if "direct_rel_bias" in r else "indirect"
            what = f"{part} light: bias {100 * r[part + '_rel_bias']:+.1f}%, rel. RMSE {100 * r[part + '_rel_rmse']:.1f}%"
            if "channel_bias" in r:
                what += ", per channel (R, G, B) " + ", ".join(f"{100 * c:+.1f}%" for c in r["channel_bias"])
        else:
            what = r.get("note", "")
            what = f"note: \u201c{what}\u201d" if "note" in r["support"] else what
    else:
        what = f"note: \u201c{r.get('note') or 'MISSING'}\u201d"
    return f"| {feature} | {r['support']} | {what} |"


def main(results, out):
    with open(results) as fh:
        rows = json.load(fh)
    rank = {"read exactly": 0, "not supported": 2}
    order = sorted(rows, key=lambda k: (rank.get(rows[k]["support"], 1), k.lower()))
    blender = sorted({r["blender"] for r in rows.values()})
    text = HEADER.format(blender=", ".join(blender)) + "\n".join(row(k, rows[k]) for k in order) + "\n"
    with open(out, "w") as fh:
        fh.write(text)
    print(out)


if __name__ == "__main__":
    args = sys.argv[1:]
    main(args[0] if args else os.path.join(ROOT, "out", "conformance.json"),
         args[1] if len(args) > 1 else os.path.join(ROOT, "docs", "blender-support.md"))
