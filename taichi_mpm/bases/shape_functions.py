"""Shape functions on a regular grid, in grid units (u = (x - lower) / dx).

A basis is one `@ti.func` that gives, per axis, the first node index of the particle's stencil and
the 1D weights and derivatives of the `stencil` nodes from there. Tensor products make the
multi-dimensional weights. Node coordinates (Greville abscissae for B-splines) come with it, so
transfers, boundary conditions and APIC's D_p are written once for every basis.

B-splines of degree p = 1, 2, 3 (`linear`, `quadratic`, `cubic`) use the open (clamped) knot vector
{0 (p+1 times), 1, 2, ..., n-1, n (p+1 times)} per axis and the Cox-de Boor recursion
(Piegl & Tiller, The NURBS Book, A2.2/A2.3), so partition of unity and linear reproduction hold up
to the walls; interior cells reduce to the uniform B-splines. There are n + p control points; the
first and last lie on the walls, which is where wall conditions act.

`gimp` is uGIMP (Bardenhagen & Kober 2004) on the nodes 0..n with one ghost node beyond each wall;
its particle half-width lp comes from the initial particle spacing, optionally stretched with F.

`cpdi` (CPDI1, Sadeghirad, Brannon & Burghardt 2011) is not a tensor product: it samples the linear
B-splines at the corners of each particle's deformed domain (stencils.py builds its contributions); its
grid, node coordinates and wall nodes are the linear basis's.

`ddmp` (Zhang, Ma & Giguere 2011) keeps the linear weights and blends the particle's linear gradient with the
dual-domain gradient, the linear interpolant of each node's exact average of grad N_i (docs/bases.md).

`ck` (CK-MPM's compact kernel on two staggered grids) is in compact_kernel.py.
"""

from dataclasses import dataclass, replace
from typing import Any, Callable, Optional

import numpy as np
import taichi as ti
from taichi.lang.matrix import make_matrix

from .. import traced
from . import registry
from .knots import greville


# below this half-width (grid units) a GIMP domain counts as shrunk to its particle (the cut at a wall it is on):
# the formulas' own l -> 0 limit is taken, exactly (at l = 1e-6 they agree with it to round-off, 1e-10 relative)
GIMP_MIN_HALF_WIDTH = 1e-6


@dataclass(frozen=True)
class Basis:
    name: str
    stencil: int            # nodes per axis a particle touches
    ghost: int              # nodes stored below node 0 (and above the last wall node)
    apic_gradient: bool     # APIC uses C = sum v grad(w)^T (equal to B D^-1 for multilinear weights)
    nodes: Callable[[int], int]            # nodes per axis for n cells, ghosts included
    coord: Callable                        # @ti.func: (node index, n cells) -> coordinate in grid units
    coord_py: Callable[[int, int], float]  # the same in Python
    weights_1d: Callable                   # @ti.func: (u, n cells, lp) -> (first node, w, dw)
    kind: str = "tensor"                   # how stencils.py builds a particle's contributions (registry.STENCIL_KINDS)
    smooth_1d: Optional[Callable] = None   # ddmp: @ti.func (u, n cells) -> (smoothed w, smoothed dw, blend)
    grids_1d: Optional[Callable] = None    # ck: @ti.func (u, n cells) -> the particle's cell on each of its two grids
    grids: int = 1                         # interleaved grids, each weighted 1/grids (ck: 2)
    axes: Optional[tuple] = None           # domain.knots: one Basis per axis (its own knot vector), else None
    knots: Any = None                      # a knot-vector axis: its KnotData (grid-unit knots and their fields)
    # B-splines: weights_1d of solver.quadrature domain (the span's functions averaged over the particle's domain,
    # lp its half-width); `domain_averaged` swaps it in
    averaged_1d: Optional[Callable] = None
    domain_quadrature: bool = False        # weights_1d is averaged_1d: the stencil passes each particle's lp
    sub_points: bool = False               # ddmp: weights and gradient averaged over two sub-points per axis

    @property
    def spec(self) -> registry.Spec:
        """What this basis supports (its declaration in registry.py)."""
        return registry.get(self.name)

    def axis(self, a: int) -> "Basis":
        """The 1D basis of axis a: its own knot vector with domain.knots, else this one."""
        return self.axes[a] if self.axes is not None else self

    def materialize(self):
        """Allocate the Taichi fields of knot-vector axes (after ti.init; budget.py only counts nodes)."""
        for b in self.axes or (self,):
            if b.knots is not None:
                b.knots.materialize()

    def contributions(self, dim: int) -> int:
        """(node, weight, gradient) contributions of one particle: S^d for tensor products; CPDI: 2^d nodes of
        each of its 2^d corners (a node shared by corners appears once per corner); ck: 2^d nodes on each of its
        two grids."""
        if self.kind in ("tensor", "mapped"):
            return self.stencil ** dim
        return self.spec.nodes_per_particle(dim)


