"""Error measures of baked light against a reference, per vertex, weighted by area.

Pure numpy; must not import bpy.

With reference r, estimate x (``(s, 3)`` RGB, reduced to their channel mean) and each
point's share of the surface area a:

* ``rel_rmse``  = sqrt(sum a (x - r)^2 / sum a) / (sum a r / sum a)
* ``rel_bias``  = (sum a x - sum a r) / sum a r    (signed; + means too bright)
* ``p95_rel``   = the area-weighted 95th percentile of |x - r| / max(r, 1e-3 mean(r))

The floor in ``p95_rel`` keeps points the reference sees as black from dividing by zero.
"""

import numpy as np

__all__ = ["errors", "compare"]


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
