"""CK-MPM's compact kernel (`solver.basis: ck`): Liu, Wang & Li, "CK-MPM: A Compact-Kernel Material Point Method",
ACM Trans. Graph. 44(4), 2025 (arXiv:2412.10399).

Two grids staggered by half a cell along every axis: A with nodes at the cell corners (i dx, on the walls) and B at
the cell centres ((i + 1/2) dx, with one ghost node half a cell beyond each wall). A particle weights only the 2^d
nodes of the cell it lies in on each grid (2 x 2^d nodes, against 3^d for quadratic B-splines), each by half of

    w(r) = 1 - r + sin(2 pi r) / (2 pi),   r = |x - x_i| / dx <= 1   (C2: w' = w'' = 0 at r = 0 and 1).

Along an axis the two nodes of a cell get 1 - s(t) and s(t), s(t) = t - sin(2 pi t) / (2 pi) (t: the position in
the cell): linear hats in a warped coordinate, a partition of unity on each grid. Each grid alone reproduces
linear fields only up to -+ sin(2 pi t) / (2 pi), and the two errors cancel: the average over both grids is
exact for linear fields, sum_i w_i x_i = x_p, sum_i x_i (x) grad w_i = I (tests/test_compact_kernel.py).

Storage: one grid of half-cell spacing, storage index k at (k - 1) / 2 cells (k = 0: B's ghost below the lower wall,
odd k: A's nodes, even k: B's), 2 n + 3 nodes per axis for n cells. A node is A's when every index is odd and B's
when every index is even; the mixed ones stay empty (on a sparse grid only the touched blocks are allocated, with
their empty nodes: 2^(d-1) x the nodes the two grids need).

Walls: B has no node on a wall. Its ghost nodes half a cell beyond sticky, roller and slip faces are images of the
nodes half a cell inside (`make_ghost_images`, the walls extension's GridSolve.images); A's wall nodes, and every
node of free faces and velocity walls, take the node-wise conditions of grid.make_wall_condition, as for every basis
(docs/bases.md, "CK-MPM": under the node-wise conditions alone a sticky wall kept a quarter of B's first node's
velocity and the manufactured solution converged at first order).

Physics code only: no CLI, rendering or file I/O here.
"""
import itertools
import math

import taichi as ti
from taichi.lang.matrix import make_matrix

from .. import traced
from .shape_functions import Basis
from .stencil_parts import KernelContext, Stencil, flat_index, loops

TWO_PI = 2.0 * math.pi
GRIDS = 2   # A (cell corners) and B (cell centres)


def make_compact(spec, knots=None) -> Basis:
    """The compact kernel's 1D functions on the half-cell storage grid. `weights_1d` gives the window of 4 storage
    nodes a particle's two cells span along an axis, each node with its weight on its own grid (each grid's two
    weights sum to 1; a stencil halves them); `grids_1d` the two grids' cells apiece (staggered_stencil)."""

    @ti.func
    def coord(k, n):
        return 0.5 * ti.cast(k - 1, float)

    @ti.func
    def grids_1d(u, n: ti.template()):
        """(first storage index, weights, derivatives) of the particle's cell on A, then on B. A cell's upper node
        weighs s(t) = t - sin(2 pi t) / (2 pi), ds/dt = 1 - cos(2 pi t); B's t is A's -+ 1/2, half a period of
        the sine away, so one sine and cosine serve both grids."""
        uu = ti.cast(u, float)
        i = ti.min(ti.max(int(ti.floor(uu)), 0), n - 1)          # A's cell [i, i + 1]
        j = ti.min(ti.max(int(ti.floor(uu + 0.5)), 0), n)        # B's cell [j - 1/2, j + 1/2]
        ta = uu - ti.cast(i, float)
        sin, cos = ti.sin(TWO_PI * ta) / TWO_PI, ti.cos(TWO_PI * ta)
        sa, da = ta - sin, 1.0 - cos
        sb, db = uu + 0.5 - ti.cast(j, float) + sin, 1.0 + cos
        return (2 * i + 1, ti.Vector([1.0 - sa, sa]), ti.Vector([-da, da]),
                2 * j, ti.Vector([1.0 - sb, sb]), ti.Vector([-db, db]))

    @ti.func
    def weights_1d(u, n: ti.template(), lp):
        ka, wa, da, kb, wb, db = grids_1d(u, n)
        a_first = ka < kb   # the window alternates A, B, A, B or B, A, B, A
        w = ti.select(a_first, ti.Vector([wa[0], wb[0], wa[1], wb[1]]), ti.Vector([wb[0], wa[0], wb[1], wa[1]]))
        dw = ti.select(a_first, ti.Vector([da[0], db[0], da[1], db[1]]), ti.Vector([db[0], da[0], db[1], da[1]]))
        return ti.min(ka, kb), w, dw

    return Basis(spec.name, 4, 1, False, lambda n: 2 * n + 3, coord, lambda k, n: 0.5 * (k - 1), weights_1d,
                 spec.stencil_kind, grids_1d=grids_1d, grids=GRIDS)


