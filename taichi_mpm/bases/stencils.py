"""A particle's stencil as (node, weight, gradient, offset) contributions, and the context kernel builders share.

Every kernel that couples particles and nodes loops over a particle's contributions:

    st = ctx.stencil.at(p)                                  # per-particle data, computed once
    for o in ti.grouped(ti.ndrange(*ctx.stencil.outer)):
        for k in ti.static(range(len(ctx.stencil.inner))):
            I, w, grad, r = ctx.stencil.node(st, o + ctx.stencil.inner[k])   # r = x_i - x_p

so that transfers, F-bar and the crack finder are written once for every basis. A node may appear in several
contributions (CPDI: once per corner that reaches it); sums over contributions are what the method defines.

- tensor (linear, gimp, quadratic, cubic): the contribution index is the node offset per axis; `at` computes the
  per-axis weights, derivatives and offsets once, `node` multiplies them (the same work as before this interface).
  ddmp is a tensor stencil too (4 nodes per axis) whose gradient blends the linear one with the dual-domain one:
      grad_a S_ip = alpha dN_a prod_{b != a} N_b + (1 - alpha) Ds_a prod_{b != a} Ns_b,  alpha = prod_a 4 t_a (1 - t_a)
  (basis.make_ddmp; derivation in docs/bases.md). Where a node of the smoothed stencil has a partly filled dual
  domain (free surfaces), the blend moves to the linear gradient: alpha_p = max(alpha_p, 1 - min fill), fill =
  sum_q V_q N_j(x_q) / (the dual domain's volume), from a nodal-volume pass before P2G (`Stencil.prepare`), so that
  no node without material receives force. ddmp's part lives in ddmp_gradient.py, with its sub-points
  (solver.ddmp.sub_points: weights and gradient averaged over two points per axis, a 5-node stencil).
- cpdi (CPDI1 and CPDI2): the linear grid functions sampled at the corners of each particle's domain, built in
  corners.py.
- mapped (domain.map): the rational basis R_i at the particle's parametric coordinates, (p + 1)^d control points, with
  physical gradients J^-T grad_xi R_i (the grid itself, xi_p and its Newton search are in mapped.py).

Physics code only: no CLI, rendering or file I/O here.
"""

from dataclasses import dataclass
from typing import Any, Callable

import taichi as ti
from taichi.lang.matrix import make_matrix

from .. import traced
from . import separable
from .compact_kernel import staggered_stencil
from .corners import cpdi_stencil
from .nurbs import UNROLL_TERMS
from .ddmp_gradient import ddmp_parts, volume_weights
from .stencil_parts import (AUTO_INNER, KernelContext, Stencil, domain_half_width, flat_index,  # noqa: F401
                            loops)


def make_stencil(ctx: KernelContext) -> Stencil:
    build = {"tensor": _tensor_stencil, "corners": cpdi_stencil, "mapped": _mapped_stencil,
             "staggered": staggered_stencil}[ctx.basis.kind]
    return build(ctx)


UNROLL_WORK = 1e7   # solver.unroll auto: runs of fewer particle-steps keep the whole stencil loop at run time


def resolve_unroll(setting, particle_steps: float):
    """solver.unroll as the kernels use it. `auto` weighs the run against the compile: unrolled nodes step 3D
    quadratic ~1.3-1.4x faster but compile ~2x longer (cold: 2.6 s more for 3D quadratic, 15 s for a 3D crack
    scene), which a run shorter than UNROLL_WORK particle-steps (a few seconds of stepping) does not earn back; such
    a run gets the run-time loop (`false`, same nodes in the same order). docs/performance.md, "Stencil loop"."""
    if setting == "auto" and particle_steps < UNROLL_WORK:
        return False
    return setting


# B-spline particles within WALL_LAYER x r0 (r0: half the initial particle spacing) of a face that holds material
# are transferred from that depth; the scene seeds the outer particles of a body flush against a face at r0, so only
# particles placed on a face (set_particles) or compressed to half their spacing against it are affected
WALL_LAYER = 0.5


