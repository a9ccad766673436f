"""Knot vectors given as data per axis (`domain.knots`): validation and the grid-unit form the basis reads.

A knot vector of degree p over [lower, upper] is open (clamped): lower and upper each p + 1 times, nondecreasing
interior knots strictly inside, each repeated at most p times. A knot of multiplicity k leaves the B-splines
C^(p-k) there (the seed's {0,0,0,1,2,3,4,4,5,5,5}, p = 2: C0 at 4, C1 at the simple knots); k = p + 1 inside
would split the grid into two unconnected pieces, so it is refused. Axes without `domain.knots` keep the uniform
open knot vector of `domain.dx`. Host side only (numpy); basis.make_knot_bspline evaluates them in kernels.
"""

import numpy as np

from . import registry


def knot_problem(knots, p: int, lower: float, upper: float):
    """None when `knots` is a valid open knot vector of degree p over [lower, upper], else what is wrong."""
    t = [float(k) for k in knots]
    if len(t) < 2 * (p + 1):
        return f"needs at least {2 * (p + 1)} knots for degree {p} ({p + 1} at each end), got {len(t)}"
    for i in range(1, len(t)):
        if t[i] < t[i - 1]:
            return f"knots must not decrease: knot {i} ({t[i]:g}) is below knot {i - 1} ({t[i - 1]:g})"
    tol = 1e-9 * (upper - lower)
    if abs(t[0] - lower) > tol or abs(t[-1] - upper) > tol:
        return (f"must span the domain: the first knot must be domain.lower ({lower:g}) and the last domain.upper "
                f"({upper:g}), got {t[0]:g} and {t[-1]:g}")
    values, counts = _multiplicities(t, tol)
    for end, k in ((values[0], counts[0]), (values[-1], counts[-1])):
        if k != p + 1:
            return (f"the end knot {end:g} appears {k} times: an open knot vector of degree {p} repeats each end "
                    f"exactly {p + 1} times")
    for value, k in zip(values[1:-1], counts[1:-1]):
        if k > p:
            return (f"the interior knot {value:g} appears {k} times: at most {p} (degree {p}; multiplicity {p} "
                    f"leaves the basis C0 there, {p + 1} would cut the grid in two)")
    return None


def _multiplicities(t, tol):
    values, counts = [t[0]], [1]
    for k in t[1:]:
        if k - values[-1] <= tol:
            counts[-1] += 1
        else:
            values.append(k)
            counts.append(1)
    return values, counts


def grid_knots(cfg):
    """Per axis: the knot vector of `domain.knots` in grid units (x - lower) / dx, its ends exactly 0 and
    n_cells (so the wall control points sit on the walls), or None for the uniform open knot vector."""
    given = cfg.domain.knots
    if given is None:
        return None
    out = []
    for a in range(cfg.dim):
        k = getattr(given, "xyz"[a])
        if k is None:
            out.append(None)
            continue
        lo, hi, dx = cfg.domain.lower[a], cfg.domain.upper[a], cfg.domain.dx
        t = (np.asarray(k, float) - lo) / dx
        n = round((hi - lo) / dx)
        p = registry.get(cfg.solver.basis).degree
        t[: p + 1], t[-(p + 1):] = 0.0, float(n)
        out.append(t)
    return out


def smallest_span(cfg) -> float:
    """The shortest nonzero knot span of the grid (m): domain.dx unless `domain.knots` has a shorter one. The
    CFL rule uses it, since the stable step of an explicit scheme follows the smallest element."""
    h = cfg.domain.dx
    for t in grid_knots(cfg) or []:
        if t is not None:
            spans = np.diff(t)
            h = min(h, float(spans[spans > 0].min()) * cfg.domain.dx)
    return h


def greville(t: np.ndarray, p: int) -> np.ndarray:
    """Greville abscissae (t_{i+1} + ... + t_{i+p}) / p of the control points: with them sum_i N_i g_i = u,
    so node offsets x_i - x_p reproduce linear fields (APIC, D_p)."""
    n_ctrl = len(t) - p - 1
    return np.array([t[i + 1: i + p + 1].mean() for i in range(n_ctrl)])