def staggered_stencil(ctx: KernelContext) -> Stencil:
    """Contributions indexed (g, o_1 .. o_d): node o of the particle's cell on grid g (0: A, 1: B), weight
    1/2 prod_a w_a, gradient 1/2 dw_a prod_{b != a} w_b, offset x_i - x_p. D_p = sum w r r^T is a full matrix
    (each grid's first moments do not vanish, only their sum does)."""
    dim, dx, inv_dx, lower, n_cells = ctx.dim, ctx.dx, 1.0 / ctx.dx, ctx.lower, ctx.n_cells
    x, grids_1d = ctx.x, ctx.basis.grids_1d
    span = [GRIDS] + [2] * dim
    if ctx.unroll == "auto":   # a grid's 2^d nodes unrolled, the two grids looped (3D, all 16: 2x the compile)
        outer = [GRIDS] + [1] * dim
        inner = [ti.Vector([0, *o]) for o in itertools.product(range(2), repeat=dim)]
    else:
        outer, inner = loops(span, ctx.unroll)
    count = GRIDS * 2 ** dim

    @ti.func
    def coordinate(p, a: ti.template()):
        """The particle's coordinate along axis a in cells, clamped onto the box (a particle a hair beyond a wall
        takes the wall's weights)."""
        return ti.min(ti.max((x[p][a] - lower[a]) * inv_dx, 0.0), ti.cast(n_cells[a], float))

    @ti.func
    def at(p):
        """Per grid g and axis a (row g dim + a): the cell's first storage index, its two weights, derivatives
        (per metre) and offsets x_i - x_p."""
        base = ti.Matrix.zero(int, GRIDS * dim, 1)
        W = ti.Matrix.zero(float, GRIDS * dim, 2)
        DW = ti.Matrix.zero(float, GRIDS * dim, 2)
        R = ti.Matrix.zero(float, GRIDS * dim, 2)
        for a in ti.static(range(dim)):
            uw = coordinate(p, a)
            ka, wa, da, kb, wb, db = grids_1d(uw, n_cells[a])
            base[a, 0], base[dim + a, 0] = ka, kb
            for k in ti.static(range(2)):
                W[a, k], DW[a, k] = wa[k], da[k] * inv_dx
                W[dim + a, k], DW[dim + a, k] = wb[k], db[k] * inv_dx
                R[a, k] = (0.5 * ti.cast(ka + 2 * k - 1, float) - uw) * dx
                R[dim + a, k] = (0.5 * ti.cast(kb + 2 * k - 1, float) - uw) * dx
        return base, W, DW, R

    @traced.traced
    def node(st, off):
        """Built at trace time (traced.py): as a func, each unrolled node's call copied the particle's tables (3D
        APIC's P2G and G2P took 44 s each to compile). Grid and node offsets may be run-time values: entries are
        picked by selects, never by indexing a local matrix at run time."""
        base, W, DW, R = st
        off = traced.local(off)
        g = traced.local(traced.at(off, 0))
        o = [traced.local(traced.at(off, 1 + a)) for a in range(dim)]

        def pick(M, a, k):
            """M[g dim + a, k]."""
            lo = traced.select(k == 0, traced.at(M, a, 0), traced.at(M, a, 1))
            hi = traced.select(k == 0, traced.at(M, dim + a, 0), traced.at(M, dim + a, 1))
            return traced.select(g == 0, lo, hi)

        Wo = [traced.local(pick(W, a, o[a])) for a in range(dim)]
        w = 0.5 * Wo[0]
        for a in range(1, dim):
            w = w * Wo[a]
        grad = []
        for a in range(dim):
            ga = 0.5 * pick(DW, a, o[a])
            for b in range(dim):
                if b != a:
                    ga = ga * Wo[b]
            grad.append(ga)
        I = [traced.select(g == 0, traced.at(base, a, 0), traced.at(base, dim + a, 0)) + 2 * o[a] for a in range(dim)]
        r = [pick(R, a, o[a]) for a in range(dim)]
        return make_matrix(I, int), w, make_matrix(grad, float), make_matrix(r, float)

    @ti.func
    def inertia(st):
        """Per grid a tensor product, so from the axes' moments: sum w r_a^2 on the diagonal and
        (sum w r_a)(sum w r_b) off it, each grid weighted 1/2 (summing the 2 x 2^d nodes instead took 25 s to
        compile in 3D APIC's P2G)."""
        W, R = st[1], st[3]
        D = ti.Matrix.zero(float, dim, dim)
        for g in ti.static(range(GRIDS)):
            first = ti.Vector([W[g * dim + a, 0] * R[g * dim + a, 0] + W[g * dim + a, 1] * R[g * dim + a, 1]
                               for a in range(dim)])
            for a in ti.static(range(dim)):
                row = g * dim + a
                for b in ti.static(range(dim)):
                    if ti.static(a == b):
                        D[a, a] += 0.5 * (W[row, 0] * R[row, 0] ** 2 + W[row, 1] * R[row, 1] ** 2)
                    else:
                        D[a, b] += 0.5 * first[a] * first[b]
        return D

    @ti.func
    def inertia_inverse(st):
        return inertia(st).inverse()

    @ti.func
    def origin(p):
        """The first storage node of the particle's window (both cells lie within 4 nodes of it per axis): the
        coloured scatter's bin."""
        first = ti.Vector.zero(int, dim)
        for a in ti.static(range(dim)):
            ka, _, _, kb, _, _ = grids_1d(coordinate(p, a), n_cells[a])
            first[a] = ti.min(ka, kb)
        return first

    return Stencil(span, outer, inner, at, node, inertia, inertia_inverse, flat_index(span), count, origin=origin)