def wall_holds(ctx: KernelContext):
    """Per axis (lower, upper): the faces that hold material (grid.make_wall_condition's `holds`), for the B-spline
    bases on the box; None otherwise (gimp cuts its domain at the walls instead; cpdi, ddmp and mapped grids keep
    their own rules)."""
    holds = getattr(ctx.wall, "holds", None)
    if ctx.basis.kind != "tensor" or not ctx.basis.spec.wall_layer or holds is None or not any(map(any, holds)):
        return None
    return holds


def make_wall_hold(ctx: KernelContext):
    """@ti.func (p, x_old, x_new) -> x_new, clamped onto a face that holds material for a particle that started in
    its wall layer (transferred from WALL_LAYER r0 inside, it moves with the velocity there, which may point
    through the face while the particle is on it); every other position as it is. The identity unless a B-spline
    basis meets such a face."""
    holds, dim, inv_dx, lower = wall_holds(ctx), ctx.dim, 1.0 / ctx.dx, ctx.lower
    n_cells, dx = ctx.n_cells, ctx.dx
    half_width = domain_half_width(ctx)
    active = holds is not None
    holds = holds or [(False, False)] * dim

    @ti.func
    def keep_inside(p, x_old, x_new):
        res = x_new
        if ti.static(active):   # selects, not branches: branches here cost g2p a tenth of a second to compile
            depth = WALL_LAYER * half_width(p)
            for a in ti.static(range(dim)):
                u_old = (x_old[a] - lower[a]) * inv_dx
                u_new = (x_new[a] - lower[a]) * inv_dx
                if ti.static(holds[a][0]):
                    res[a] = ti.select((u_old < depth) & (u_new < 0.0), lower[a], res[a])
                if ti.static(holds[a][1]):
                    res[a] = ti.select((u_old > n_cells[a] - depth) & (u_new > n_cells[a]),
                                       lower[a] + n_cells[a] * dx, res[a])
        return res
    return keep_inside