def cox_de_boor(p: int, knot: Callable, whole_knots: bool = False):
    """The Cox-de Boor recursion (The NURBS Book A2.2) for values and first derivatives of the p + 1 B-splines
    that are nonzero on knot span c, [knot(c), knot(c + 1)), with 0/0 = 0 where repeated knots make a
    denominator vanish. `knot(k, n)` is the k-th knot; n the cell count, for clamped knots. Built at trace time
    (traced.py): the recursion is a few dozen expressions, which a func would walk once per axis and kernel.
    whole_knots: the knots are whole numbers (the clamped uniform vector), so every denominator is 0, 1 or 2 up to
    quadratic: the ratios multiply by 1 or 0.5 (the same bits as dividing) instead of dividing."""

    def ratio(num, den):
        if whole_knots and p <= 2:
            return num * traced.select(den > 1.5, 0.5, traced.select(den > 0.5, 1.0, 0.0))
        return traced.select(den > 0, num / den, 0.0)   # 0/0 = 0

    @traced.traced
    def evaluate(uu, c, n):
        uu, c = traced.local(uu), traced.local(c)
        N = [1.0] + [0.0] * p   # degree-j values of the functions c-j..c of the span, j = 0..p
        M = N                   # degree p-1 values, for the derivatives
        for j in range(1, p + 1):
            if j == p:
                M = list(N)
            saved = 0.0
            for r in range(j):
                right = traced.local(knot(c + r + 1, n) - uu)
                left = traced.local(uu - knot(c + 1 - j + r, n))
                temp = traced.local(ratio(N[r], right + left))
                N[r] = traced.local(saved + right * temp)
                saved = left * temp
            N[j] = traced.local(saved)
        dN = []
        for r in range(p + 1):
            # N'_{k,p} = p [N_{k,p-1} / (T_{k+p} - T_k) - N_{k+1,p-1} / (T_{k+p+1} - T_{k+1})], k = c - p + r
            d = 0.0
            if r >= 1:
                d = d + ratio(M[r - 1], knot(c + r, n) - knot(c - p + r, n))
            if r < p:
                d = d - ratio(M[r], knot(c + r + 1, n) - knot(c - p + r + 1, n))
            dN.append(p * d)
        return make_matrix(N, float), make_matrix(dN, float)

    return evaluate


def span_average(evaluate):
    """solver.quadrature domain: (u, c, n, l) -> (S, dS), the polynomial pieces of knot span c (`evaluate(u, c, n)`,
    the Cox-de Boor recursion, which is a polynomial in u for a fixed span) averaged over the particle's domain
    [u - l, u + l]:
        S  = (N(u - l) + 4 N(u) + N(u + l)) / 6        (Simpson: the exact average of a cubic)
        dS = (N(u + l) - N(u - l)) / (2 l)              (the exact average of N')
    The span stays the particle's own, so the stencil keeps its p + 1 nodes; sums over the span's functions keep
    partition of unity (sum S = 1, sum dS = 0) and linear reproduction (sum g_i S_i = u). With particle domains that
    tile the body, sum_p V_p dS_i(x_p) is then exact for the span polynomials under a constant stress (the particle
    quadrature of a cubic's quadratic N' is not next to a wall: docs/accuracy.md, "Cubic B-splines at sticky
    walls"). Linear: the identity; quadratic: dS = N', S = N + l^2 N'' / 6."""

    @traced.traced
    def average(u, c, n, l):
        N, _ = evaluate(u, c, n)
        lo, _ = evaluate(traced.local(u - l), c, n)
        hi, _ = evaluate(traced.local(u + l), c, n)
        return (lo + 4.0 * N + hi) / 6.0, (hi - lo) / (2.0 * l)

    return average


