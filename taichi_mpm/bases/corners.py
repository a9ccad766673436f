"""CPDI's stencils: the linear grid functions N_i sampled at the 2^d corners of each particle's domain.

Both variants replace N_i over the domain Omega_p by its multilinear interpolant from the corners x_c,
N_i(x) ~ sum_c M_c(x) N_i(x_c) (M_c: the domain's own multilinear corner functions), and take the domain
averages
    S_ip      = sum_c share_c N_i(x_c),    share_c = (1/V_p) int_Omega_p M_c
    grad S_ip = sum_c N_i(x_c) g_c,        g_c     = (1/V_p) int_Omega_p grad M_c
The contribution index is (corner bits, node offset bits): 4^d contributions. While the corners are inside the
grid, sum S = 1, sum S x_i = sum_c share_c x_c = x_p, sum grad S = 0 and sum x_i (x) grad S = I exactly
(tests/test_cpdi.py, tests/test_cpdi2.py).

- cpdi1 (Sadeghirad, Brannon & Burghardt 2011, IJNME 86): the domain is the parallelogram / parallelepiped
  x_p + A xi, xi in [-1, 1]^d, with half-edge vectors A = F A0 (A0 = half the initial spacing per axis; full F,
  rotation included): corners x_p + A s_c (s_c in {-1, 1}^d), share_c = 2^-d and g_c = 2^-d A^-T s_c.
- cpdi2 (Sadeghirad, Brannon & Guilkey 2013, IJNME 95; the quadrilateral / hexahedral form): the corners are points
  of their own (extensions/domain_corners.py keeps them), moved with the grid velocity at the corner,
  x_c += dt sum_i N_i(x_c) v_i, and the particle sits at its domain's centroid sum_c share_c x_c. The domain is
  the multilinear (isoparametric) image of [-1, 1]^d; share_c and g_c are integrated exactly by 2^d Gauss points:
  with J = dx/dxi, int M_c = sum_g M_c(xi_g) det J_g and int grad M_c = sum_g cof(J_g) grad_xi M_c(xi_g)
  (cof J = det J J^-T; both integrands are polynomials of degree <= 3 per axis, which 2-point Gauss integrates).
  Neighbouring particles seeded on one lattice share their corners and keep sharing them (the same point moved by
  the same velocities), so the domains tile the body however it deforms: sum_p V_p grad S_ip = 0 at a node whose
  functions do not reach the body's surface, where CPDI1's parallelograms gap and overlap under a non-uniform
  deformation (docs/bases.md, "CPDI2").

APIC's D_p = sum_c share_c (diag(t (1 - t)) dx^2 + (x_c - x_p)(x_c - x_p)^T) (t: the corner's position in its
cell; cpdi1's corner spread is A A^T) is never singular for a domain of positive volume.

Physics code only: no CLI, rendering or file I/O here.
"""
import itertools
import math

import taichi as ti

from .stencil_parts import KernelContext, Stencil, domain_half_width, flat_index, loops

CPDI_CORNER_TOL = 0.01   # cells: how far a CPDI domain corner may lie beyond a wall (make_domain_check)
CORNER_CODE, FOLD_CODE = 5, 7   # failure codes (solver.FAIL_CAUSES): a corner past a wall, a folded cpdi2 domain
GAUSS = 1.0 / math.sqrt(3.0)    # 2-point Gauss abscissa on [-1, 1] (weights 1)


def corner_signs(dim: int) -> list:
    """s_c per corner c = sum_a bit_a 2^a: s_ca = 2 bit_a - 1 (the order VTK's pixel / voxel cells use)."""
    return [[2.0 * ((c >> a) & 1) - 1.0 for a in range(dim)] for c in range(2 ** dim)]


def _gauss_tables(dim: int):
    """At Gauss point g (xi = GAUSS s_g): M[g][c] = M_c(xi) and dM[g][c][a] = dM_c / dxi_a, as constants."""
    s = corner_signs(dim)
    M, dM = [], []
    for g in range(2 ** dim):
        xi = [GAUSS * s[g][a] for a in range(dim)]
        hat = [[0.5 * (1.0 + s[c][a] * xi[a]) for a in range(dim)] for c in range(2 ** dim)]
        M.append([math.prod(h) for h in hat])
        dM.append([[0.5 * s[c][a] * math.prod(hat[c][b] for b in range(dim) if b != a) for a in range(dim)]
                   for c in range(2 ** dim)])
    return M, dM