def _tensor_stencil(ctx: KernelContext) -> Stencil:
    dim, dx, inv_dx = ctx.dim, ctx.dx, 1.0 / ctx.dx
    basis, n_cells, lower = ctx.basis, ctx.n_cells, ctx.lower
    S = basis.stencil
    axes = [basis.axis(a) for a in range(dim)]   # per-axis 1D bases (knot vectors of domain.knots)
    x, F = ctx.x, ctx.F
    domain_weights, gimp_deforming = basis.spec.particle_domains, ctx.gimp_deforming   # uGIMP: lp per particle
    averaged = basis.domain_quadrature
    smooth = basis.smooth_1d is not None   # ddmp
    half_width = domain_half_width(ctx)
    holds = wall_holds(ctx)   # B-splines: per axis and side, transfer from at least WALL_LAYER r0 inside
    d_min = (1e-5 if ctx.precision == "f32" else 1e-10) * dx * dx  # smallest D_p entry inverted
    span = [S] * dim
    outer, inner = loops(span, ctx.unroll, auto_inner=AUTO_INNER)
    dual = _dual_domain_fill(ctx, span) if smooth else None
    prepare, fill = (dual.prepare, dual.fill) if smooth else (None, None)
    # ddmp's gradient (ddmp_gradient.py); with sub-points its stencil is one node wider than its 1D functions
    ddmp = ddmp_parts(basis, axes, n_cells, S, dx, half_width, F, fill) if smooth else None
    S1 = S - 1 if smooth and basis.sub_points else S

    @traced.traced
    def at(p):
        """Stencil origin (storage index), per-axis weights W[a, k], x-derivatives DW[a, k] and node offsets
        R[a, k] = (x_i - x_p)_a, so the node loop only multiplies. Built at trace time (traced.py)."""
        return axes_of(p, with_fill=True)

    def axes_of(p, with_fill):
        u = traced.local((traced.at(x, p) - lower) * inv_dx)
        base, W, DW, R = [], [], [], []
        # ddmp: smoothed weights and derivatives, blend (sub-points: their per-axis means); unused otherwise
        WS = [[0.0] * (ddmp.width if smooth else S) for _ in range(dim)]
        DS = [[0.0] * S for _ in range(dim)]
        alpha = 1.0
        for a in range(dim):
            ua = traced.at(u, a)
            # the weights of a particle a hair beyond a wall (round-off, at most the solver's out_tol) are those on
            # the wall: extrapolated ones would carry it further out (docs/bases.md, "Bodies flush against walls")
            uw = traced.local(ti.min(ti.max(ua, 0.0), ti.cast(n_cells[a], float)))
            if holds is not None and any(holds[a]):
                # a B-spline particle closer than WALL_LAYER r0 to a face that holds is transferred from that depth
                # (weights, gradients and offsets alike): on the face itself its weight on the first interior
                # control point is 0 while its gradient there is p / dx, so its stress pushed a node it gave no
                # mass (docs/bases.md "Bodies flush against walls"); make_wall_hold keeps it inside
                depth = WALL_LAYER * half_width(p)
                if holds[a][0]:
                    uw = ti.max(uw, depth)
                if holds[a][1]:
                    uw = ti.min(uw, n_cells[a] - depth)
            lp = 0.0
            if averaged:
                lp = half_width(p)   # solver.quadrature domain: the B-spline span averaged over the domain
            if domain_weights:
                lp = half_width(p)
                if gimp_deforming:
                    lp = ti.min(lp * ti.abs(traced.at(traced.at(F, p), a, a)), 0.5)
                # a particle's domain ends at the walls: otherwise interior nodes keep weight on a particle
                # at the wall and carry it through (sticky wall: out at step 1; slip floor at Mach 3). On a wall
                # the cut leaves 0, whose limit (the linear hat, gradient inside the domain) weights_1d takes.
                lp = ti.min(lp, uw, n_cells[a] - uw)
            b, w, dw = (traced.local(v) for v in axes[a].weights_1d(uw, n_cells[a], lp))   # axes[a]: its knots
            base.append(b)
            W.append([traced.at(w, k) for k in range(S1)])
            DW.append([traced.at(dw, k) * inv_dx for k in range(S1)])
            R.append([(axes[a].coord(b + k, n_cells[a]) - uw) * dx for k in range(S1)])
            if smooth:
                base[a], W[a], DW[a], R[a], WS[a], DS[a], al = ddmp.axis(p, a, uw, b, W[a], DW[a], R[a])
                alpha = alpha * al
        base = make_matrix(base, int)
        if smooth:
            alpha = ddmp.blend(alpha, base, with_fill)
        return (base, make_matrix(W, float), make_matrix(DW, float), make_matrix(R, float), make_matrix(WS, float),
                make_matrix(DS, float), alpha)

    def pick(M, a, i, start=0):
        """M[a, start + i]. Along an axis the run-time loop walks, next to unrolled ones, by selects: indexing a local
        matrix at run time moves it from registers to the stack (3D quadratic, 3 nodes unrolled: G2P 23-28 against
        14-17 ms, one thread). A loop that runs all at run time keeps the indexing (selects: G2P 16 against 13 ms).
        `start`: the first column of an S-wide block (ddmp's sub-point arrays lie side by side)."""
        if outer[a] > 1 and len(inner) > 1:
            v = traced.at(M, a, start)
            for k in range(1, S):
                v = traced.select(i == k, traced.at(M, a, start + k), v)
            return v
        return traced.at(M, a, start + i if start else i)

    @traced.traced
    def node(st, off):
        """Built at trace time (traced.py): a func would be walked once per unrolled node of every kernel."""
        base, W, DW, R, WS, DS, alpha = st
        off = traced.local(off)
        o = [traced.local(traced.at(off, a)) for a in range(dim)]
        Wo = [traced.local(pick(W, a, o[a])) for a in range(dim)]
        w = Wo[0]
        for a in range(1, dim):
            w = w * Wo[a]
        grad = []
        factors = ddmp.factors(WS, o, pick) if smooth else None
        for a in range(dim):
            g = pick(DW, a, o[a])
            for b in range(dim):
                if b != a:
                    g = g * Wo[b]
            if smooth:
                g = ddmp.gradient(g, a, o, pick, DW, factors, DS, alpha)
            grad.append(g)
        r = [pick(R, a, o[a]) for a in range(dim)]
        return base + off, w, make_matrix(grad, float), make_matrix(r, float)

    @traced.traced
    def inertia(st):
        """D_p: diagonal for tensor-product weights."""
        W, R = traced.local(st[1]), traced.local(st[3])
        return traced.diagonal([traced.total([traced.at(W, a, k) * traced.at(R, a, k) * traced.at(R, a, k)
                                              for k in range(S)]) for a in range(dim)])

    @traced.traced
    def inertia_inverse(st):
        """D_p^-1; zero along an axis where D_p vanishes (a B-spline particle exactly on a wall sits on
        the wall's control point: D_p = 0 there and B_p = 0 too, so the affine part is zero, not 0/0)."""
        D = traced.local(inertia(st))
        return traced.diagonal([traced.select(traced.at(D, a, a) > d_min, 1.0 / traced.at(D, a, a), 0.0)
                                for a in range(dim)])

    @traced.traced
    def origin(p):
        return axes_of(p, with_fill=False)[0]   # the weights are dead code here, removed by the compiler

    @traced.traced
    def factor(st, a, row, i):
        """Axis a's row at its node i (separable.py): the weight, the weight times the node offset, or the
        derivative."""
        W, DW, R = st[1], st[2], st[3]
        if row == separable.WEIGHT:
            return pick(W, a, i)
        if row == separable.MOMENT:
            return pick(W, a, i) * pick(R, a, i)
        return pick(DW, a, i)

    return Stencil(span, outer, inner, at, node, inertia, inertia_inverse, flat_index(span), S ** dim, prepare,
                   origin, dual=dual, factor=None if smooth else factor)