# how a face reflects B's ghost nodes: every component (sticky), the normal one (roller), the normal one while the
# material moves into the face (slip; else the ghost stays a node of its own)
ALL, NORMAL, INTO = 1, 2, 3
MIRRORED = {"sticky": ALL, "roller": NORMAL, "slip": INTO}


def make_ghost_images(dim: int, n_cells: list, faces: list, reaction=None):
    """B's ghost nodes beyond sticky, roller and slip faces as images of their mirror nodes half a cell inside (the
    method of images): `fold(gm, decide, g, with_mass, gkick, measure)` before the grid solve adds each ghost's P2G
    sums to its mirror node, reflected (the momentum, force and gravity the mirrored material would give it), and
    empties the ghost; `mirror(gm, g)` after it gives the ghost the reflected velocity of its mirror node. The
    velocity the two grids interpolate on the face is then the face's (sticky: zero; roller, slip: no normal
    component), and the mirror node's equation is that of a node inside a mirrored body instead of one at a free
    surface. A corner ghost is reflected across both faces. Slip folds and mirrors only while the material moves
    into the face (`decide`: the momentum that says so). Free faces and velocity walls keep the node-wise
    conditions of grid.make_wall_condition, as friction does. `reaction` (the walls' per-face impulse for wall
    probes, or None): a measured fold adds each face's reflection of the ghost's momentum, B's share of the wall's
    impulse (A's wall nodes give theirs through the node-wise condition). None when no face reflects."""
    kinds = [[MIRRORED.get(faces[a][side], 0) for side in range(2)] for a in range(dim)]
    reflects = [[k > 0 for k in axis] for axis in kinds]
    if not any(map(any, reflects)):
        return None
    ghost = [(0, 2 * n + 2) for n in n_cells]     # storage index of B's ghost below and above each axis' walls
    image = [(2, 2 * n) for n in n_cells]         # and of its mirror node inside
    measuring = reaction is not None

    @ti.func
    def reflect(I, v, p, measure: ti.template()):
        """(v reflected across every face ghost I lies beyond, whether a slip face there sees p move out); measured:
        each face's change of v into its reaction slot."""
        out = False
        for a in ti.static(range(dim)):
            for side in ti.static(range(2)):
                if ti.static(reflects[a][side]):
                    if I[a] == ghost[a][side]:
                        before = v
                        if ti.static(kinds[a][side] == ALL):
                            v = -v
                        else:
                            v[a] = -v[a]
                            if ti.static(kinds[a][side] == INTO):
                                out = out or (p[a] > 0 if ti.static(side == 0) else p[a] < 0)
                        if ti.static(measure and measuring):
                            reaction[2 * a + side] += v - before
        return v, out

    @ti.func
    def mirror_of(I):
        J, beyond = I, False
        for a in ti.static(range(dim)):
            for side in ti.static(range(2)):
                if ti.static(reflects[a][side]):
                    if I[a] == ghost[a][side]:
                        J[a], beyond = image[a][side], True
        return J, beyond

    @ti.func
    def fold(gm: ti.template(), decide: ti.template(), g: ti.template(), with_mass: ti.template(), gkick,
             measure: ti.template()):
        """with_mass: g is the momentum the grid solve will add gravity to (gkick per unit mass); the mirrored
        material's gravity is reflected too, so the ghost's is folded in reflected and taken out again."""
        for I in ti.grouped(g):
            J, beyond = mirror_of(I)
            if beyond:
                mI = gm[I]   # the ghost's mass (the momentum fold runs last: FLIP's fold decides as it will)
                p = decide[I] + decide[J] + (mI + gm[J]) * gkick
                _, out = reflect(I, p, p, False)
                if not out:
                    if ti.static(with_mass):
                        v, _ = reflect(I, g[I] + mI * gkick, p, measure)
                        g[J] += v - mI * gkick
                        gm[J] += mI
                        gm[I] = 0.0
                    else:
                        v, _ = reflect(I, g[I], p, False)
                        g[J] += v
                    g[I] = ti.Vector.zero(float, dim)

    @ti.func
    def mirror(gm: ti.template(), g: ti.template()):
        for I in ti.grouped(g):
            J, beyond = mirror_of(I)
            if beyond and gm[I] == 0 and gm[J] > 0:   # folded (a ghost that kept its mass solved itself)
                g[I], _ = reflect(I, g[J], g[J], False)
    return fold, mirror
