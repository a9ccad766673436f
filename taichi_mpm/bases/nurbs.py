"""NURBS: rational B-splines with control-point weights, knot insertion, and 2D geometry maps x(xi) built from
them (the `annulus` map: exact circles through the weights). Issue 12, steps 2 and the map half of 3.

Rational basis (The NURBS Book, eq. 4.2): with B-splines N_i of the knot vectors (basis.make_knot_bspline) and
weights w_i > 0,
    W = sum_j N_j w_j,   R_i = N_i w_i / W,   grad R_i = (grad N_i w_i - R_i grad W) / W
exactly (no differencing), so sum R_i = 1 and sum grad R_i = 0 for any weights. A map is
    x(xi) = sum_i R_i(xi) P_i,   J = dx/dxi = sum_i P_i (x) grad_xi R_i,
and physical gradients follow from grad_x R_i = J^-T grad_xi R_i. `invert` finds xi of a physical point by
Newton's method on x(xi) = x (the solver will keep each particle's xi and start from it).

Parameter coordinates are in cells (knots 0..n per axis), as the solver's grid units. Host side: numpy
construction (knot insertion, the annulus). Kernel side: `Map.materialize()` then its @ti.func's.
Physics code only: no CLI, rendering or file I/O here.
"""

import math

import numpy as np
import taichi as ti

from .shape_functions import make_knot_bspline
from .mapgeom import bspline_values, cartesian, homogeneous, insert_knot, surface  # noqa: F401 (re-exported)


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


def annulus(r_inner: float, r_outer: float, angle: float, n_angle: int, n_radial: int, centre=(0.0, 0.0)):
    """The annulus map, quadratic in both parameters: xi (cells along the angle, counter-clockwise from +x)
    and eta (cells from r_inner to r_outer). Every line eta = const is an exact circle of radius
    r(eta) = r_inner + (r_outer - r_inner) eta / n_radial: the radial control points sit at the Greville
    abscissae of the open uniform knot vector, where linear functions are reproduced. Returns a `Map`."""
    t0, Q, wq = arc(angle, n_angle)
    t1 = np.array([0.0] * 3 + [float(k) for k in range(1, n_radial)] + [float(n_radial)] * 3)
    g = np.array([t1[j + 1: j + 3].mean() for j in range(len(t1) - 3)])
    r = r_inner + (r_outer - r_inner) * g / n_radial
    P = Q[:, None, :] * r[None, :, None] + np.asarray(centre, float)
    w = np.repeat(wq[:, None], len(r), axis=1)
    return Map([t0, t1], [2, 2], P, w)