@dataclass
class DualDomains:
    """ddmp's dual domains (the supports of the linear hats): the node volumes V_j = sum_q V_q N_j(x_q) on a grid of
    their own (`grid.m`; with the small-node fold also its fields, layout.ddmp_grid), `prepare()` scattering them
    each step, `fill(base)` and `geometry(I)`."""
    grid: Any
    prepare: Callable
    fill: Callable       # @ti.func (base) -> the smallest V_j / V_j^dual over the real nodes of a stencil at `base`
    geometry: Callable   # @ti.func (I) -> (V_j^dual, real): the geometric dual-domain volume (dx^d, halved per wall
    #                      the node lies on) and whether I is a real node (not a ghost beyond a wall)


def _dual_domain_fill(ctx: KernelContext, span: list) -> DualDomains:
    """ddmp: prepare() scatters the nodal volumes V_j = sum_q V_q N_j(x_q) (linear weights) onto their own scalar
    grid; fill(base) is the smallest V_j / (geometric dual-domain volume) over the real nodes of a stencil starting
    at `base` (1 where every dual domain is full, 0 where a node has no material)."""
    from ..grid import Grid   # only ddmp allocates it
    from ..layout import ddmp_grid   # its declaration (budget counts the same)

    dim, dx, basis, n_cells, lower = ctx.dim, ctx.dx, ctx.basis, ctx.n_cells, ctx.lower
    x, F, vol0 = ctx.x, ctx.F, ctx.vol0
    S = span[0]
    spread = volume_weights(basis, [basis.axis(a) for a in range(dim)], n_cells, S, domain_half_width(ctx), F)
    decl = ddmp_grid(ctx.feat.small_node_fold > 0)
    grid = Grid(dim, ctx.grid.shape, ctx.grid.sparse, list(decl.vectors), apart=list(decl.apart),
                apart_scalars=list(decl.scalars))
    vol = grid.m
    cell = float(dx ** dim)
    inv_dx = 1.0 / dx

    @ti.kernel
    def scatter():
        for p in x:
            u = (x[p] - lower) * inv_dx
            base = ti.Vector.zero(int, dim)
            W = ti.Matrix.zero(float, dim, S)
            for a in ti.static(range(dim)):
                b, w = spread(p, a, u[a])
                base[a] = b
                for k in ti.static(range(S)):
                    W[a, k] = w[k]
            Vp = vol0[p] * F[p].determinant()
            for off in ti.static(ti.grouped(ti.ndrange(*span))):
                w = 1.0
                for a in ti.static(range(dim)):
                    w *= W[a, off[a]]
                if w > 0:
                    vol[base + off] += w * Vp

    # the fill runs in every `at` (P2G, G2P, binning): unrolled, each node's sparse-grid read adds its code to all of
    # them (3D, 64 nodes: 20 s of compile; 2D, 16: P2G and G2P 3.4 and 3.1 s against 0.45 and 0.54 s looped). Runs
    # whose stencil keeps its loop at run time (solver.unroll false or auto's short runs) loop here too; the minimum
    # is the same in any order.
    outer, inner = loops(span, False if ctx.unroll is False else "auto", auto_inner=S)

    @ti.func
    def geometry(I):
        geo = cell
        real = True
        for a in ti.static(range(dim)):
            c = I[a] - 1                          # storage index i holds node i - 1
            if c < 0 or c > n_cells[a]:
                real = False                      # a ghost node: no dual domain, no smoothed gradient
            elif c == 0 or c == n_cells[a]:
                geo *= 0.5                        # a wall node's dual domain is half a cell wide
        return geo, real

    @ti.func
    def fill(base):
        f = 1.0
        for o in ti.grouped(ti.ndrange(*outer)):
          for k in ti.static(range(len(inner))):  # noqa: E111 (one loop over the stencil, split as `unroll` does)
            I = base + o + inner[k]
            geo, real = geometry(I)
            if real:
                f = ti.min(f, vol[I] / geo)
        return ti.min(f, 1.0)

    def prepare():
        grid.clear()
        scatter()

    return DualDomains(grid, prepare, fill, geometry)