def _cofactor(dim: int):
    """@ti.func (J) -> det(J) J^-T, without a division (0 for a singular J)."""
    @ti.func
    def cof(J):
        out = ti.Matrix.zero(float, dim, dim)
        if ti.static(dim == 1):
            out[0, 0] = 1.0
        elif ti.static(dim == 2):
            out = ti.Matrix([[J[1, 1], -J[1, 0]], [-J[0, 1], J[0, 0]]])
        else:   # column a: the cross product of J's other two columns
            for a in ti.static(range(3)):
                u = ti.Vector([J[0, (a + 1) % 3], J[1, (a + 1) % 3], J[2, (a + 1) % 3]])
                w = ti.Vector([J[0, (a + 2) % 3], J[1, (a + 2) % 3], J[2, (a + 2) % 3]])
                c = u.cross(w)
                for b in ti.static(range(3)):
                    out[b, a] = c[b]
        return out
    return cof


def _gauss_jacobian(dim: int):
    """(@ti.func () -> the tables, @ti.func (tables, X: the corners as rows, g: a run-time Gauss point) -> J =
    dx/dxi there, M[g][c]): the tables are local matrices indexed by the run-time g, built once per particle."""
    nc = 2 ** dim
    M, dM = _gauss_tables(dim)
    dM_lists = [[[dM[g][c][a] for c in range(nc)] for g in range(nc)] for a in range(dim)]

    @ti.func
    def tables():
        return [ti.Matrix(dM_lists[a]) for a in ti.static(range(dim))]   # [g, c] per axis a

    @ti.func
    def jacobian(dM_tables: ti.template(), X, g):
        J = ti.Matrix.zero(float, dim, dim)
        for c in ti.static(range(nc)):
            for a in ti.static(range(dim)):
                for b in ti.static(range(dim)):
                    J[b, a] += X[c, b] * dM_tables[a][g, c]
        return J
    return tables, jacobian, M


def make_domain_geometry(dim: int, gradients: bool = True):
    """@ti.func (X: the corners as rows, 2^d x d) -> (V_p, share_c, g_c as rows, the smallest det J at a Gauss
    point): the multilinear domain's volume and the corner functions' averages, exact (module docstring). The
    Gauss points are a run-time loop over constant tables: unrolled, 3D's eight made every kernel that reads the
    stencil compile for minutes. gradients False: g_c stays zero (not computed; the centroid needs the shares only,
    and with the gradients 3D cpdi2's G2P compiled ~3 s longer)."""
    nc = 2 ** dim
    tables, jacobian, M = _gauss_jacobian(dim)
    cof = _cofactor(dim)

    @ti.func
    def geometry(X):
        M_table = ti.Matrix(M)   # [g, c], local: indexed by the run-time g
        dM_tables = tables()
        V = 0.0
        det_min = 1e30   # det J ~ (domain size)^d, far below this in any unit a scene uses
        shares = ti.Vector.zero(float, nc)
        grads = ti.Matrix.zero(float, nc, dim)
        for g in range(nc):
            J = jacobian(dM_tables, X, g)
            det = J.determinant()
            V += det
            det_min = ti.min(det_min, det)
            for c in ti.static(range(nc)):
                shares[c] += M_table[g, c] * det
            if ti.static(gradients):
                C = cof(J)
                for c in ti.static(range(nc)):
                    for a in ti.static(range(dim)):
                        for b in ti.static(range(dim)):
                            grads[c, a] += C[a, b] * dM_tables[b][g, c]
        return V, shares / V, grads / V, det_min
    return geometry


def make_centroid(dim: int):
    """@ti.func (X: corners as rows) -> (the domain's centroid sum_c share_c x_c, the smallest det J at a Gauss
    point: <= 0 where the domain folded)."""
    geometry = make_domain_geometry(dim, gradients=False)

    @ti.func
    def centroid(X):
        V, shares, g, det_min = geometry(X)
        out = ti.Vector.zero(float, dim)
        for c in ti.static(range(2 ** dim)):
            out += shares[c] * ti.Vector([X[c, a] for a in range(dim)])
        return out, det_min
    return centroid


def _corner_weights(basis, n_cells, lower, inv_dx, dim):
    """@ti.func (xc) -> (first node's storage index, its linear weight per axis) of a corner; a corner further
    beyond a wall than the domain check admits is weighted at that distance (the check stops the run in this step's
    G2P; extrapolating further, a domain on a face reaches r0 past it: weights 1.25 / -0.25, made D_p indefinite, a
    NaN before the check could name the cause)."""
    @ti.func
    def weights(xc):
        u = (xc - lower) * inv_dx
        base = ti.Vector.zero(int, dim)
        w0 = ti.Vector.zero(float, dim)
        for a in ti.static(range(dim)):
            ua = ti.min(ti.max(u[a], -CPDI_CORNER_TOL), n_cells[a] + CPDI_CORNER_TOL)
            b, w, dw = basis.weights_1d(ua, n_cells[a], 0.0)
            base[a] = b
            w0[a] = w[0]
        return base, w0
    return weights