class Map:
    """A 2D NURBS geometry map: knot vectors per parameter axis (cells), degrees, control points P (n0, n1, 2)
    and weights w (n0, n1). After `materialize()` (Taichi fields; after ti.init) its @ti.func's are
    `rational(xi)`, `point(xi)` and `invert(x, xi0)`."""

    def __init__(self, knots, degrees, P, w):
        self.knots = [np.asarray(t, float) for t in knots]
        self.degrees = list(degrees)
        self.P, self.w = np.asarray(P, float), np.asarray(w, float)
        shape = tuple(len(t) - p - 1 for t, p in zip(self.knots, self.degrees))
        if self.P.shape != shape + (2,) or self.w.shape != shape:
            raise ValueError(f"control points {self.P.shape} and weights {self.w.shape} do not match the knot "
                             f"vectors ({shape} control points)")
        if not (self.w > 0).all():
            raise ValueError("NURBS weights must be positive")
        self.n_cells = [float(t[-1] - t[0]) for t in self.knots]
        self.axes = [make_knot_bspline(p, "nurbs", t) for t, p in zip(self.knots, self.degrees)]
        self.ctrl = self.weight = None
        self.periodic = False      # a full ring: xi[0] wraps around instead of stopping at the ends
        self._build()

    def materialize(self):
        if self.ctrl is None:
            for b in self.axes:
                b.materialize()
            self.ctrl = ti.Vector.field(2, float, self.w.shape)
            self.weight = ti.field(float, self.w.shape)
            self.ctrl.from_numpy(self.P)
            self.weight.from_numpy(self.w)

    def _build(self):
        ax0, ax1 = self.axes
        S0, S1 = self.degrees[0] + 1, self.degrees[1] + 1
        hi = ti.Vector(self.n_cells)
        this = self

        @ti.func
        def rational(xi):
            """(first control point (2,), R (S0 x S1), dR/dxi0, dR/dxi1) at parameters xi."""
            w = ti.static(this.weight)
            b0, N0, dN0 = ax0.weights_1d(xi[0], 0, 0.0)
            b1, N1, dN1 = ax1.weights_1d(xi[1], 0, 0.0)
            W, W0, W1 = 0.0, 0.0, 0.0
            for i, j in ti.static(ti.ndrange(S0, S1)):
                wij = w[b0 + i, b1 + j]
                W += N0[i] * N1[j] * wij
                W0 += dN0[i] * N1[j] * wij
                W1 += N0[i] * dN1[j] * wij
            R = ti.Matrix.zero(float, S0, S1)
            R0 = ti.Matrix.zero(float, S0, S1)
            R1 = ti.Matrix.zero(float, S0, S1)
            for i, j in ti.static(ti.ndrange(S0, S1)):
                wij = w[b0 + i, b1 + j] / W
                R[i, j] = N0[i] * N1[j] * wij
                R0[i, j] = dN0[i] * N1[j] * wij - R[i, j] * W0 / W
                R1[i, j] = N0[i] * dN1[j] * wij - R[i, j] * W1 / W
            return ti.Vector([b0, b1]), R, R0, R1

        @ti.func
        def point(xi):
            """x(xi) and the Jacobian J = dx/dxi (columns: the two parameter directions)."""
            P = ti.static(this.ctrl)
            b, R, R0, R1 = rational(xi)
            x = ti.Vector.zero(float, 2)
            J = ti.Matrix.zero(float, 2, 2)
            for i, j in ti.static(ti.ndrange(S0, S1)):
                Pij = P[b[0] + i, b[1] + j]
                x += R[i, j] * Pij
                for c in ti.static(range(2)):
                    J[c, 0] += R0[i, j] * Pij[c]
                    J[c, 1] += R1[i, j] * Pij[c]
            return x, J

        @ti.func
        def invert(x, xi0, tol):
            """Newton's method on x(xi) = x from xi0, steps kept inside the parameter box (a step that leaves it
            is cut back to the box): (xi, converged). converged: |x(xi) - x| <= tol within 30 iterations and
            an invertible Jacobian on the way."""
            xi = xi0
            ok = False
            for _ in range(30):
                y, J = point(xi)
                r = y - x
                if r.norm() <= tol:
                    ok = True
                    break
                det = J.determinant()
                if det == 0.0:
                    break
                nxt = xi - J.inverse() @ r
                if ti.static(this.periodic):
                    nxt[0] -= ti.floor(nxt[0] / hi[0]) * hi[0]
                    nxt[1] = ti.min(ti.max(nxt[1], 0.0), hi[1])
                else:
                    nxt = ti.min(ti.max(nxt, 0.0), hi)
                xi = nxt
            return xi, ok

        self.rational, self.point, self.invert = rational, point, invert

    # ---------------------------------------------------------------- host side (numpy), for setup and plots
    def rational_host(self, xi: np.ndarray) -> np.ndarray:
        """All rational functions R (M, n0, n1) at parameter points (M, 2), numpy (tests, drawing)."""
        N = [bspline_values(t, p, xi[:, a]) for a, (t, p) in enumerate(zip(self.knots, self.degrees))]
        Nw = np.einsum("mi,mj,ij->mij", N[0], N[1], self.w)
        return Nw / Nw.sum(axis=(1, 2))[:, None, None]

    def surface_host(self, xi: np.ndarray):
        """x(xi) (M, 2) and the Jacobian (M, 2, 2), numpy (mapgeom.surface)."""
        return surface(self.knots, self.degrees, self.P, self.w, xi)

    def evaluate(self, xi: np.ndarray) -> np.ndarray:
        """x(xi) for parameter points (M, 2): the nonzero B-splines of each axis from the Cox-de Boor recursion in
        numpy (mapgeom.surface; independent of the kernel's code path; for setup, tests and drawing). Its memory
        grows with the points only (rational_host, every function at every point, grows with points x net)."""
        return surface(self.knots, self.degrees, self.P, self.w, xi)[0]

