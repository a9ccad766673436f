"""Host-side (numpy only, no Taichi) geometry of 2D NURBS maps x(xi) = sum_i R_i(xi) P_i: B-spline values and
derivatives, the map and its Jacobian at parameter points, the checks a map given in the config must pass (the
map does not fold: det J > 0), the outward wall normal at each control point of a parameter face, and the cell
sizes the CFL rule reads. Used by config validation (without Taichi) and by mapped.py when it builds a grid.

Parameter coordinates are in cells: knots from 0 to the number of nonzero knot spans (`cell_knots`).
"""

import numpy as np

FACE_NAMES = ("x_min", "x_max", "y_min", "y_max")
DET_SAMPLES = 4       # det J is checked at (DET_SAMPLES + 1)^2 points per cell, the cell's edges included


def bspline_values(t: np.ndarray, p: int, u: np.ndarray) -> np.ndarray:
    """All B-splines of degree p on knots t at points u (M,) -> (M, n): the textbook recursion over degrees with
    0/0 = 0, the last span closed on the right."""
    t = np.asarray(t, float)
    u = np.asarray(u, float)
    m = len(t)
    N = np.zeros((len(u), m - 1))
    last = np.nonzero(t[:-1] < t[1:])[0][-1]
    for i in range(m - 1):
        inside = (t[i] <= u) & (u < t[i + 1])
        if i == last:
            inside |= u == t[-1]
        N[:, i] = inside
    for k in range(1, p + 1):
        out = np.zeros((len(u), m - 1 - k))
        for i in range(m - 1 - k):
            a = t[i + k] - t[i]
            b = t[i + k + 1] - t[i + 1]
            if a > 0:
                out[:, i] += (u - t[i]) / a * N[:, i]
            if b > 0:
                out[:, i] += (t[i + k + 1] - u) / b * N[:, i + 1]
        N = out
    return N


def bspline_derivatives(t: np.ndarray, p: int, u: np.ndarray) -> np.ndarray:
    """First derivatives of all B-splines (M, n): N'_i = p (N_{i,p-1} / (t_{i+p} - t_i) - N_{i+1,p-1} /
    (t_{i+p+1} - t_{i+1})), 0/0 = 0 (The NURBS Book eq. 2.7)."""
    t = np.asarray(t, float)
    lower = bspline_values(t, p - 1, u)          # (M, n + 1)
    n = len(t) - p - 1
    out = np.zeros((len(np.atleast_1d(u)), n))
    for i in range(n):
        a, b = t[i + p] - t[i], t[i + p + 1] - t[i + 1]
        if a > 0:
            out[:, i] += p * lower[:, i] / a
        if b > 0:
            out[:, i] -= p * lower[:, i + 1] / b
    return out


def insert_knot(t: np.ndarray, p: int, Pw: np.ndarray, u: float, axis: int = 0):
    """Boehm's knot insertion (The NURBS Book A5.1, one knot) along `axis` of homogeneous control points Pw
    (w P, w): returns the new knot vector and points; the curve or surface does not change."""
    k = int(np.searchsorted(t, u, side="right")) - 1          # t[k] <= u < t[k+1]
    Pw = np.moveaxis(Pw, axis, 0)
    n = Pw.shape[0]
    Q = np.empty((n + 1,) + Pw.shape[1:])
    Q[: k - p + 1] = Pw[: k - p + 1]
    for i in range(k - p + 1, k + 1):
        a = (u - t[i]) / (t[i + p] - t[i])
        Q[i] = a * Pw[i] + (1 - a) * Pw[i - 1]
    Q[k + 1:] = Pw[k:]
    return np.insert(t, k + 1, u), np.moveaxis(Q, 0, axis)


def homogeneous(P: np.ndarray, w: np.ndarray) -> np.ndarray:
    return np.concatenate([P * w[..., None], w[..., None]], axis=-1)


def cartesian(Pw: np.ndarray):
    return Pw[..., :-1] / Pw[..., -1:], Pw[..., -1]


def refine(knots, P, w, per_span):
    """The patch the solver's grid uses: every nonzero knot span of axis a split into per_span[a] equal spans by
    knot insertion (degree 2 per axis), the knots then scaled to cells (cell_knots). The map is exactly the same;
    only the grid is finer."""
    Pw = homogeneous(np.asarray(P, float), np.asarray(w, float))
    knots = [np.asarray(t, float) for t in knots]
    for axis, k in enumerate(per_span):
        b = np.unique(knots[axis])
        for lo, hi in zip(b[:-1], b[1:]):
            for j in range(1, k):
                knots[axis], Pw = insert_knot(knots[axis], 2, Pw, lo + (hi - lo) * j / k, axis)
    P, w = cartesian(Pw)
    return [cell_knots(t) for t in knots], P, w


def cell_knots(t) -> np.ndarray:
    """A knot vector scaled to cells: from 0 to its number of nonzero spans (uniform spans become unit cells)."""
    t = np.asarray(t, float)
    spans = int(np.count_nonzero(np.diff(t) > 0))
    return (t - t[0]) * (spans / (t[-1] - t[0]))


