"""How far the bounce series has converged, and the light it has not reached yet.

Pure numpy; must not import bpy.

Bounce k's light is ``T^k d`` for the direct light ``d`` and the bounce operator ``T``
(gather, project, interpolate, times albedo), so the series shrinks like the powers of
``T``'s largest eigenvalue, about the scene's mean albedo seen through its openness. After a
few bounces each bounce is nearly the one before times a fixed ratio ``r`` (per colour
channel), and the light still missing after bounce ``N`` is close to

    tail = l_N * r / (1 - r)        (the rest of a geometric series),

which is cheap and good when little is missing. When much is missing (stiff, high-albedo
scenes, where ``1 / (1 - r)`` magnifies any error in ``r``) the tail is solved for instead:
``sum_{k>N} T^k d`` is ``(I - M)^-1 c_{N+1}`` in probe-coefficient space (M: one bounce from
probe coefficients to probe coefficients), a small linear system solved by GMRES with one
bounce per iteration.
"""

import numpy as np

from .working import checkpoint

__all__ = ["ratios", "converges", "geometric_factor", "remaining_share", "geometric_tail", "gmres", "fixed_point"]

# Each bounce keeps this share of the light before (or more): the series is taken not to
# converge (albedo 1 in a closed room), the tail is not added and the bake warns.
DIVERGENT_RATIO = 0.999
# Up to this estimated share of the indirect light still missing, the geometric tail is
# used; above it, the tail is solved for.
GEOMETRIC_TAIL_LIMIT = 0.01
# A fixed-point iteration stops once the error it estimates is left is at most this share of
# the vector's largest entry, or after FIXED_POINT_STEPS steps (see fixed_point).
FIXED_POINT_TOLERANCE = 1e-6
FIXED_POINT_STEPS = 64
# The steps an Anderson mix looks back on, and how far above the least change so far a
# change sends it back to plain steps (see fixed_point).
ANDERSON_MEMORY, RESTART = 5, 10.0


