"""The crack finder's part of the grid solve: a tensor node mass M_i = m_i I + A_i (A_i from particles in contact),
v_i = M_i^+ p_i. The solver's one grid-solve chain (step.grid_update) takes it as its node solve on steps where a
particle is in contact (CrackFinder.node_solve_active); gravity, walls and grips follow in the chain as for every
node. With crack.friction, its acceleration term turns the momentum contact added at a node into the velocity it
changed there: (p_c - A v) / m, p_c the terms in P2G's momentum that only particles in contact add, v the node's
velocity from the tensor mass before gravity; the sides apart (each particle through its own side's nodes) would
give (p - p_c) / m, and M v = p. G2P's friction reads it (transfer.friction_at)."""

import taichi as ti

from ...materials import sym_eig
from ...step.moments import GridSolve


def tensor_grid_solve(ctx) -> GridSolve:
    dim, grid = ctx.fields.dim, ctx.view.grid
    Arows = [grid.vec[f"A{a}"] for a in range(dim)]
    node_mark = grid.scalar["crack_mark"]
    tol = 1e-12 if ctx.view.precision == "f64" else 1e-6   # pseudo-inverse cut-off, relative
    gdv, gravity_kick = grid.vec.get("crack_dv"), ctx.solver.gravity_kick

    @ti.func
    def tensor(I):
        A = ti.Matrix.zero(float, dim, dim)
        if node_mark[I] > 0:   # only particles in contact add to A, and their stencils are marked
            for a in ti.static(range(dim)):
                for b in ti.static(range(dim)):
                    A[a, b] = Arows[a][I][b]
        return A

    @ti.func
    def solve(m, A, vec):
        """M^+ vec for M = m I + A (symmetric positive semi-definite)."""
        res = ti.Vector.zero(float, dim)
        if A.norm_sqr() == 0:
            if m > 0:
                res = vec / m
        else:
            M = m * ti.Matrix.identity(float, dim) + A
            M = 0.5 * (M + M.transpose())
            ev, Q = sym_eig(M)
            cut = tol * ev.max()
            for k in ti.static(range(dim)):
                if ev[k] > cut:
                    q = ti.Vector([Q[a, k] for a in ti.static(range(dim))])
                    res += q.dot(vec) / ev[k] * q
        return res

    @ti.func
    def has_mass(I, m):
        return m > 0 or tensor(I).norm_sqr() > 0

    @ti.func
    def velocity(I, m, p):
        return solve(m, tensor(I), p)

    @ti.func
    def contact_change(I, vel, m, kick_before, kick_after):
        if node_mark[I] > 0 and m > 0:
            v = vel - gravity_kick(kick_before, kick_after)
            gdv[I] = (gdv[I] - tensor(I) @ v) / m
        return vel

    return GridSolve(has_mass=has_mass, velocity=velocity,
                     accelerate=contact_change if ctx.fields.needs.friction else None)