def domain_averaged(basis: Basis) -> Basis:
    """The basis with solver.quadrature domain: its (and its axes') weights averaged over each particle's domain."""
    if basis.averaged_1d is None:
        raise ValueError(f"basis {basis.name} has no domain-averaged weights (solver.quadrature domain)")
    axes = None if basis.axes is None else tuple(domain_averaged(b) for b in basis.axes)
    return replace(basis, weights_1d=basis.averaged_1d, axes=axes, domain_quadrature=True)


@traced.traced
def _cell(u, n):
    """The cell (knot span of a uniform clamped vector) holding u, clamped to 0..n-1."""
    return ti.min(ti.max(ti.cast(ti.floor(u), int), 0), n - 1)


def make_bspline(p: int, name: str) -> Basis:
    def knot_py(k, n):
        return float(min(max(k - p, 0), n))

    def coord_py(i, n):  # Greville abscissa of control point i
        return sum(knot_py(i + m, n) for m in range(1, p + 1)) / p

    @traced.traced
    def coord(i, n):
        return traced.total([ti.cast(ti.min(ti.max(i + m - p, 0), n), float) for m in range(1, p + 1)]) / p

    def clamped_knot(k, n):
        """Knot k of the open uniform vector, indexed so that span c is cell c: {0 (p+1 times), 1, .., n (p+1)}."""
        return ti.cast(ti.min(ti.max(k, 0), n), float)

    recursion = cox_de_boor(p, clamped_knot, whole_knots=True)

    @traced.traced
    def weights_1d(u, n, lp):
        c = traced.local(_cell(u, n))                    # knot span (cell) holding u
        N, dN = recursion(ti.cast(u, float), c, n)       # values and derivatives of nodes c..c+p
        return c, N, dN

    average = span_average(recursion)

    @traced.traced
    def averaged_1d(u, n, lp):
        c = traced.local(_cell(u, n))
        N, dN = average(ti.cast(u, float), c, n, ti.cast(lp, float))
        return c, N, dN

    return Basis(name, p + 1, 0, p == 1, lambda n: n + p, coord, coord_py, weights_1d, averaged_1d=averaged_1d)


def make_gimp(spec: registry.Spec, knots=None) -> Basis:
    """uGIMP (the registry's factory; no knot vectors)."""
    @ti.func
    def coord(i, n):
        return ti.cast(i - 1, float)  # storage index i holds node i - 1 (one ghost node below 0)

    @ti.func
    def weights_1d(u, n: ti.template(), lp):
        uu = ti.cast(u, float)
        l = ti.cast(lp, float)
        base = int(ti.floor(uu - 0.5))
        N = ti.Vector.zero(float, 3)
        dN = ti.Vector.zero(float, 3)
        if l < GIMP_MIN_HALF_WIDTH:
            # the domain has shrunk to the particle (cut at a wall it is on): the limit l -> 0, the linear hats of
            # its cell with their gradients taken inside the domain. The formulas below lose node 1's gradient at
            # l = 0 (and a floor on l let the domain reach past the wall: weight l/4 on the ghost and on the
            # interior node, which moved a particle on a sticky wall out and gave a slip wall's ghost node a full
            # gradient on almost no mass; docs/bases.md "Bodies flush against walls")
            c = ti.min(ti.max(int(ti.floor(uu)), 0), n - 1)
            t = uu - ti.cast(c, float)
            for k in ti.static(range(3)):
                if base + k == c:
                    N[k] = 1.0 - t
                    dN[k] = -1.0
                elif base + k == c + 1:
                    N[k] = t
                    dN[k] = 1.0
        else:
            for k in ti.static(range(3)):
                xi = uu - ti.cast(base + k, float)
                a = ti.abs(xi)
                s = 1.0 if xi >= 0 else -1.0
                if a < l:
                    N[k] = 1.0 - (xi * xi + l * l) / (2.0 * l)
                    dN[k] = -xi / l
                elif a < 1.0 - l:
                    N[k] = 1.0 - a
                    dN[k] = -s
                elif a < 1.0 + l:
                    N[k] = (1.0 + l - a) ** 2 / (4.0 * l)
                    dN[k] = -s * (1.0 + l - a) / (2.0 * l)
        return base + 1, N, dN  # storage index of the first node

    return Basis(spec.name, 3, 1, False, lambda n: n + 3, coord, lambda i, n: float(i - 1), weights_1d)


