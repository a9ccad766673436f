"""Host-side (numpy only, no Taichi) geometry of 2D and 3D NURBS maps x(xi) = sum_i R_i(xi) P_i: B-spline values and
derivatives, the map and its Jacobian at parameter points, the checks a map given in the config must pass (the
map does not fold: det J > 0), the outward wall normal at each control point of a parameter face, and the cell
sizes the CFL rule reads. Used by config validation (without Taichi) and by mapped.py when it builds a grid.

Parameter coordinates are in cells: knots from 0 to the number of nonzero knot spans (`cell_knots`).
"""

import math

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


def refine(knots, P, w, per_span, degree: int = 2):
    """The patch the solver's grid uses: every nonzero knot span of axis a split into per_span[a] equal spans by
    knot insertion (of the net's degree per axis), the knots then scaled to cells (cell_knots). The map is exactly
    the same; only the grid is finer. The insertions are made once per axis on the identity (the refinement
    matrix of that axis, refined rows x given rows), then applied to the net: the cost grows with the refined net,
    not with the refined net times the number of knots inserted."""
    Pw = homogeneous(np.asarray(P, float), np.asarray(w, float))
    knots = [np.asarray(t, float) for t in knots]
    for axis, k in enumerate(per_span):
        t, T = knots[axis], np.eye(Pw.shape[axis])
        b = np.unique(t)
        for lo, hi in zip(b[:-1], b[1:]):
            for j in range(1, k):
                t, T = insert_knot(t, degree, T, lo + (hi - lo) * j / k, 0)
        knots[axis] = t
        Pw = np.moveaxis(np.tensordot(T, Pw, axes=(1, axis)), 0, axis)
    P, w = cartesian(Pw)
    return [cell_knots(t) for t in knots], P, w


def elevate(knots, P, w, degree: int):
    """A quadratic net raised to `degree` along every axis (The NURBS Book 5.5, by another route): each distinct
    knot once more, so the continuity at every knot stays what it was and the old B-splines lie in the new space;
    their coefficients there solve the collocation at the new space's Greville abscissae (nonsingular by
    Schoenberg-Whitney). The map does not change. Returns (knots, P, w)."""
    Pw = homogeneous(np.asarray(P, float), np.asarray(w, float))
    out = []
    for axis, t in enumerate(knots):
        t = np.asarray(t, float)
        raised = np.sort(np.concatenate([t, np.unique(t)]))
        u = greville(raised, degree)
        T = np.linalg.solve(bspline_values(raised, degree, u), bspline_values(t, 2, u))
        Pw = np.moveaxis(np.tensordot(T, Pw, axes=(1, axis)), 0, axis)
        out.append(raised)
    P, w = cartesian(Pw)
    return out, P, w


def refined_shape(knots, per_span, degree: int = 2) -> tuple[list[int], list[int]]:
    """(control points, cells) per axis of `refine(knots, ..., per_span)` of the quadratic net (raised to `degree`
    first: `elevate`), from the knots alone (nothing built): each of the S nonzero spans of an axis gains
    per_span - 1 knots, and elevation one more control point per span, so n + S (per_span - 1) + (degree - 2) S
    control points and S per_span cells."""
    ctrl, cells = [], []
    for t, k in zip(knots, per_span):
        t = np.asarray(t, float)
        spans = int(np.count_nonzero(np.diff(t) > 0))
        ctrl.append(len(t) - 3 + spans * (int(k) - 1) + (degree - 2) * spans)
        cells.append(spans * int(k))
    return ctrl, cells


def arc_pieces(degrees: float) -> int:
    """Rational pieces of an arc of `degrees`: one per at most a quarter turn."""
    return max(1, math.ceil(degrees / 90.0 - 1e-9))