def ratios(previous_mean, mean):
    """Per-channel ratio of a bounce's mean light to the one before (0 where there is none)."""
    prev = np.asarray(previous_mean, dtype=np.float64)
    cur = np.asarray(mean, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(prev > 0.0, cur / np.where(prev > 0.0, prev, 1.0), 0.0)
    return np.nan_to_num(r, nan=0.0, posinf=np.inf)


def converges(ratio):
    return bool(np.all(np.asarray(ratio) < DIVERGENT_RATIO))


def geometric_factor(ratio):
    """``r / (1 - r)`` per channel; inf where the series does not converge."""
    r = np.asarray(ratio, dtype=np.float64)
    out = np.full(r.shape, np.inf)
    ok = r < DIVERGENT_RATIO
    out[ok] = r[ok] / (1.0 - r[ok])
    return out


def remaining_share(indirect_mean, last_mean, ratio):
    """Estimated share of the full indirect light still missing: tail / (indirect + tail).

    All arguments are per channel ``(3,)``; channels are summed (a grey measure). 1.0 when
    the series does not converge, 0.0 when there is no indirect light at all.
    """
    factor = geometric_factor(ratio)
    last = np.asarray(last_mean, dtype=np.float64)
    if not np.all(np.isfinite(factor[last > 0])):
        return 1.0
    tail = float((last * np.where(last > 0, factor, 0.0)).sum())
    have = float(np.asarray(indirect_mean, dtype=np.float64).sum())
    if have + tail <= 0.0:
        return 0.0
    return tail / (have + tail)


def geometric_tail(last, ratio):
    """The rest of the series after ``last`` ``(s, 3)``, each channel geometric at ``ratio``."""
    factor = geometric_factor(ratio)
    factor = np.where(np.isfinite(factor), factor, 0.0)
    return np.asarray(last, dtype=np.float64) * factor[None, :]


def gmres(apply, b, tol=1e-5, max_iter=60):
    """Solve ``apply(x) = b`` by GMRES without restarts.

    ``apply`` maps a 1-D float64 vector to one of the same length. Returns ``(x, iterations,
    relative residual)``. The Krylov basis is kept whole, so ``max_iter`` vectors of b's size
    are stored; b is small here (probes x 27).
    """
    b = np.asarray(b, dtype=np.float64)
    beta = float(np.linalg.norm(b))
    if beta == 0.0 or not np.isfinite(beta):
        return np.zeros_like(b), 0, 0.0
    basis = [b / beta]
    h = np.zeros((max_iter + 1, max_iter))
    y = np.zeros(0)
    residual = 1.0
    j = 0
    for j in range(max_iter):
        checkpoint()  # (a cancelled bake's tail stops here)
        w = np.asarray(apply(basis[j]), dtype=np.float64)
        for i in range(j + 1):  # modified Gram-Schmidt
            h[i, j] = float(w @ basis[i])
            w = w - h[i, j] * basis[i]
        h[j + 1, j] = float(np.linalg.norm(w))
        rhs = np.zeros(j + 2)
        rhs[0] = beta
        y = np.linalg.lstsq(h[: j + 2, : j + 1], rhs, rcond=None)[0]
        residual = float(np.linalg.norm(h[: j + 2, : j + 1] @ y - rhs)) / beta
        if residual <= tol or h[j + 1, j] <= 1e-14 * beta:
            break
        basis.append(w / h[j + 1, j])
    x = np.stack(basis[: len(y)], axis=1) @ y
    return x, j + 1, residual


def fixed_point(step, x, tol=FIXED_POINT_TOLERANCE, max_steps=FIXED_POINT_STEPS, gain=None):
    """``x = step(x)`` solved from ``x`` by Anderson acceleration (each step's input mixes the
    last ANDERSON_MEMORY steps' outputs so that their change is least, GMRES's answer for a
    linear ``step``) until the error left, estimated from the last step's change and the
    map's ``gain`` (a bound on how much of a change a step keeps; None: the ratio of the last
    two changes), ``change r / (1 - r)`` (the rest of a geometric series), is at most ``tol``
    of the largest entry (max norm), or ``max_steps`` steps: ``(x, steps)``, ``x`` a step's
    output. For contractions such as the near field's sum of bounces (each step gathers
    once more, taking at most the albedo of the light before: the light inside a white
    teapot keeps 0.9 of itself a step, and plain steps would take a hundred and fifty)."""
    shape = np.shape(x)
    x = np.asarray(x, dtype=np.float64).ravel()
    changes, outputs, last, gram = [], [], None, np.zeros((0, 0))
    steps, before, out, least = 0, None, x, np.inf
    for steps in range(1, max_steps + 1):
        checkpoint()  # (a cancelled bake's tail stops here)
        out = np.asarray(step(x.reshape(shape)), dtype=np.float64).ravel()
        f = out - x
        change = float(np.max(np.abs(f), initial=0.0))
        r = gain if gain is not None else (min(change / before, 0.999) if before else 0.0)
        if not change * (1.0 + r / (1.0 - r)) > tol * float(np.max(np.abs(out), initial=0.0)):
            break
        if before is not None and change > RESTART * least:  # the mix went astray: start it again
            changes, outputs, gram = [], [], np.zeros((0, 0))
        elif last is not None:
            changes.append(f - last[0])
            outputs.append(out - last[1])
            kept = len(gram) - min(len(gram), ANDERSON_MEMORY - 1)  # the products of the changes still kept
            gram = _gram_with(gram[kept:, kept:], changes[-ANDERSON_MEMORY:])
            del changes[:-ANDERSON_MEMORY], outputs[:-ANDERSON_MEMORY]
        before, last, least = change, (f, out), min(least, change)
        x = out
        if changes:
            # The least-squares mix by its normal equations (a few columns: no (n, k) copy).
            mix = np.linalg.lstsq(gram + 1e-12 * np.trace(gram) * np.eye(len(changes)), [a @ f for a in changes], rcond=None)[0]
            x = out.copy()
            for m, o in zip(mix, outputs):
                x -= m * o
    return out.reshape(shape), steps


def _gram_with(gram, changes):
    """The Gram matrix of ``changes`` (a list of vectors) from ``gram``, that of all of them
    but the last: only the last one's products are taken (a step's one new column, not the
    whole matrix again: at a million points each product reads tens of MB)."""
    row = np.array([changes[-1] @ a for a in changes])
    out = np.empty((len(changes), len(changes)))
    out[:-1, :-1] = gram
    out[-1, :] = row
    out[:, -1] = row
    return out