def cpdi_stencil(ctx: KernelContext) -> Stencil:
    dim, dx, inv_dx = ctx.dim, ctx.dx, 1.0 / ctx.dx
    basis, n_cells, lower = ctx.basis, ctx.n_cells, ctx.lower
    nc = 2 ** dim                      # corners
    share = 1.0 / nc
    x, F = ctx.x, ctx.F
    corners = ctx.extra.get("corners")   # cpdi2: the tracked corners (extensions/domain_corners.py)
    tracked = corners is not None
    half_width = domain_half_width(ctx)
    signs = ti.Matrix(corner_signs(dim))
    corner_weights = _corner_weights(basis, n_cells, lower, inv_dx, dim)
    geometry = make_domain_geometry(dim)
    # The loops over corners: unrolled in long runs (solver.unroll), a run-time loop in short ones. 3D cpdi2's G2P
    # compiled for 18-22 s with them unrolled (the corners' 2^d x 2^d sparse reads) and 5-6 s at run time, where its
    # steps were 10-20 % slower (64 000 particles; docs/performance.md, "cpdi2's compile").
    unrolled = ctx.unroll is not False

    @ti.func
    def corner_sign(c):
        s = ti.Vector.zero(float, dim)
        for a in ti.static(range(dim)):
            s[a] = signs[c, a]
        return s

    @ti.func
    def corner_stencil(c, X: ti.template(), xp, shares: ti.template(), base: ti.template(), W0: ti.template(),
                       spread: ti.template()):
        """Corner c's first node and weights into row c of base and W0; cpdi2: its share of the spread."""
        xc = ti.Vector([X[c, a] for a in ti.static(range(dim))])
        b, w0 = corner_weights(xc)
        for a in ti.static(range(dim)):
            base[c, a] = b[a]
            W0[c, a] = w0[a]
        if ti.static(tracked):
            spread += shares[c] * (xc - xp).outer_product(xc - xp)

    @ti.func
    def at(p):
        """Per corner: first node of its linear stencil (storage index), the weight of that node per axis
        (the other node has 1 - that) and its gradient direction g_c; the particle position, the corners' shares
        (cpdi1: all 2^-d) and spread sum_c share_c (x_c - x_p)(x_c - x_p)^T."""
        xp = x[p]
        base = ti.Matrix.zero(int, nc, dim)
        W0 = ti.Matrix.zero(float, nc, dim)
        GS = ti.Matrix.zero(float, nc, dim)
        shares = ti.Vector([share] * nc)
        spread = ti.Matrix.zero(float, dim, dim)
        X = ti.Matrix.zero(float, nc, dim)
        if ti.static(tracked):
            X = corners[p]
            V, shares, GS, det_min = geometry(X)
        else:
            A = F[p] * (half_width(p) * dx)           # half-edge vectors r_a = F r_a0 as columns
            G = A.inverse().transpose() * share
            spread = A @ A.transpose()
            for c in ti.static(range(nc)):
                s = corner_sign(c)
                xc = xp + A @ s
                g = G @ s
                for a in ti.static(range(dim)):
                    X[c, a] = xc[a]
                    GS[c, a] = g[a]
        if ti.static(unrolled):
            for c in ti.static(range(nc)):
                corner_stencil(c, X, xp, shares, base, W0, spread)
        else:
            for c in range(nc):
                corner_stencil(c, X, xp, shares, base, W0, spread)
        return base, W0, GS, xp, shares, spread

    @ti.func
    def node(st, off):
        """off = (corner bits, node offset bits): node base_c + offset, w = share_c N_i(x_c), grad = N_i(x_c) g_c."""
        base, W0, GS, xp, shares, spread = st
        c = 0
        for a in ti.static(range(dim)):
            c += off[a] << a
        I = ti.Vector.zero(int, dim)
        N = 1.0
        grad = ti.Vector.zero(float, dim)
        r = ti.Vector.zero(float, dim)
        for a in ti.static(range(dim)):
            k = off[dim + a]
            I[a] = base[c, a] + k
            w0 = W0[c, a]
            N *= w0 + ti.cast(k, float) * (1.0 - 2.0 * w0)   # k = 0: w0, k = 1: 1 - w0
            grad[a] = GS[c, a]
            r[a] = lower[a] + basis.coord(I[a], n_cells[a]) * dx - xp[a]
        wc = share
        if ti.static(tracked):
            wc = shares[c]
        return I, wc * N, N * grad, r

    @ti.func
    def inertia(st):
        """D_p = sum_c share_c diag(t (1 - t)) dx^2 + spread (t: the corner's coordinate within its cell, i.e. the
        linear hat's own second moment at x_c, plus the corners' spread about x_p)."""
        base, W0, GS, xp, shares, spread = st
        D = spread
        for c in ti.static(range(nc)):
            for a in ti.static(range(dim)):
                D[a, a] += shares[c] * W0[c, a] * (1.0 - W0[c, a]) * dx * dx
        return D

    @ti.func
    def inertia_inverse(st):
        return inertia(st).inverse()   # positive definite while the domain has volume

    span = [2] * (2 * dim)
    outer, inner = loops(span, ctx.unroll)
    return Stencil(span, outer, inner, at, node, inertia, inertia_inverse, flat_index(span), 4 ** dim,
                   advance=_corner_advance(ctx, corners, unrolled) if tracked else None)