def surface(knots, degrees, P, w, xi):
    """x(xi) (M, 2) and J = dx/dxi (M, 2, 2) at parameter points xi (M, 2), by the quotient rule."""
    xi = np.atleast_2d(np.asarray(xi, float))
    N = [bspline_values(t, p, xi[:, a]) for a, (t, p) in enumerate(zip(knots, degrees))]
    dN = [bspline_derivatives(t, p, xi[:, a]) for a, (t, p) in enumerate(zip(knots, degrees))]
    Nw = np.einsum("mi,mj,ij->mij", N[0], N[1], w)
    D0 = np.einsum("mi,mj,ij->mij", dN[0], N[1], w)
    D1 = np.einsum("mi,mj,ij->mij", N[0], dN[1], w)
    W, W0, W1 = Nw.sum(axis=(1, 2)), D0.sum(axis=(1, 2)), D1.sum(axis=(1, 2))
    x = np.einsum("mij,ijc->mc", Nw, P) / W[:, None]
    J = np.empty((len(xi), 2, 2))
    J[:, :, 0] = (np.einsum("mij,ijc->mc", D0, P) - W0[:, None] * x) / W[:, None]
    J[:, :, 1] = (np.einsum("mij,ijc->mc", D1, P) - W1[:, None] * x) / W[:, None]
    return x, J


def _samples(t, k):
    """k + 1 points per nonzero span of t, both ends included."""
    b = np.unique(t)
    return np.unique(np.concatenate([np.linspace(b[i], b[i + 1], k + 1) for i in range(len(b) - 1)]))


def fold(knots, degrees, P, w):
    """(min s det J / |J|^2, the parameter point where it is smallest) over DET_SAMPLES + 1 points per cell and
    axis, s the sign of det J at most samples (either orientation is a grid: the annulus, angle first, has
    det J < 0): a map that folds or pinches (that value <= 0 somewhere) is not a grid."""
    s = [_samples(t, DET_SAMPLES) for t in knots]
    xi = np.stack(np.meshgrid(*s, indexing="ij"), -1).reshape(-1, 2)
    _, J = surface(knots, degrees, P, w, xi)
    det = np.linalg.det(J)
    det *= 1.0 if np.median(det) >= 0 else -1.0
    scale = np.abs(J).max(axis=(1, 2)) ** 2
    k = int(np.argmin(det / scale))
    return det[k] / scale[k], xi[k]


def greville(t, p) -> np.ndarray:
    t = np.asarray(t, float)
    return np.array([t[i + 1: i + p + 1].mean() for i in range(len(t) - p - 1)])


def face_normals(knots, degrees, P, w, periodic=False) -> np.ndarray:
    """Outward unit normals (n0, n1, 4, 2) per control point and parameter face (x_min, x_max, y_min, y_max),
    zero off the face. A face's normal at control point P_i is the curve's normal at the point of the face
    nearest to P_i (Newton on (x(s) - P_i) . x'(s) = 0 from its Greville abscissa): on a circle that is the
    radial direction of P_i itself, so a slip or roller impulse there points through the centre and exerts no
    torque about it. A periodic map (x wraps) has no x faces."""
    n0, n1 = w.shape
    out = np.zeros((n0, n1, 4, 2))
    hi = [float(t[-1]) for t in knots]
    for k in range(4):
        axis = k // 2            # x faces: xi0 fixed; y faces: xi1 fixed
        if axis == 0 and periodic:
            continue
        along = 1 - axis
        at = 0.0 if k % 2 == 0 else hi[axis]
        nodes = P[0 if k == 0 else -1, :] if axis == 0 else P[:, 0 if k == 2 else -1]
        s = greville(knots[along], degrees[along])

        def point(s):
            xi = np.empty((len(s), 2))
            xi[:, along], xi[:, axis] = s, at
            return surface(knots, degrees, P, w, xi)

        for _ in range(60):
            x, J = point(s)
            d = J[:, :, along]
            f = ((x - nodes) * d).sum(-1)
            h = 1e-6 * hi[along]
            _, Jh = point(np.minimum(s + h, hi[along]))
            _, Jl = point(np.maximum(s - h, 0.0))
            fp = (d * d).sum(-1) + ((x - nodes) * (Jh[:, :, along] - Jl[:, :, along])).sum(-1) / (
                np.minimum(s + h, hi[along]) - np.maximum(s - h, 0.0))
            step = f / fp
            s = np.clip(s - step, 0.0, hi[along])
            if np.abs(step).max() < 1e-15 * hi[along]:
                break
        x, J = point(s)
        tangent = J[:, :, along]
        n = np.stack([tangent[:, 1], -tangent[:, 0]], -1) / np.linalg.norm(tangent, axis=-1, keepdims=True)
        outward = 1.0 if k % 2 else -1.0
        n *= np.sign((n * J[:, :, axis]).sum(-1) * outward)[:, None]
        if axis == 0:
            out[0 if k == 0 else -1, :, k] = n
        else:
            out[:, 0 if k == 2 else -1, k] = n
    return out


def cell_sizes(knots, degrees, P, w):
    """(smallest, largest) chord between neighbouring cell corners x(knot_a, knot_b): the edges of the
    physical cells (the annulus: an inner arc's chord and a radial cell)."""
    b = [np.unique(t) for t in knots]
    xi = np.stack(np.meshgrid(*b, indexing="ij"), -1)
    x, _ = surface(knots, degrees, P, w, xi.reshape(-1, 2))
    x = x.reshape(xi.shape)
    edges = np.concatenate([np.linalg.norm(np.diff(x, axis=0), axis=-1).ravel(),
                            np.linalg.norm(np.diff(x, axis=1), axis=-1).ravel()])
    return float(edges.min()), float(edges.max())
