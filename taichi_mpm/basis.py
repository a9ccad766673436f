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
"""

from dataclasses import dataclass, replace
from typing import Callable, Optional

import taichi as ti

BASES = ("linear", "gimp", "quadratic", "cubic", "cpdi", "ddmp")
TENSOR_BASES = ("linear", "gimp", "quadratic", "cubic", "ddmp")   # per-axis weights: the tensor-product fast path


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
    kind: str = "tensor"                   # how stencils.py builds a particle's contributions: tensor, cpdi
    smooth_1d: Optional[Callable] = None   # ddmp: @ti.func (u, n cells) -> (smoothed w, smoothed dw, blend)

    def contributions(self, dim: int) -> int:
        """(node, weight, gradient) contributions of one particle: S^d for tensor products; CPDI: 2^d nodes of
        each of its 2^d corners (a node shared by corners appears once per corner)."""
        return self.stencil ** dim if self.kind == "tensor" else 4 ** dim


@ti.func
def _knot(k, p: ti.template(), n: ti.template()):
    return ti.min(ti.max(k - p, 0), n)


def make_bspline(p: int, name: str) -> Basis:
    def knot_py(k, n):
        return float(min(max(k - p, 0), n))

    def coord_py(i, n):  # Greville abscissa of control point i
        return sum(knot_py(i + m, n) for m in range(1, p + 1)) / p

    @ti.func
    def coord(i, n):
        s = 0.0
        for m in ti.static(range(1, p + 1)):
            s += ti.cast(_knot(i + m, p, n), float)
        return s / p

    @ti.func
    def weights_1d(u, n: ti.template(), lp):
        c = ti.min(ti.max(int(ti.floor(u)), 0), n - 1)  # knot span (cell) holding u
        N = ti.Vector.zero(float, p + 1)   # degree-p values of nodes c..c+p
        M = ti.Vector.zero(float, p + 1)   # degree p-1 values, for the derivatives
        N[0] = 1.0
        uu = ti.cast(u, float)
        for j in ti.static(range(1, p + 1)):
            if ti.static(j == p):
                M = N
            saved = 0.0
            for r in ti.static(range(j)):
                right = ti.cast(ti.min(ti.max(c + r + 1, 0), n), float) - uu
                left = uu - ti.cast(ti.min(ti.max(c + 1 - j + r, 0), n), float)
                temp = N[r] / (right + left)
                N[r] = saved + right * temp
                saved = left * temp
            N[j] = saved
        dN = ti.Vector.zero(float, p + 1)
        for r in ti.static(range(p + 1)):
            # N'_{k,p} = p [N_{k,p-1} / (U_{k+p} - U_k) - N_{k+1,p-1} / (U_{k+p+1} - U_{k+1})], k = c + r
            d = 0.0
            if ti.static(r >= 1):
                den = ti.cast(ti.min(ti.max(c + r, 0), n) - ti.min(ti.max(c + r - p, 0), n), float)
                if den > 0:
                    d += M[r - 1] / den
            if ti.static(r < p):
                den = ti.cast(ti.min(ti.max(c + r + 1, 0), n) - ti.min(ti.max(c + r + 1 - p, 0), n), float)
                if den > 0:
                    d -= M[r] / den
            dN[r] = p * d
        return c, N, dN

    return Basis(name, p + 1, 0, p == 1, lambda n: n + p, coord, coord_py, weights_1d)


def make_gimp() -> Basis:
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

    return Basis("gimp", 3, 1, False, lambda n: n + 3, coord, lambda i, n: float(i - 1), weights_1d)


def make_cpdi() -> Basis:
    """CPDI1 over the linear B-splines: the grid, wall nodes and 1D weights are the linear basis's; `stencil` is
    the nodes per axis an undeformed domain (half-width <= half a cell) reaches (budget and crack reach)."""
    return replace(make_bspline(1, "cpdi"), stencil=3, apic_gradient=False, kind="cpdi")


def make_ddmp() -> Basis:
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
        c = ti.min(ti.max(int(ti.floor(u)), 0), n - 1)
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

    return Basis("ddmp", 4, 1, True, lambda n: n + 3, coord, lambda i, n: float(i - 1), weights_1d, "tensor",
                 smooth_1d)


def make_basis(name: str) -> Basis:
    if name == "gimp":
        return make_gimp()
    if name == "cpdi":
        return make_cpdi()
    if name == "ddmp":
        return make_ddmp()
    return make_bspline({"linear": 1, "quadratic": 2, "cubic": 3}[name], name)
