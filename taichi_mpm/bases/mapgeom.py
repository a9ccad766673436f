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
    only the grid is finer. The insertions are made once per axis on the identity (the refinement matrix of that
    axis, refined rows x given rows), then applied to the net: the cost grows with the refined net, not with the
    refined net times the number of knots inserted."""
    Pw = homogeneous(np.asarray(P, float), np.asarray(w, float))
    knots = [np.asarray(t, float) for t in knots]
    for axis, k in enumerate(per_span):
        t, T = knots[axis], np.eye(Pw.shape[axis])
        b = np.unique(t)
        for lo, hi in zip(b[:-1], b[1:]):
            for j in range(1, k):
                t, T = insert_knot(t, 2, T, lo + (hi - lo) * j / k, 0)
        knots[axis] = t
        Pw = np.moveaxis(np.tensordot(T, Pw, axes=(1, axis)), 0, axis)
    P, w = cartesian(Pw)
    return [cell_knots(t) for t in knots], P, w


def refined_shape(knots, per_span) -> tuple[list[int], list[int]]:
    """(control points, cells) per axis of `refine(knots, ..., per_span)`, from the knots alone (nothing built):
    each of the S nonzero spans of an axis gains per_span - 1 knots, so n + S (per_span - 1) control points and
    S per_span cells."""
    ctrl, cells = [], []
    for t, k in zip(knots, per_span):
        t = np.asarray(t, float)
        spans = int(np.count_nonzero(np.diff(t) > 0))
        ctrl.append(len(t) - 3 + spans * (int(k) - 1))
        cells.append(spans * int(k))
    return ctrl, cells


def annulus_shape(angle_deg: float, cells) -> tuple[list[int], list[int]]:
    """(control points, cells) per axis of the built-in annulus (nurbs.annulus), from its config alone: the arc
    is one rational piece per quarter turn (double knots between them), n_angle + pieces + 1 control points;
    the radius n_radial + 2 (a full ring stores its seam column once: one fewer along the angle)."""
    pieces = max(1, int(np.ceil(angle_deg / 90.0 - 1e-9)))
    n_angle, n_radial = (int(c) for c in cells)
    return [n_angle + pieces + 1, n_radial + 2], [n_angle, n_radial]


def scaled_knots(t, cells: int) -> np.ndarray:
    """The knot vector t affinely scaled to [0, cells]: the same spline as its refinement scaled by cell_knots,
    so a refined map can be evaluated (and checked) on its coarse control net."""
    t = np.asarray(t, float)
    return (t - t[0]) * (cells / (t[-1] - t[0]))

def cell_knots(t) -> np.ndarray:
    """A knot vector scaled to cells: from 0 to its number of nonzero spans (uniform spans become unit cells)."""
    t = np.asarray(t, float)
    spans = int(np.count_nonzero(np.diff(t) > 0))
    return (t - t[0]) * (spans / (t[-1] - t[0]))


def local_basis(t, p: int, u):
    """The p + 1 B-splines of degree p that are nonzero at each point u (M,) and their first derivatives:
    (index of the first, values (M, p + 1), derivatives (M, p + 1)); The NURBS Book A2.2 and eq. 2.7, for all
    points at once. The same numbers as bspline_values / bspline_derivatives (last span closed on the right), at a
    cost that does not grow with the number of control points."""
    t = np.asarray(t, float)
    u = np.atleast_1d(np.asarray(u, float))
    n = len(t) - p - 1
    k = np.clip(np.searchsorted(t, u, side="right") - 1, p, n - 1)      # t[k] <= u < t[k + 1]
    def basis(q):
        N = np.zeros((len(u), q + 1))
        N[:, 0] = 1.0
        left = [None] + [u - t[k + 1 - j] for j in range(1, q + 1)]
        right = [None] + [t[k + j] - u for j in range(1, q + 1)]
        for j in range(1, q + 1):
            saved = np.zeros(len(u))
            for r in range(j):
                den = right[r + 1] + left[j - r]
                temp = np.divide(N[:, r], den, out=np.zeros(len(u)), where=den != 0)
                N[:, r] = saved + right[r + 1] * temp
                saved = left[j - r] * temp
            N[:, j] = saved
        return N
    N = basis(p)
    dN = np.zeros_like(N)
    if p > 0:
        lower = basis(p - 1)            # the degree p - 1 functions k - p + 1 .. k
        for r in range(p + 1):
            if r >= 1:
                a = t[k + r] - t[k - p + r]
                dN[:, r] += p * np.divide(lower[:, r - 1], a, out=np.zeros(len(u)), where=a > 0)
            if r <= p - 1:
                b = t[k + r + 1] - t[k - p + r + 1]
                dN[:, r] -= p * np.divide(lower[:, r], b, out=np.zeros(len(u)), where=b > 0)
    return k - p, N, dN


def surface(knots, degrees, P, w, xi):
    """x(xi) (M, 2) and J = dx/dxi (M, 2, 2) at parameter points xi (M, 2), by the quotient rule. Each point
    reads only its (p0 + 1) x (p1 + 1) control points (local_basis): memory and time grow with the points, not
    with the points times the net."""
    xi = np.atleast_2d(np.asarray(xi, float))
    P, w = np.asarray(P, float), np.asarray(w, float)
    (i0, N0, dN0), (i1, N1, dN1) = (local_basis(t, p, xi[:, a]) for a, (t, p) in enumerate(zip(knots, degrees)))
    I0 = i0[:, None] + np.arange(N0.shape[1])
    I1 = i1[:, None] + np.arange(N1.shape[1])
    wl = w[I0[:, :, None], I1[:, None, :]]                      # (M, p0 + 1, p1 + 1)
    Pl = P[I0[:, :, None], I1[:, None, :]]                      # (M, p0 + 1, p1 + 1, 2)
    Nw = N0[:, :, None] * N1[:, None, :] * wl
    D0 = dN0[:, :, None] * N1[:, None, :] * wl
    D1 = N0[:, :, None] * dN1[:, None, :] * wl
    W, W0, W1 = Nw.sum(axis=(1, 2)), D0.sum(axis=(1, 2)), D1.sum(axis=(1, 2))
    x = np.einsum("mij,mijc->mc", Nw, Pl) / W[:, None]
    J = np.empty((len(xi), 2, 2))
    J[:, :, 0] = (np.einsum("mij,mijc->mc", D0, Pl) - W0[:, None] * x) / W[:, None]
    J[:, :, 1] = (np.einsum("mij,mijc->mc", D1, Pl) - W1[:, None] * x) / W[:, None]
    return x, J


def _samples(t, k):
    """k + 1 points per nonzero span of t, both ends included."""
    b = np.unique(t)
    return np.unique(np.concatenate([np.linspace(b[i], b[i + 1], k + 1) for i in range(len(b) - 1)]))


def fold(knots, degrees, P, w, per_span=(DET_SAMPLES, DET_SAMPLES)):
    """(min s det J / |J|^2, the parameter point where it is smallest) over DET_SAMPLES + 1 points per cell and
    axis, s the sign of det J at most samples (either orientation is a grid: the annulus, angle first, has
    det J < 0): a map that folds or pinches (that value <= 0 somewhere) is not a grid."""
    s = [_samples(t, k) for t, k in zip(knots, per_span)]
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


def cell_sizes(knots, degrees, P, w, breaks=None, rows=256):
    """(smallest, largest) chord between neighbouring cell corners x(knot_a, knot_b): the edges of the
    physical cells (the annulus: an inner arc's chord and a radial cell). `breaks`: the corner parameters per
    axis (default: the distinct knots; a refined map's on its coarse net: scaled_knots). Evaluated a few rows
    of corners at a time (memory of `rows` rows' corners at most)."""
    b = [np.unique(t) for t in knots] if breaks is None else [np.asarray(v, float) for v in breaks]
    lo, hi, prev = np.inf, 0.0, None
    step = max(1, rows * 1024 // max(len(b[1]), 1))
    for start in range(0, len(b[0]), step):
        rows_xi = b[0][start:start + step]
        xi = np.stack(np.meshgrid(rows_xi, b[1], indexing="ij"), -1)
        x, _ = surface(knots, degrees, P, w, xi.reshape(-1, 2))
        x = x.reshape(xi.shape)
        if prev is not None:
            x = np.concatenate([prev[None], x])
        edges = np.concatenate([np.linalg.norm(np.diff(x, axis=0), axis=-1).ravel(),
                                np.linalg.norm(np.diff(x, axis=1), axis=-1).ravel()])
        if len(edges):
            lo, hi = min(lo, float(edges.min())), max(hi, float(edges.max()))
        prev = x[-1]
    return lo, hi


def boundary(knots, degrees, P, w, per_cell: int = 16, most: int = 16384) -> np.ndarray:
    """The map's boundary as a closed polygon (K, 2): its four parameter faces in turn (y_min, x_max, y_max
    reversed, x_min reversed), `per_cell` points per cell of each face, at most `most` per face. A periodic map's
    seam is traversed both ways, so it adds no crossing to an even-odd test (`outside`)."""
    hi = [float(t[-1]) for t in knots]
    s = [np.linspace(0.0, h, min(most, per_cell * max(1, int(round(h)))) + 1) for h in hi]
    faces = [np.stack([s[0], np.zeros_like(s[0])], -1), np.stack([np.full_like(s[1], hi[0]), s[1]], -1),
             np.stack([s[0][::-1], np.full_like(s[0], hi[1])], -1), np.stack([np.zeros_like(s[1]), s[1][::-1]], -1)]
    return surface(knots, degrees, P, w, np.concatenate(faces))[0]


def outside(polygon: np.ndarray, pts: np.ndarray, tol: float) -> np.ndarray:
    """Mask of the points outside the closed polygon (even-odd rule) by more than `tol` (points within `tol` of
    its edges count as inside: particles flush with a wall)."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    out = np.zeros(len(pts), bool)
    for start in range(0, len(pts), 4096):
        p = pts[start:start + 4096, None, :]
        crosses = ((a[None, :, 1] > p[..., 1]) != (b[None, :, 1] > p[..., 1]))
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = a[None, :, 0] + (p[..., 1] - a[None, :, 1]) * (b[None, :, 0] - a[None, :, 0]) / (
                b[None, :, 1] - a[None, :, 1])
        inside = (crosses & (p[..., 0] < x_at)).sum(axis=1) % 2 == 1
        far = ~inside
        if far.any():
            q = p[far]
            e = b - a
            L2 = np.maximum((e * e).sum(-1), 1e-300)
            t = np.clip(((q - a[None]) * e[None]).sum(-1) / L2[None], 0.0, 1.0)
            dist = np.linalg.norm(q - (a[None] + t[..., None] * e[None]), axis=-1).min(axis=1)
            far[np.flatnonzero(far)] = dist > tol
        out[start:start + 4096] = far
    return out