def _corner_advance(ctx: KernelContext, corners, unrolled: bool):
    """cpdi2's advance (Stencil.advance): (read_v) -> @ti.func (p, st, dt) -> the new x_p after moving each
    corner with the node velocities read_v(p, I) at it (the linear weights `at` found), the corners written back;
    the particle at its new centroid. A domain that folded (det J <= 0 at a Gauss point) sets the failure flag with
    FOLD_CODE here, from the geometry the centroid needs anyway (another evaluation in the G2P checks added 10 s to
    a 3D compile)."""
    dim = ctx.dim
    nc = 2 ** dim
    node_bits = list(itertools.product(range(2), repeat=dim))
    centroid = make_centroid(dim)
    fail, n_codes = getattr(ctx, "fail", None), getattr(ctx, "fail_codes", 8)   # the solver's failure flag

    def advance(read_v):
        @ti.func
        def move_corner(p, c, base: ti.template(), W0: ti.template(), dt, X: ti.template()):
            vc = ti.Vector.zero(float, dim)
            for k in ti.static(node_bits):
                N = 1.0
                I = ti.Vector.zero(int, dim)
                for a in ti.static(range(dim)):
                    N *= W0[c, a] if k[a] == 0 else 1.0 - W0[c, a]
                    I[a] = base[c, a] + k[a]
                vc += N * read_v(p, I)
            for a in ti.static(range(dim)):
                X[c, a] += dt * vc[a]

        @ti.func
        def move(p, st, dt):
            base, W0, GS, xp, shares, spread = st
            X = corners[p]
            if ti.static(unrolled):
                for c in ti.static(range(nc)):
                    move_corner(p, c, base, W0, dt, X)
            else:
                for c in range(nc):
                    move_corner(p, c, base, W0, dt, X)
            corners[p] = X
            out, det_min = centroid(X)
            if not det_min > 0.0:   # NaN included: the flag keeps the smallest code, non-finite values (2) first
                ti.atomic_min(fail[None], p * n_codes + FOLD_CODE)
            return out
        return move
    return advance


def make_domain_check(ctx: KernelContext):
    """@ti.func (p, xp, Fp) -> CORNER_CODE when a corner of the particle's domain lies beyond a wall (by more than
    tol), else 0 (also for bases without corners; a folded cpdi2 domain is flagged where its corners move)."""
    dim, dx = ctx.dim, ctx.dx
    cpdi = ctx.basis.kind == "corners"   # particle-domain corners
    corners = ctx.extra.get("corners")
    tracked = corners is not None
    half_width = domain_half_width(ctx)
    lower, upper = ctx.lower, ctx.upper
    signs = corner_signs(dim)
    # A corner a little past a wall is harmless: its cell is clamped to the wall cell, whose linear functions
    # extrapolate with partition of unity and linear reproduction intact (weights down to -tol / dx). A body
    # pressed against a sticky wall has such corners: x_p - F_p r0 misses the material point on the wall by the
    # displacement's curvature, u'' r0^2 / 2 (G = 0.05 manufactured solution: 5e-5 dx at 16 cells, ~dx^2).
    # A hundredth of a cell admits that and still stops a domain that has truly crossed.
    tol = CPDI_CORNER_TOL * dx

    @ti.func
    def check(p, xp, Fp):
        code = 0
        if ti.static(cpdi):
            X = ti.Matrix.zero(float, 2 ** dim, dim)
            if ti.static(tracked):
                X = corners[p]
            else:
                A = Fp * (half_width(p) * dx)
                for c in ti.static(range(2 ** dim)):
                    xc = xp + A @ ti.Vector(signs[c])
                    for a in ti.static(range(dim)):
                        X[c, a] = xc[a]
            for c in ti.static(range(2 ** dim)):
                xc = ti.Vector([X[c, a] for a in range(dim)])
                if (xc < lower - tol).any() or (xc > upper + tol).any():
                    code = CORNER_CODE
        return code
    return check