def _mapped_stencil(ctx: KernelContext) -> Stencil:
    """domain.map: the mapped grid's contributions, 3^d control points per particle (mapped.MappedGrid, given
    as ctx.extra["mapped"]: its map, the particles' xi and the smallest cell)."""
    mapped = ctx.extra["mapped"]
    mp, xi, x, d = mapped.map, mapped.xi, ctx.x, mapped.dim
    periodic, n_seam = mapped.periodic, mapped.shape[0]
    d_min = (1e-5 if ctx.precision == "f32" else 1e-10) * mapped.h_min ** 2
    span = mp.span
    count = len(mp.terms)
    index = flat_index(span)

    @ti.func
    def at(p):
        b, R, G = mp.rational(xi[p])
        J = mp.jacobian(b, G)
        return b, R, G, J.inverse().transpose(), x[p]

    @ti.func
    def node(st, off):
        ctrl = ti.static(mp.ctrl)
        b, R, G, JiT, xp = st
        I = b + off
        r = ctrl[I] - xp
        k = index(off)
        g = ti.Vector.zero(float, d)
        for a in ti.static(range(d)):
            g[a] = G[k, a]
        grad = JiT @ g
        if ti.static(periodic):
            if I[0] >= n_seam:
                I[0] -= n_seam
        return I, R[k], grad, r

    @ti.func
    def inertia(st):
        ctrl = ti.static(mp.ctrl)
        b, R, G, JiT, xp = st
        D = ti.Matrix.zero(float, d, d)
        if ti.static(count <= UNROLL_TERMS):
            for k in ti.static(range(count)):
                r = ctrl[b + ti.static(mp.offsets)[k]] - xp
                D += R[k] * r.outer_product(r)
        else:
            for k in range(count):
                r = ctrl[b + mp.term(k)] - xp
                D += R[k] * r.outer_product(r)
        return D

    @ti.func
    def inertia_inverse(st):
        """D_p^-1, regularised by d_min where D_p is (nearly) singular: a particle on a wall circle weighs only
        the wall's row of nodes, D_p has no radial extent there, and B_p none either."""
        D = inertia(st)
        if D.determinant() < d_min * (D.trace() + d_min):
            D += ti.Matrix.identity(float, d) * d_min
        return D.inverse()

    outer, inner = loops(span, ctx.unroll)
    return Stencil(span, outer, inner, at, node, inertia, inertia_inverse, index, count)