def arc(angle: float, n_cells: int):
    """A unit-radius circular arc from angle 0 to `angle` (<= 2 pi) as a quadratic NURBS on parameters
    [0, n_cells]: one rational Bezier piece (weights 1, cos(d/2), 1) per at most a quarter turn, joined by
    double knots (C0 in the parameter, the circle itself stays smooth), then uniform knot insertion up to
    n_cells spans. Returns (knots, control points (n, 2), weights (n,))."""
    pieces = max(1, math.ceil(angle / (0.5 * math.pi) - 1e-9))
    if n_cells % pieces:
        raise ValueError(f"an arc of {math.degrees(angle):g} degrees is {pieces} rational pieces: its number of "
                         f"cells must be a multiple of {pieces}, got {n_cells}")
    d = angle / pieces
    P, w = [[1.0, 0.0]], [1.0]
    for k in range(pieces):
        mid, end = (k + 0.5) * d, (k + 1) * d
        P += [[math.cos(mid) / math.cos(d / 2), math.sin(mid) / math.cos(d / 2)], [math.cos(end), math.sin(end)]]
        w += [math.cos(d / 2), 1.0]
    per = n_cells // pieces
    t = np.array([0.0] * 3 + [float(k * per) for k in range(1, pieces) for _ in range(2)] + [float(n_cells)] * 3)
    Pw = homogeneous(np.array(P), np.array(w))
    for k in range(pieces):
        for j in range(1, per):
            t, Pw = insert_knot(t, 2, Pw, float(k * per + j))
    P, w = cartesian(Pw)
    return t, P, w


def open_knots(n_cells: int) -> np.ndarray:
    """The open uniform quadratic knot vector of n_cells unit spans (ends 3 times)."""
    return np.array([0.0] * 3 + [float(k) for k in range(1, n_cells)] + [float(n_cells)] * 3)


def radii(r_inner: float, r_outer: float, n_radial: int):
    """(knots, radius of each control point) across a wall of n_radial cells: the control points at the Greville
    abscissae of the open uniform knots, where linear functions are reproduced (so r is linear in the parameter)."""
    t = open_knots(n_radial)
    return t, r_inner + (r_outer - r_inner) * greville(t, 2) / n_radial


def cylinder_net(r_inner, r_outer, angle, length, cells, centre):
    """The thick-walled cylinder (or a sector of it) as a 3D NURBS volume, quadratic in each parameter: xi0 along
    the angle (counter-clockwise about +z from +x), xi1 across the wall, xi2 along the axis (+z, from the base
    circle's centre `centre`). Every surface of constant xi1 is an exact circular cylinder; the net is the
    annulus' times a line. Returns (knots, P (n0, n1, n2, 3), w (n0, n1, n2))."""
    n_angle, n_radial, n_axial = cells
    t0, Q, wq = arc(angle, n_angle)
    t1, r = radii(r_inner, r_outer, n_radial)
    t2 = open_knots(n_axial)
    z = length * greville(t2, 2) / n_axial
    P = np.empty((len(wq), len(r), len(z), 3))
    P[..., :2] = Q[:, None, None, :] * r[None, :, None, None]
    P[..., 2] = z[None, None, :]
    P += np.asarray(centre, float)
    w = np.broadcast_to(wq[:, None, None], P.shape[:3]).copy()
    return [t0, t1, t2], P, w


def meridian(latitudes, n_cells: int):
    """A unit meridian arc from latitude latitudes[0] to latitudes[1] (radians, inside (-pi/2, pi/2)) as
    (knots, (rho, z) control points, weights): `arc` turned to start at the first latitude."""
    lo, hi = latitudes
    t, Q, w = arc(hi - lo, n_cells)
    c, s = np.cos(lo), np.sin(lo)
    return t, np.stack([c * Q[:, 0] - s * Q[:, 1], s * Q[:, 0] + c * Q[:, 1]], -1), w


def shell_net(r_inner, r_outer, angle, latitudes, cells, centre):
    """A spherical shell between two latitudes as a 3D NURBS volume (the surface of revolution of a meridian
    arc, The NURBS Book 8.5, times the radius): xi0 along the longitude (counter-clockwise about +z from +x),
    xi1 across the shell, xi2 along the latitude (south to north). Every surface of constant xi1 is an exact
    sphere; the poles are left out (det J = 0 there). Returns (knots, P (n0, n1, n2, 3), w (n0, n1, n2))."""
    n_lon, n_radial, n_lat = cells
    t0, C, wc = arc(angle, n_lon)
    t1, r = radii(r_inner, r_outer, n_radial)
    t2, M, wm = meridian(latitudes, n_lat)
    S = np.empty((len(wc), len(wm), 3))                          # the unit sphere's net
    S[..., :2] = C[:, None, :] * M[None, :, 0, None]
    S[..., 2] = M[None, :, 1]
    P = r[None, :, None, None] * S[:, None, :, :] + np.asarray(centre, float)
    w = np.broadcast_to((wc[:, None] * wm[None, :])[:, None, :], P.shape[:3]).copy()
    return [t0, t1, t2], P, w