def make_cpdi(spec: registry.Spec, knots=None) -> Basis:
    """CPDI1 over the linear B-splines: the grid, wall nodes and 1D weights are the linear basis's; `stencil` is
    the nodes per axis an undeformed domain (half-width <= half a cell) reaches (budget and crack reach)."""
    return replace(make_bspline(1, spec.name), stencil=3, apic_gradient=False, kind=spec.stencil_kind)


def make_ddmp(spec: registry.Spec, knots=None) -> Basis:
    """DDMP (Zhang, Ma & Giguere 2011) over the linear grid functions, nodes 0..n plus one ghost node beyond each
    wall (storage index i holds node i - 1, as gimp) so that the smoothed gradient's 4-node stencil stays in range.
    weights_1d gives the linear weights and derivatives of nodes c-1..c+2 (c: the particle's cell; the outer two
    are zero); smooth_1d gives the dual-domain functions of the same nodes (docs/bases.md):
        Ns_i(u) = sum_j N_j(u) M_ij,   Ds_i(u) = sum_j N_j(u) D_ij,
        M_ij = int N_j N_i / int N_j,  D_ij = int N_j N_i' / int N_j   (exact integrals over node j's support)
    and the blend alpha(u) = 4 t (1 - t), t = u - c, of the particle's own gradient (zero on cell faces)."""
    third, sixth = 1.0 / 3.0, 1.0 / 6.0

    @ti.func
    def coord(i, n):
        return ti.cast(i - 1, float)

    @ti.func
    def cell(u, n):
        c = _cell(u, n)
        return c, ti.cast(u, float) - ti.cast(c, float)

    @ti.func
    def weights_1d(u, n: ti.template(), lp):
        c, t = cell(u, n)
        N = ti.Vector([0.0, 1.0 - t, t, 0.0])
        dN = ti.Vector([0.0, -1.0, 1.0, 0.0])
        return c, N, dN   # storage index of node c - 1

    @ti.func
    def column(j, n: ti.template()):
        """(M_{j-1,j}, M_jj, M_{j+1,j}, D_{j-1,j}, D_jj, D_{j+1,j}) in grid units; a wall node's support is one
        cell, so its averages are one-sided."""
        res = ti.Vector([sixth, 2.0 * third, sixth, -0.5, 0.0, 0.5])
        if j == 0:
            res = ti.Vector([0.0, 2.0 * third, third, 0.0, -1.0, 1.0])
        elif j == n:
            res = ti.Vector([third, 2.0 * third, 0.0, -1.0, 1.0, 0.0])
        return res

    @ti.func
    def smooth_1d(u, n: ti.template()):
        c, t = cell(u, n)
        a, b = column(c, n), column(c + 1, n)   # node c (weight 1 - t) and node c + 1 (weight t)
        s = 1.0 - t
        Ns = ti.Vector([s * a[0], s * a[1] + t * b[0], s * a[2] + t * b[1], t * b[2]])
        Ds = ti.Vector([s * a[3], s * a[4] + t * b[3], s * a[5] + t * b[4], t * b[5]])
        return Ns, Ds, 4.0 * t * s

    return Basis(spec.name, 4, 1, True, lambda n: n + 3, coord, lambda i, n: float(i - 1), weights_1d, "tensor",
                 smooth_1d)


