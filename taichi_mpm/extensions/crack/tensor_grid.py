"""The crack finder's part of the grid solve: a tensor node mass M_i = m_i I + A_i (A_i from particles in contact),
v_i = M_i^+ p_i. The solver's one grid-solve chain (step.grid_update) takes it as its node solve on steps where a
particle is in contact (CrackFinder.node_solve_active); gravity, walls and grips follow in the chain as for every
node. With crack.friction, Coulomb friction at each node between its own side and the particles in contact across
it (node_friction, after the chain: the velocity those particles read is the node's final one, a grip's included)."""

import taichi as ti

from ...friction import friction_loss
from ...materials import sym_eig
from ...step.moments import GridSolve


def tensor_grid_solve(ctx) -> GridSolve:
    dim, grid = ctx.fields.dim, ctx.view.grid
    Arows = [grid.vec[f"A{a}"] for a in range(dim)]
    node_mark = grid.scalar["crack_mark"]
    tol = 1e-12 if ctx.view.precision == "f64" else 1e-6   # pseudo-inverse cut-off, relative
    gdv, gravity_kick, gv = grid.vec.get("crack_dv"), ctx.solver.gravity_kick, grid.vec["v"]
    gpf, gnf, gvc = (grid.vec.get(k) for k in ("crack_pf", "crack_nf", "crack_vc"))
    gmf, gmw = grid.scalar.get("crack_mf"), grid.scalar.get("crack_mw")
    mu = float(ctx.cc.friction)

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
    def before_conditions(I, vel, m, kick_before, kick_after):
        gvc[I] = vel   # node_friction tells the nodes a wall or grip set by this (then keeps its loss there)
        return vel

    @ti.func
    def node_friction(I, kick_before, kick_after):
        """Coulomb friction between node I's own side (mass m = the node's, velocity v) and the particles in
        contact across it. These bring, in their normal functions Nn, mass mf = sum m_p Nn, mw = sum m_p Nn^2,
        mean velocity u = pf / mf, normals nf pointing towards this side, and normal momentum with force impulse
        p_n (P2G's across terms here). They read v along their normals, so their normal impulse here is
        J = p_n . n - mf (v - gravity's kick) . n (v alone where a wall or grip set v: it gave them no gravity);
        compressive when J > 0. Friction takes mu J of the tangential slip s = v - u: the node loses L and the
        particles across gain Nn X each, X = m L / mf (momentum kept), which moves their mean u by X mw / mf; so
        |L| = min(mu J / m, |s| mf^2 / (mf^2 + m mw)), at most what makes both sides slide together. A node a wall
        or grip set keeps its velocity (an infinitely heavy side): |X| = min(mu J / mf, |s| mf / mw). X goes to
        crack_dv (and L to crack_vc), which G2P applies. The work is the kinetic energy the particles near the
        discontinuity lose by both, summed in G2P from each one's velocity and the change it gets over all its
        nodes (a per-node sum would count (sum Nn X)^2 as sum (Nn X)^2): the energy balance's friction."""
        far, own = ti.Vector.zero(float, dim), ti.Vector.zero(float, dim)
        m, mf, mw, nf = grid.m[I], gmf[I], gmw[I], gnf[I]
        if node_mark[I] > 0 and m > 0 and mf > 0 and nf.norm_sqr() > 0:
            nh = nf.normalized()
            v = gv[I]
            held = (v - gvc[I]).norm_sqr() > 0
            v_read = v
            if not held:
                v_read = v - gravity_kick(kick_before, kick_after)
            J = gdv[I].dot(nh) - mf * v_read.dot(nh)
            if J > 0:
                rel = v - gpf[I] / mf
                slip = rel - rel.dot(nh) * nh
                if held:
                    far = friction_loss(slip * (mf / mw), J / mf, mu)
                else:
                    own = friction_loss(slip * (mf * mf / (mf * mf + m * mw)), J / m, mu)
                    gv[I] = v - own
                    far = own * (m / mf)
        if node_mark[I] > 0:   # for G2P: the reaction across, and the node's own loss (its work)
            gdv[I], gvc[I] = far, own

    friction = ctx.fields.needs.friction
    return GridSolve(has_mass=has_mass, velocity=velocity, accelerate=before_conditions if friction else None,
                     node_fields=node_friction if friction else None)
