"""Error measures of baked light against a reference, per vertex, weighted by area.

Pure numpy; must not import bpy.

With reference r, estimate x (``(s, 3)`` RGB, reduced to their channel mean) and each
point's share of the surface area a:

* ``rel_rmse``  = sqrt(sum a (x - r)^2 / sum a) / (sum a r / sum a)
* ``rel_bias``  = (sum a x - sum a r) / sum a r    (signed; + means too bright)
* ``p95_rel``   = the area-weighted 95th percentile of |x - r| / max(r, 1e-3 mean(r))

The floor in ``p95_rel`` keeps points the reference sees as black from dividing by zero.

Where the error sits: each point's share of ``sum a (x - r)^2`` (:func:`squared_error`), and
how few points hold a given share of it (:func:`error_holders`; a room modelled as a few
large quads has a handful of vertices standing for most of its surface, and they can hold
most of the error).
"""

import numpy as np

__all__ = ["errors", "compare", "squared_error", "error_holders"]


def _weighted_quantile(values, weights, q):
    order = np.argsort(values)
    v, w = values[order], weights[order]
    c = np.cumsum(w)
    if c[-1] <= 0:
        return 0.0
    return float(v[np.searchsorted(c, q * c[-1])])


def errors(estimate, reference, areas):
    """The measures above as a dict; all zero when the reference has no light."""
    x = np.asarray(estimate, dtype=np.float64)
    r = np.asarray(reference, dtype=np.float64)
    if x.ndim == 2:
        x, r = x.mean(axis=1), r.mean(axis=1)
    a = np.asarray(areas, dtype=np.float64)
    total = a.sum()
    mean_r = (a * r).sum() / total if total > 0 else 0.0
    if mean_r <= 0:
        return {"rel_rmse": 0.0, "rel_bias": 0.0, "p95_rel": 0.0, "reference_mean": 0.0}
    rmse = np.sqrt((a * (x - r) ** 2).sum() / total)
    rel = np.abs(x - r) / np.maximum(r, 1e-3 * mean_r)
    return {
        "rel_rmse": float(rmse / mean_r),
        "rel_bias": float(((a * x).sum() - (a * r).sum()) / (a * r).sum()),
        "p95_rel": _weighted_quantile(rel, a, 0.95),
        "reference_mean": float(mean_r),
    }


def compare(direct, indirect, ref_direct, ref_indirect, areas):
    """:func:`errors` of the direct, indirect and total (direct + indirect) light."""
    return {
        "direct": errors(direct, ref_direct, areas),
        "indirect": errors(indirect, ref_indirect, areas),
        "total": errors(np.asarray(direct) + np.asarray(indirect), np.asarray(ref_direct) + np.asarray(ref_indirect), areas),
    }


def squared_error(estimate, reference, areas) -> np.ndarray:
    """``(s,)``: each point's ``a (x - r)^2`` (channel means), over their sum (all zero where
    the estimate is exact)."""
    x = np.asarray(estimate, dtype=np.float64)
    r = np.asarray(reference, dtype=np.float64)
    if x.ndim == 2:
        x, r = x.mean(axis=1), r.mean(axis=1)
    e = np.asarray(areas, dtype=np.float64) * (x - r) ** 2
    total = e.sum()
    return e / total if total > 0 else np.zeros_like(e)


def error_holders(estimate, reference, areas, share=0.5):
    """The fewest points holding at least ``share`` of the squared error
    (:func:`squared_error`): ``{"points": k, "area_share": their share of the area}``
    (0 and 0.0 where the estimate is exact)."""
    e = squared_error(estimate, reference, areas)
    if not e.any():
        return {"points": 0, "area_share": 0.0}
    order = np.argsort(-e, kind="stable")
    k = int(np.searchsorted(np.cumsum(e[order]), share * (1.0 - 1e-12))) + 1
    a = np.asarray(areas, dtype=np.float64)
    return {"points": k, "area_share": float(a[order[:k]].sum() / a.sum())}


# An object's mean light under this share of the scene's has no bias worth a percentage.
NEGLIGIBLE = 1e-3


def furthest_off(names, counts, light, reference, areas, most=3, least_share=0.05):
    """The objects that hold the most of the scene's error: up to ``most`` of those holding at
    least ``least_share`` of the total light's squared error, largest first, each ``{"name",
    "error_share", "direct_bias", "indirect_bias"}`` (their area-weighted mean against the
    reference's, None where the reference's mean is under NEGLIGIBLE of the scene's mean light:
    a panel Cycles gives 1e-4 is not "-100%"). ``names``/``counts``: the objects and their
    points, in the order of ``light`` and ``reference`` (``{"direct", "indirect"}``, each
    ``(s, 3)``) and ``areas (s,)``."""
    a = np.asarray(areas, dtype=np.float64)
    x = {k: np.asarray(v, dtype=np.float64).mean(axis=1) for k, v in light.items()}
    r = {k: np.asarray(v, dtype=np.float64).mean(axis=1) for k, v in reference.items()}
    share = squared_error(x["direct"] + x["indirect"], r["direct"] + r["indirect"], a)
    scene_mean = float(a @ (r["direct"] + r["indirect"])) / max(float(a.sum()), 1e-300)
    out, start = [], 0
    for name, count in zip(names, counts):
        sl = slice(start, start + int(count))
        start += int(count)
        bias, area = {}, float(a[sl].sum())
        for part in ("direct", "indirect"):
            theirs = float(a[sl] @ r[part][sl])
            seen = theirs > 0 and theirs > NEGLIGIBLE * scene_mean * area
            bias[f"{part}_bias"] = float(a[sl] @ x[part][sl]) / theirs - 1.0 if seen else None
        out.append({"name": name, "error_share": float(share[sl].sum()), **bias})
    out.sort(key=lambda o: -o["error_share"])
    return [o for o in out if o["error_share"] >= least_share][:most]
