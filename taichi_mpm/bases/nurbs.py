"""NURBS: rational B-splines with control-point weights, knot insertion, and 2D and 3D geometry maps x(xi) built
from them (the `annulus`, `cylinder` and `shell` maps: exact circles and spheres through the weights). Issue 12,
steps 2 and the map half of 3; 3D maps issue 32.

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

import itertools

import numpy as np
import taichi as ti

from .shape_functions import make_knot_bspline
from .mapgeom import (arc, bspline_values, cartesian, cylinder_net, homogeneous, insert_knot, radii,  # noqa: F401
                      shell_net, surface)                                                   # (re-exported)


def annulus(r_inner: float, r_outer: float, angle: float, n_angle: int, n_radial: int, centre=(0.0, 0.0)):
    """The annulus map, quadratic in both parameters: xi (cells along the angle, counter-clockwise from +x)
    and eta (cells from r_inner to r_outer). Every line eta = const is an exact circle of radius
    r(eta) = r_inner + (r_outer - r_inner) eta / n_radial: the radial control points sit at the Greville
    abscissae of the open uniform knot vector, where linear functions are reproduced. Returns a `Map`."""
    t0, Q, wq = arc(angle, n_angle)
    t1, r = radii(r_inner, r_outer, n_radial)
    P = Q[:, None, :] * r[None, :, None] + np.asarray(centre, float)
    w = np.repeat(wq[:, None], len(r), axis=1)
    return Map([t0, t1], [2, 2], P, w)


def cylinder(r_inner: float, r_outer: float, angle: float, length: float, cells, centre=(0.0, 0.0, 0.0)):
    """The thick-walled cylinder map (3D, quadratic per parameter; mapgeom.cylinder_net). Returns a `Map`."""
    knots, P, w = cylinder_net(r_inner, r_outer, angle, length, cells, centre)
    return Map(knots, [2, 2, 2], P, w)


def shell(r_inner: float, r_outer: float, angle: float, latitudes, cells, centre=(0.0, 0.0, 0.0)):
    """The spherical shell map between two latitudes (3D, quadratic per parameter; mapgeom.shell_net)."""
    knots, P, w = shell_net(r_inner, r_outer, angle, latitudes, cells, centre)
    return Map(knots, [2, 2, 2], P, w)


UNROLL_TERMS = 9     # a point's functions are unrolled up to this many (2D quadratic), else looped (3D)


class Map:
    """A 2D or 3D NURBS geometry map: knot vectors per parameter axis (cells), degrees, control points P
    (n0, n1[, n2], d) and weights w (n0, n1[, n2]). After `materialize()` (Taichi fields; after ti.init) its
    @ti.func's are `rational(xi)`, `point(xi)` and `invert(x, xi0)`. A particle's (p + 1)^d functions are kept
    flat, the last axis fastest (stencil_parts.flat_index)."""

    def __init__(self, knots, degrees, P, w):
        self.knots = [np.asarray(t, float) for t in knots]
        self.degrees = list(degrees)
        self.dim = len(self.knots)
        self.P, self.w = np.asarray(P, float), np.asarray(w, float)
        shape = tuple(len(t) - p - 1 for t, p in zip(self.knots, self.degrees))
        if self.P.shape != shape + (self.dim,) or self.w.shape != shape:
            raise ValueError(f"control points {self.P.shape} and weights {self.w.shape} do not match the knot "
                             f"vectors ({shape} control points)")
        if not (self.w > 0).all():
            raise ValueError("NURBS weights must be positive")
        self.n_cells = [float(t[-1] - t[0]) for t in self.knots]
        self.axes = [make_knot_bspline(p, "nurbs", t) for t, p in zip(self.knots, self.degrees)]
        self.span = [p + 1 for p in self.degrees]     # functions per axis at a point
        self.ctrl = self.weight = None
        self.periodic = False      # a full ring: xi[0] wraps around instead of stopping at the ends
        self._build()

    def materialize(self):
        if self.ctrl is None:
            for b in self.axes:
                b.materialize()
            self.ctrl = ti.Vector.field(self.dim, float, self.w.shape)
            self.weight = ti.field(float, self.w.shape)
            self.ctrl.from_numpy(self.P)
            self.weight.from_numpy(self.w)

    def _build(self):
        D, span, axes = self.dim, self.span, self.axes
        S = max(span)
        terms = list(itertools.product(*[range(s) for s in span]))   # flat order: the last axis fastest
        K = len(terms)
        this = self

        @ti.func
        def term(k):
            """The multi-index (p + 1 per axis, the last axis fastest) of flat function number k."""
            I = ti.Vector.zero(ti.i32, D)
            rest = k
            for c in ti.static(range(D)):
                a = ti.static(D - 1 - c)
                I[a] = rest % span[a]
                rest //= span[a]
            return I

        @ti.func
        def product(N: ti.template(), dN: ti.template(), I: ti.template(), a: ti.template()):
            """prod_c N_c(I_c), with the derivative in place of axis a's factor (a = -1: none), in axis order. I: a
            tuple of ints (unrolled: the matrices are indexed at compile time) or a run-time index vector."""
            v = dN[0, I[0]] if ti.static(a == 0) else N[0, I[0]]
            for c in ti.static(range(1, D)):
                v *= dN[c, I[c]] if ti.static(a == c) else N[c, I[c]]
            return v

        # A 2D point's 9 functions are unrolled (kept in registers, indexed at compile time); 3D's 27 run as a
        # loop: unrolled, each with d + 1 products, they made Newton's inversion (which evaluates them per
        # iteration) take a minute to compile. The sums keep the same order either way.
        unrolled = K <= UNROLL_TERMS
        offsets = [ti.Vector(list(t)) for t in terms]     # compile-time constants of the unrolled terms

        @ti.func
        def weight_term(N: ti.template(), dN: ti.template(), b, I: ti.template(), off: ti.template()):
            """w_k prod N and its parameter derivatives, for W = sum_k N_k w_k and dW/dxi (I: the term's
            multi-index, off: it as a vector)."""
            wI = w_field()[b + off]
            sd = ti.Vector.zero(float, D)
            for a in ti.static(range(D)):
                sd[a] = product(N, dN, I, a) * wI
            return product(N, dN, I, -1) * wI, sd

        @ti.func
        def basis_term(N: ti.template(), dN: ti.template(), b, I: ti.template(), off: ti.template(), W, Wd):
            """R_k and dR_k/dxi by the quotient rule."""
            wI = w_field()[b + off] / W
            r = product(N, dN, I, -1) * wI
            g = ti.Vector.zero(float, D)
            for a in ti.static(range(D)):
                g[a] = product(N, dN, I, a) * wI - r * Wd[a] / W
            return r, g

        @ti.func
        def w_field():
            return ti.static(this.weight)

        @ti.func
        def rational(xi):
            """(first control point (d,), R ((p+1)^d,), dR/dxi ((p+1)^d, d)) at parameters xi."""
            b = ti.Vector.zero(ti.i32, D)
            N = ti.Matrix.zero(float, D, S)
            dN = ti.Matrix.zero(float, D, S)
            for a in ti.static(range(D)):
                ba, Na, dNa = ti.static(axes)[a].weights_1d(xi[a], 0, 0.0)
                b[a] = ba
                for i in ti.static(range(span[a])):
                    N[a, i], dN[a, i] = Na[i], dNa[i]
            W = 0.0
            Wd = ti.Vector.zero(float, D)
            R = ti.Vector.zero(float, K)
            G = ti.Matrix.zero(float, K, D)
            if ti.static(unrolled):
                w = ti.static(this.weight)
                for k in ti.static(range(K)):
                    I = ti.static(terms[k])
                    wI = w[b + ti.static(offsets)[k]]
                    W += product(N, dN, I, -1) * wI
                    for a in ti.static(range(D)):
                        Wd[a] += product(N, dN, I, a) * wI
                for k in ti.static(range(K)):
                    I = ti.static(terms[k])
                    wI = w[b + ti.static(offsets)[k]] / W
                    R[k] = product(N, dN, I, -1) * wI
                    for a in ti.static(range(D)):
                        G[k, a] = product(N, dN, I, a) * wI - R[k] * Wd[a] / W
            else:
                for k in range(K):
                    off = term(k)
                    s, sd = weight_term(N, dN, b, off, off)
                    W += s
                    Wd += sd
                for k in range(K):
                    off = term(k)
                    R[k], g = basis_term(N, dN, b, off, off, W, Wd)
                    for a in ti.static(range(D)):
                        G[k, a] = g[a]
            return b, R, G

        self.terms, self.offsets = terms, offsets
        self.term, self.rational = term, rational
        self.jacobian, self.point = self._build_point(K, unrolled)
        self.invert = self._build_invert()

    def _build_point(self, K, unrolled):
        """The funcs jacobian(b, G) and point(xi) -> (x, J)."""
        D, term, rational, this, offsets = self.dim, self.term, self.rational, self, self.offsets

        @ti.func
        def jacobian_term(b, G, k: ti.template(), off: ti.template()):
            """P_k (x) dR_k/dxi (k: an int when unrolled, off: the term's index vector)."""
            Pk = ti.static(this.ctrl)[b + off]
            J = ti.Matrix.zero(float, D, D)
            for c in ti.static(range(D)):
                for a in ti.static(range(D)):
                    J[c, a] = G[k, a] * Pk[c]
            return J

        @ti.func
        def jacobian(b, G):
            """J = dx/dxi = sum_k P_k (x) dR_k/dxi (columns: the parameter directions)."""
            J = ti.Matrix.zero(float, D, D)
            if ti.static(unrolled):
                P = ti.static(this.ctrl)
                for k in ti.static(range(K)):
                    Pk = P[b + ti.static(offsets)[k]]
                    for c in ti.static(range(D)):
                        for a in ti.static(range(D)):
                            J[c, a] += G[k, a] * Pk[c]
            else:
                for k in range(K):
                    J += jacobian_term(b, G, k, term(k))
            return J

        @ti.func
        def point(xi):
            """x(xi) and the Jacobian J = dx/dxi."""
            P = ti.static(this.ctrl)
            b, R, G = rational(xi)
            x = ti.Vector.zero(float, D)
            if ti.static(unrolled):
                for k in ti.static(range(K)):
                    x += R[k] * P[b + ti.static(offsets)[k]]
            else:
                for k in range(K):
                    x += R[k] * P[b + term(k)]
            return x, jacobian(b, G)

        return jacobian, point

    def _build_invert(self):
        D, point, this = self.dim, self.point, self
        hi = ti.Vector(self.n_cells)

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
                    for a in ti.static(range(1, D)):
                        nxt[a] = ti.min(ti.max(nxt[a], 0.0), hi[a])
                else:
                    nxt = ti.min(ti.max(nxt, 0.0), hi)
                xi = nxt
            return xi, ok

        return invert

    # ---------------------------------------------------------------- host side (numpy), for setup and plots
    def rational_host(self, xi: np.ndarray) -> np.ndarray:
        """All rational functions R (M, n0, n1[, n2]) at parameter points (M, d), numpy (tests, drawing)."""
        N = [bspline_values(t, p, xi[:, a]) for a, (t, p) in enumerate(zip(self.knots, self.degrees))]
        Nw = np.einsum("mi,mj,ij->mij", N[0], N[1], self.w) if self.dim == 2 else \
            np.einsum("mi,mj,mk,ijk->mijk", N[0], N[1], N[2], self.w)
        return Nw / Nw.sum(axis=tuple(range(1, self.dim + 1))).reshape((-1,) + (1,) * self.dim)

    def surface_host(self, xi: np.ndarray):
        """x(xi) (M, d) and the Jacobian (M, d, d), numpy (mapgeom.surface)."""
        return surface(self.knots, self.degrees, self.P, self.w, xi)

    def evaluate(self, xi: np.ndarray) -> np.ndarray:
        """x(xi) for parameter points (M, d): the nonzero B-splines of each axis from the Cox-de Boor recursion in
        numpy (mapgeom.surface; independent of the kernel's code path; for setup, tests and drawing). Its memory
        grows with the points only (rational_host, every function at every point, grows with points x net)."""
        return surface(self.knots, self.degrees, self.P, self.w, xi)[0]