def knot_points(t, Q, w) -> np.ndarray:
    """The points of a quadratic rational curve (knots t, control points Q, weights w) at its distinct knots:
    its cells' corners."""
    N = bspline_values(t, 2, np.unique(t)) * w[None, :]
    return (N @ Q) / N.sum(axis=1, keepdims=True)


def arc_chords(angle: float, n_cells: int) -> np.ndarray:
    """Chords between neighbouring knot points of the unit `arc` (its cells' edges, the rational pieces'
    uneven split included)."""
    return np.linalg.norm(np.diff(knot_points(*arc(angle, n_cells)), axis=0), axis=1)


def solid_cell_sizes(kind: str, r_inner, r_outer, angle, cells, length=None, latitudes=None):
    """(smallest, largest) cell edge of the built-in cylinder or shell: the edges of a tensor-product net of
    circles are chords of its unit arcs times their radii, so the extremes are products of 1D extremes."""
    n_angle, n_radial, n_axial = cells
    ring = arc_chords(angle, n_angle)
    radial = (r_outer - r_inner) / n_radial
    if kind == "cylinder":
        sizes = [r_inner * ring.min(), r_outer * ring.max(), radial, length / n_axial]
        return min(sizes), max(sizes)
    corners = knot_points(*meridian(latitudes, n_axial))
    rho = corners[:, 0]                                  # distance from the axis of each latitude corner
    along = np.linalg.norm(np.diff(corners, axis=0), axis=1)
    lo = min(r_inner * rho.min() * ring.min(), r_inner * along.min(), radial)
    hi = max(r_outer * rho.max() * ring.max(), r_outer * along.max(), radial)
    return lo, hi


def solid_map_cell_sizes(m):
    """(smallest, largest) cell edge of a `cylinder` or `shell` domain.map config (solid_cell_sizes)."""
    return solid_cell_sizes(m.type, m.inner_radius, m.outer_radius, math.radians(m.angle), m.cells,
                            length=getattr(m, "length", None),
                            latitudes=np.radians(m.latitudes) if m.type == "shell" else None)


def solid_map_shape(m, degree: int = 2) -> tuple[list[int], list[int]]:
    """(control points, cells) per axis of a `cylinder` or `shell` domain.map config (solid_shape)."""
    return solid_shape(m.type, m.angle, m.cells, float(np.ptp(m.latitudes)) if m.type == "shell" else 0.0, degree)


def solid_shape(kind: str, angle_deg: float, cells, span_deg: float = 0.0,
                degree: int = 2) -> tuple[list[int], list[int]]:
    """(control points, cells) per axis of the built-in cylinder or shell from its config alone: the annulus'
    two axes, then the axial line (n + p) or the meridian arc (like the angle's, its own rational pieces)."""
    ctrl, cells2 = annulus_shape(angle_deg, cells[:2], degree)
    if kind == "cylinder":
        return ctrl + [int(cells[2]) + degree], cells2 + [int(cells[2])]
    pieces = arc_pieces(span_deg)
    return ctrl + [int(cells[2]) + (degree - 1) * pieces + 1], cells2 + [int(cells[2])]


class JoinError(ValueError):
    """Patches that do not join: `patch` is the index of the later one, `where` the key below it (".knots.y")."""

    def __init__(self, patch: int, where: str, message: str):
        super().__init__(message)
        self.patch, self.where = patch, where


def join_patches(nets, tol: float = 1e-12):
    """Several quadratic patches (knots per axis, control points, weights) joined in order along the first
    parameter into one patch: each one's knots scaled to cells and shifted to follow the previous one's, the
    shared layer of control points stored once, so the joint is a double knot (C0, like the rational pieces of
    the built-in arcs). The patches must be conforming: equal knots (in cells) along the other axes, and the
    last layer of control points and weights of each equal to the first of the next (to `tol` of the net's size).
    Returns (knots, P, w)."""
    knots = [cell_knots(t) for t in nets[0][0]]
    P, w = nets[0][1], nets[0][2]
    size = max(float(np.ptp(n[1].reshape(-1, n[1].shape[-1]), axis=0).max()) for n in nets)
    axes = "xyz"
    for i, (t_next, P_next, w_next) in enumerate(nets[1:], start=1):
        t_next = [cell_knots(t) for t in t_next]
        for a in range(1, len(knots)):
            if len(t_next[a]) != len(knots[a]) or np.abs(t_next[a] - knots[a]).max() > 1e-12:
                raise JoinError(i, f".knots.{axes[a]}", f"patch {i} does not conform to patch {i - 1}: its knots "
                                f"along {axes[a]} (in cells) must equal theirs")
        if np.abs(P_next[0] - P[-1]).max() > tol * size or np.abs(w_next[0] - w[-1]).max() > tol * w.max():
            raise JoinError(i, ".control_points", f"patch {i} does not join patch {i - 1}: its first layer of "
                            "control points and weights must equal the last layer of the patch before it")
        t0, start = knots[0], knots[0][-1]
        knots[0] = np.concatenate([t0[:-1], t_next[0][3:] + start])     # ends: 3 -> the joint twice
        P = np.concatenate([P, P_next[1:]])
        w = np.concatenate([w, w_next[1:]])
    return knots, P, w


