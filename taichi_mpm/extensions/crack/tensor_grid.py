"""The grid update with a tensor node mass M_i = m_i I + A_i (A_i from particles in contact): v_i = M_i^+ p_i.
Its kernels replace the solver's grid update and MUSL remap on steps where a particle is in contact."""

from typing import Callable, NamedTuple

import taichi as ti

from ...materials import sym_eig


class TensorGrid(NamedTuple):
    grid_update: Callable   # kernel (kick_before, kick_after)
    grid_remap: Callable    # kernel (): MUSL's remapped velocities


def tensor_grid_kernels(ctx) -> TensorGrid:
    dim, grid, flip = ctx.fields.dim, ctx.view.grid, ctx.view.flip
    wall, gravity_kick = ctx.solver.wall, ctx.solver.gravity_kick   # runtime gravity (solver)
    gm, gv = grid.m, grid.vec["v"]
    gv_old, gv2 = grid.vec.get("v_old"), grid.vec.get("v2")
    Arows = [grid.vec[f"A{a}"] for a in range(dim)]
    node_mark = grid.scalar["crack_mark"]
    tol = 1e-12 if ctx.view.precision == "f64" else 1e-6   # pseudo-inverse cut-off, relative

    @ti.func
    def node_mass(I):
        A = ti.Matrix.zero(float, dim, dim)
        if node_mark[I] > 0:   # only particles in contact add to A, and their stencils are marked
            for a in ti.static(range(dim)):
                for b in ti.static(range(dim)):
                    A[a, b] = Arows[a][I][b]
        return gm[I], A

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

    @ti.kernel
    def grid_update(kick_before: float, kick_after: float):
        for I in ti.grouped(gm):
            m, A = node_mass(I)
            if m > 0 or A.norm_sqr() > 0:
                vel = solve(m, A, gv[I]) + gravity_kick(kick_before, kick_after)
                gv[I] = wall(I, vel)
                if ti.static(flip):
                    gv_old[I] = solve(m, A, gv_old[I])

    @ti.kernel
    def grid_remap():
        for I in ti.grouped(gm):
            m, A = node_mass(I)
            if m > 0 or A.norm_sqr() > 0:
                gv2[I] = wall(I, solve(m, A, gv2[I]))

    return TensorGrid(grid_update=grid_update, grid_remap=grid_remap)