class KnotData:
    """One axis's knot vector in grid units (numpy) and, once materialized, as Taichi fields with the Greville
    abscissae of its control points."""

    def __init__(self, t: np.ndarray, p: int):
        self.t, self.p = np.asarray(t, float), p
        self.g = greville(self.t, p)
        self.field = self.coords = None

    def materialize(self):
        if self.field is None:
            self.field = ti.field(float, len(self.t))
            self.coords = ti.field(float, len(self.g))
            self.field.from_numpy(self.t)
            self.coords.from_numpy(self.g)


def make_knot_bspline(p: int, name: str, t: np.ndarray) -> Basis:
    """B-splines of degree p on the open knot vector t (grid units, any spacing, interior knots repeated up to p
    times): span search by bisection, Cox-de Boor values (The NURBS Book A2.2) and first derivatives, with
    0/0 = 0 wherever repeated knots make a denominator vanish. Control point i has the Greville abscissa g_i."""
    data = KnotData(t, p)
    m = len(data.t)
    n_ctrl = m - p - 1
    first, last = p, m - p - 2     # the nonempty spans lie between knots first..last + 1

    @ti.func
    def coord(i, n):
        return data.coords[i]

    @ti.func
    def span(u):
        """The knot span c with T[c] <= u < T[c + 1], nonempty (after a repeated knot, the last copy); u beyond
        the ends takes the end spans, u on the last knot the last span."""
        T = ti.static(data.field)
        lo, hi = first, last
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if T[mid] <= u:
                lo = mid
            else:
                hi = mid - 1
        return lo

    def knot(k, n):
        return traced.at(data.field, k)

    recursion = cox_de_boor(p, knot)

    @ti.func
    def weights_1d(u, n: ti.template(), lp):
        uu = ti.cast(u, float)
        c = span(uu)
        N, dN = recursion(uu, c, n)   # values and derivatives of control points c-p..c
        return c - p, N, dN

    average = span_average(recursion)

    @ti.func
    def averaged_1d(u, n: ti.template(), lp):
        uu = ti.cast(u, float)
        c = span(uu)
        N, dN = average(uu, c, n, ti.cast(lp, float))
        return c - p, N, dN

    g = data.g
    return Basis(name, p + 1, 0, p == 1, lambda n: n_ctrl, coord, lambda i, n: float(g[i]), weights_1d,
                 knots=data, averaged_1d=averaged_1d)


def make_bspline_basis(spec: registry.Spec, knots=None) -> Basis:
    """The registry's factory of the B-spline bases: degree spec.degree on the uniform open knot vector, or per axis
    on the given one (`knots`: per axis a knot vector in grid units or None, knots.grid_knots)."""
    uniform = make_bspline(spec.degree, spec.name)
    if knots is None or all(t is None for t in knots):
        return uniform
    axes = tuple(uniform if t is None else make_knot_bspline(spec.degree, spec.name, t) for t in knots)
    return replace(uniform, axes=axes)


def make_basis(name: str, knots=None) -> Basis:
    """The shape functions of the registered basis `name`; `knots`: per axis a knot vector in grid units or None
    (knots.grid_knots), for the bases that take domain.knots."""
    return registry.get(name).build(knots)


def with_sub_points(basis: Basis) -> Basis:
    """ddmp with solver.ddmp.sub_points: weights and gradient averaged over two sub-points per axis
    (ddmp_gradient.py), whose stencil reaches one node further (5 per axis; one more ghost node beyond the upper
    wall)."""
    if basis.smooth_1d is None:
        raise ValueError(f"basis {basis.name} has no sub-points (solver.ddmp.sub_points is ddmp's)")
    nodes = basis.nodes
    return replace(basis, stencil=basis.stencil + 1, nodes=lambda n: nodes(n) + 1, sub_points=True)


def configured_basis(cfg) -> Basis:
    """The shape functions a config runs with: solver.basis on domain.knots' vectors, with the options that change
    them (solver.quadrature domain, solver.ddmp.sub_points). The solver and the memory estimate build it alike."""
    from .knots import grid_knots
    basis = make_basis(cfg.solver.basis, grid_knots(cfg))
    if cfg.solver.quadrature == "domain":
        basis = domain_averaged(basis)
    if cfg.solver.basis == "ddmp" and cfg.solver.ddmp.sub_points:
        basis = with_sub_points(basis)
    return basis