def config_net(m):
    """(knots per axis, control points, weights) of a `nurbs` domain.map config as given (one patch: its knots in
    any scale; several: joined, knots in cells). The config has checked it (config._check_nurbs_map)."""
    def one(p):
        d = 2 if p.knots.z is None else 3
        P = np.asarray(p.control_points, float)
        w = np.ones(P.shape[:-1]) if p.weights is None else np.asarray(p.weights, float)
        return [np.asarray(getattr(p.knots, a), float) for a in "xyz"[:d]], P, w
    return one(m) if m.patches is None else join_patches([one(p) for p in m.patches])


def face_samples(cells, per_axis_most: int) -> np.ndarray:
    """Parameter points on every face of the box [0, cells]: 8 per cell along each face axis, at most
    per_axis_most + 1 per axis."""
    s = [np.linspace(0.0, n, min(8 * n, per_axis_most) + 1) for n in cells]
    out = []
    for a in range(len(cells)):
        for end in (0.0, float(cells[a])):
            grid = np.stack(np.meshgrid(*[s[b] if b != a else np.array([end]) for b in range(len(cells))],
                                        indexing="ij"), -1)
            out.append(grid.reshape(-1, len(cells)))
    return np.concatenate(out)


def annulus_shape(angle_deg: float, cells, degree: int = 2) -> tuple[list[int], list[int]]:
    """(control points, cells) per axis of the built-in annulus (nurbs.annulus), from its config alone: the arc
    is one rational piece per quarter turn (joined by knots of multiplicity p), n_angle + (p - 1) pieces + 1
    control points; the radius n_radial + p (a full ring stores its seam column once: one fewer along the
    angle)."""
    pieces = arc_pieces(angle_deg)
    n_angle, n_radial = (int(c) for c in cells)
    return [n_angle + (degree - 1) * pieces + 1, n_radial + degree], [n_angle, n_radial]


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


def _outer(factors):
    """The per-point outer product of one factor (M, n_a) per axis: (M, n_0, ..., n_{d-1}), in axis order."""
    d = len(factors)
    out = factors[0].reshape(factors[0].shape + (1,) * (d - 1))
    for a in range(1, d):
        out = out * factors[a].reshape((len(factors[a]),) + (1,) * a + (factors[a].shape[1],) + (1,) * (d - 1 - a))
    return out


def _weighted_local(knots, degrees, w, xi):
    """The functions nonzero at each parameter point xi (M, d): (xi as (M, d), per axis local_basis' (first, N, dN),
    the index of each point's (p_0 + 1) x ... control points into the net, their weights w_i and w_i N_i (both
    (M, p_0 + 1, ...)))."""
    w = np.asarray(w, float)
    d = w.ndim
    xi = np.asarray(xi, float).reshape(-1, d)
    local = [local_basis(t, p, xi[:, a]) for a, (t, p) in enumerate(zip(knots, degrees))]
    index = tuple((i[:, None] + np.arange(N.shape[1])).reshape((len(xi),) + (1,) * a + (N.shape[1],)
                                                               + (1,) * (d - 1 - a))
                  for a, (i, N, _) in enumerate(local))
    wl = w[index]
    return xi, local, index, wl, _outer([N for _, N, _ in local]) * wl


def surface(knots, degrees, P, w, xi):
    """x(xi) (M, d) and J = dx/dxi (M, d, d) at parameter points xi (M, d), by the quotient rule (2D and 3D
    maps). Each point reads only its prod (p_a + 1) control points (local_basis): memory and time grow with the
    points, not with the points times the net."""
    P = np.asarray(P, float)
    xi, local, index, wl, Nw = _weighted_local(knots, degrees, w, xi)
    d = xi.shape[1]
    Pl = P[index]                                               # (M, p0 + 1, ..., d)
    Dw = [_outer([dN if b == a else N for b, (_, N, dN) in enumerate(local)]) * wl for a in range(d)]
    axes = tuple(range(1, d + 1))
    W = Nw.sum(axis=axes)
    sub = "ijk"[:d]
    x = np.einsum(f"m{sub},m{sub}c->mc", Nw, Pl) / W[:, None]
    J = np.empty((len(xi), d, d))
    for a in range(d):
        J[:, :, a] = (np.einsum(f"m{sub},m{sub}c->mc", Dw[a], Pl) - Dw[a].sum(axis=axes)[:, None] * x) / W[:, None]
    return x, J


def node_sums(knots, degrees, w, xi, values) -> np.ndarray:
    """sum_q R_i(xi_q) values_q for every control point i: (n0, n1[, n2], c) from parameter points xi (M, d) and
    their values (M, c), R the rational basis w_i N_i / sum_j w_j N_j (the grid's functions on a mapped grid)."""
    xi, _, index, _, Nw = _weighted_local(knots, degrees, w, xi)
    d, values = xi.shape[1], np.asarray(values, float)
    R = Nw / Nw.sum(axis=tuple(range(1, d + 1)), keepdims=True)
    out = np.zeros(np.shape(w) + (values.shape[1],))
    full = tuple(np.broadcast_to(i, R.shape) for i in index)
    np.add.at(out, full, R[..., None] * values.reshape((len(xi),) + (1,) * d + (values.shape[1],)))
    return out


def _samples(t, k):
    """k + 1 points per nonzero span of t, both ends included."""
    b = np.unique(t)
    return np.unique(np.concatenate([np.linspace(b[i], b[i + 1], k + 1) for i in range(len(b) - 1)]))


def fold(knots, degrees, P, w, per_span=None):
    """(min s det J / |J|^2, the parameter point where it is smallest) over DET_SAMPLES + 1 points per cell and
    axis, s the sign of det J at most samples (either orientation is a grid: the annulus, angle first, has
    det J < 0): a map that folds or pinches (that value <= 0 somewhere) is not a grid."""
    per_span = [DET_SAMPLES] * len(knots) if per_span is None else per_span
    s = [_samples(t, k) for t, k in zip(knots, per_span)]
    xi = np.stack(np.meshgrid(*s, indexing="ij"), -1).reshape(-1, len(s))
    _, J = surface(knots, degrees, P, w, xi)
    det = np.linalg.det(J)
    det *= 1.0 if np.median(det) >= 0 else -1.0
    scale = np.abs(J).max(axis=(1, 2)) ** J.shape[-1]
    k = int(np.argmin(det / scale))
    return det[k] / scale[k], xi[k]


def greville(t, p) -> np.ndarray:
    t = np.asarray(t, float)
    return np.array([t[i + 1: i + p + 1].mean() for i in range(len(t) - p - 1)])


def face_normals(knots, degrees, P, w, periodic=False) -> np.ndarray:
    """Outward unit normals (n0, n1[, n2], 2 d, d) per control point and parameter face (x_min, x_max, y_min,
    y_max[, z_min, z_max]), zero off the face; 2D below, 3D in `_face_normals_3d` (the same rule)."""
    if w.ndim == 3:
        return _face_normals_3d(knots, degrees, P, w, periodic)
    return _face_normals_2d(knots, degrees, P, w, periodic)


def _face_normals_2d(knots, degrees, P, w, periodic=False) -> np.ndarray:
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


def _face_normals_3d(knots, degrees, P, w, periodic=False) -> np.ndarray:
    """3D maps: per control point of each parameter face, the face surface's unit normal at the point of the face
    nearest to it (Newton on (x(s) - P_i) . dx/ds_k = 0 for the face's two parameters, from its Greville
    abscissae; the second derivatives by central differences), turned outward. On a cylinder or a sphere that
    is the radial direction through the control point, so a slip impulse there exerts no torque about the axis
    or the centre. A periodic map (x wraps) has no x faces."""
    shape = w.shape
    out = np.zeros(shape + (6, 3))
    hi = [float(t[-1]) for t in knots]
    for k in range(6):
        axis = k // 2
        if axis == 0 and periodic:
            continue
        along = [a for a in range(3) if a != axis]
        at = 0.0 if k % 2 == 0 else hi[axis]
        nodes = np.take(P, 0 if k % 2 == 0 else -1, axis=axis).reshape(-1, 3)
        g = [greville(knots[a], degrees[a]) for a in along]
        s = np.stack(np.meshgrid(*g, indexing="ij"), -1).reshape(-1, 2)
        top = np.array([hi[a] for a in along])

        def point(s):
            """x and the full J at face parameters s."""
            xi = np.empty((len(s), 3))
            xi[:, along[0]], xi[:, along[1]], xi[:, axis] = s[:, 0], s[:, 1], at
            return surface(knots, degrees, P, w, xi)

        for _ in range(60):
            x, J = point(s)
            T = J[:, :, along]
            f = np.einsum("mc,mck->mk", x - nodes, T)
            H = np.einsum("mck,mcl->mkl", T, T)
            for l in range(2):
                h = 1e-6 * top[l]
                e = np.zeros(2)
                e[l] = h
                up, dn = np.minimum(s + e, top), np.maximum(s - e, 0.0)
                dT = (point(up)[1][:, :, along] - point(dn)[1][:, :, along]) / (up[:, l] - dn[:, l])[:, None, None]
                H[:, :, l] += np.einsum("mc,mck->mk", x - nodes, dT)
            step = np.linalg.solve(H, f[..., None])[..., 0]
            s = np.clip(s - step, 0.0, top)
            if np.abs(step).max() < 1e-15 * top.max():
                break
        _, J = point(s)
        n = np.cross(J[:, :, along[0]], J[:, :, along[1]])
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        n *= np.sign((n * J[:, :, axis]).sum(-1) * (1.0 if k % 2 else -1.0))[:, None]
        index = [slice(None)] * 3
        index[axis] = 0 if k % 2 == 0 else -1
        out[tuple(index) + (k,)] = n.reshape(out[tuple(index) + (k,)].shape)
    return out


def cell_sizes(knots, degrees, P, w, breaks=None, rows=256):
    """(smallest, largest) chord between neighbouring cell corners x(knot_a, knot_b[, knot_c]): the edges of the
    physical cells (the annulus: an inner arc's chord and a radial cell). `breaks`: the corner parameters per
    axis (default: the distinct knots; a refined map's on its coarse net: scaled_knots). Evaluated a few layers
    of corners at a time (memory of about `rows` x 1024 corners)."""
    b = [np.unique(t) for t in knots] if breaks is None else [np.asarray(v, float) for v in breaks]
    d = len(b)
    lo, hi, prev = np.inf, 0.0, None
    step = max(1, rows * 1024 // max(math.prod(len(v) for v in b[1:]), 1))
    for start in range(0, len(b[0]), step):
        xi = np.stack(np.meshgrid(b[0][start:start + step], *b[1:], indexing="ij"), -1)
        x, _ = surface(knots, degrees, P, w, xi.reshape(-1, d))
        x = x.reshape(xi.shape)
        if prev is not None:
            x = np.concatenate([prev[None], x])
        edges = np.concatenate([np.linalg.norm(np.diff(x, axis=a), axis=-1).ravel() for a in range(d)])
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


def locate_host(knots, degrees, P, w, pts, tol, periodic=False, per_cell: int = 3):
    """Parameters of physical points (M, d) by Newton's method on x(xi) = x from the nearest of per_cell^d samples
    per cell, steps kept in the parameter box (wrapped along x when periodic): (xi (M, d), found (M,)), found
    where |x(xi) - x| <= tol within 30 iterations. A point outside the map's image is not found. Host side (numpy,
    scipy's k-d tree), for checks before anything is built."""
    from scipy.spatial import cKDTree

    hi = np.array([float(t[-1]) for t in knots])
    d = len(knots)
    s = [(np.arange(int(per_cell * n)) + 0.5) / per_cell for n in hi]
    samples = np.stack(np.meshgrid(*s, indexing="ij"), -1).reshape(-1, d)
    xi = samples[cKDTree(surface(knots, degrees, P, w, samples)[0]).query(pts)[1]]
    found = np.zeros(len(pts), bool)
    for _ in range(30):
        x, J = surface(knots, degrees, P, w, xi)
        r = x - pts
        found = np.linalg.norm(r, axis=1) <= tol
        if found.all():
            break
        step = np.linalg.solve(J, r[..., None])[..., 0]
        xi = xi - np.where(found[:, None], 0.0, step)
        if periodic:
            xi[:, 0] %= hi[0]
        xi = np.clip(xi, 0.0, hi)
    return xi, found


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
