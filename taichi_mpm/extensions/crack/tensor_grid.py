"""The crack finder's part of the grid solve: a tensor node mass M_i = m_i I + A_i (A_i from particles in contact),
v_i = M_i^+ p_i. The solver's one grid-solve chain (step.grid_update) takes it as its node solve on steps where a
particle is in contact (CrackFinder.node_solve_active); gravity, walls and grips follow in the chain as for every
node. With crack.friction, a node has a second velocity field, the particles in contact across it, and Coulomb
contact between the two after the chain (two_field_contact; a wall or grip that set the node's own velocity makes
that side infinitely heavy)."""

import taichi as ti

from ...friction import friction_loss
from ...materials import sym_eig
from ...step.moments import GridSolve
from ..contact.surface import TOUCH, particle_half_width, surface_gap, surface_offset
from ..grips import grip_setter
from .nodes import owner_key_funcs


def tensor_grid_solve(ctx) -> GridSolve:
    dim, grid = ctx.fields.dim, ctx.view.grid
    Arows = [grid.vec[f"A{a}"] for a in range(dim)]
    node_mark = grid.scalar["crack_mark"]
    tol = 1e-12 if ctx.view.precision == "f64" else 1e-6   # pseudo-inverse cut-off, relative
    gravity_kick, gv, wall, flip = ctx.solver.gravity_kick, grid.vec["v"], ctx.solver.wall, ctx.view.flip
    gpf, gnf, gvc, gof = (grid.vec.get(k) for k in ("crack_pf", "crack_nf", "crack_vc", "crack_of"))
    gmf, lost = grid.scalar.get("crack_mf"), ctx.friction_lost
    far_grip = _far_grip_func(ctx)
    gxm, gxf, inv_dx = grid.vec.get("crack_xm"), grid.vec.get("crack_xf"), 1.0 / ctx.view.dx
    spec = ctx.solver.basis.spec
    surface = (surface_offset(spec.degree, particle_half_width(spec, ctx.view.spacing / ctx.view.dx))
               if ctx.fields.needs.friction else None)
    mu, pair_mu = float(ctx.cc.friction), _pair_friction(ctx)
    by_pair = pair_mu is not None

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
    def has_mass_two(I, m):
        """With friction, a node whose only mass is a second field's solves too (two_field_contact)."""
        return has_mass(I, m) or gmf[I] > 0

    @ti.func
    def velocity(I, m, p):
        return solve(m, tensor(I), p)

    @ti.func
    def before_conditions(I, vel, m, kick_before, kick_after):
        gvc[I] = vel   # two_field_contact tells the nodes a wall or grip set by this (an infinitely heavy side)
        return vel

    # the cells between the second field's surface and the own field's (multi-field contact's check): without it
    # the nodes a stencil ahead of a rolling disk's contact point, whose particles face the base within the SPH
    # reach, stuck to the base
    gap = surface_gap(surface, inv_dx) if surface is not None else None

    @ti.func
    def two_field_contact(I, kick_before, kick_after):
        """Coulomb contact between node I's two velocity fields (with crack.friction): its own (mass m, velocity v
        after the chain) and the second, the particles in contact across it (mass mf, momentum with its force
        impulse pf, their normals nf, which point towards this side). The second field's velocity u = pf / mf plus
        gravity, under the walls and the grip of its particles (component 1 of the node's grip flag). Where both
        hold mass, u approaches v's side along n = nf / |nf| (a = (u - v) . n > 0) and their surfaces touch by the
        end of the step (the gap, within multi-field contact's TOUCH), the relative velocity loses
        a n and, by Coulomb's law (friction.friction_loss, the walls' and multi-field contact's), mu a of its
        tangential part s, not below zero (they stick); each field takes its share of that change by the other's
        mass (all of it where the other is held: a wall or grip set it, an infinitely heavy side), so momentum is
        kept. The friction's work, the tangential impulse at the slip it leaves, m_red loss . (s - loss) (m_red:
        the reduced mass, or the free side's), goes to the energy balance. G2P reads the second field where a
        particle in contact has a node across (two_fields.g2p): crack_pf then holds its velocity, crack_of FLIP's
        old one."""
        mf = gmf[I]
        if mf > 0:
            u = gpf[I] / mf + gravity_kick(kick_before, kick_after)
            if ti.static(flip):
                gof[I] = gof[I] / mf
            u, held_far = far_grip(I, wall(I, u))
            m, v, nf = grid.m[I], gv[I], gnf[I]
            held = (v - gvc[I]).norm_sqr() > 0
            if m > 0 and nf.norm_sqr() > 0 and not (held and held_far):
                n = nf.normalized()
                rel = u - v
                a = rel.dot(n)
                if a > 0 and gap(n, gxf[I], mf, gxm[I], m) - 2.0 * kick_after * a * inv_dx < TOUCH:
                    slip = rel - a * n
                    coefficient = mu
                    if ti.static(by_pair):   # crack.friction_pairs: the two bodies' own
                        coefficient = pair_mu(I)
                    loss = friction_loss(slip, a, coefficient)
                    change = a * n + loss   # taken off the relative velocity u - v
                    share = mf / (m + mf)   # the own field's part of it
                    m_red = m * share
                    if held:
                        share, m_red = 0.0, mf
                    elif held_far:
                        share, m_red = 1.0, m
                    u -= (1.0 - share) * change
                    if not held:   # (walls then grips, as in the chain: a held node keeps its velocity)
                        gv[I] = wall(I, v + share * change)
                        u, _ = far_grip(I, wall(I, u))
                    lost[0][None] += m_red * loss.dot(slip - loss)
            gpf[I] = u

    friction = ctx.fields.needs.friction
    return GridSolve(has_mass=has_mass_two if friction else has_mass, velocity=velocity,
                     accelerate=before_conditions if friction else None,
                     node_fields=two_field_contact if friction else None)


def _far_grip_func(ctx):
    """@ti.func (I, u) -> (u, held): the second field's velocity under the grip of its particles (component 1 of
    the node's grip flag, extensions/grips.py: a gripped body's particles in contact across a node) and whether a
    grip holds it."""
    dim, grid = ctx.fields.dim, ctx.view.grid
    given, grip_v = ctx.solver.extra.get("grip_given", []), ctx.solver.extra.get("grip_v")
    gripped = bool(given) and dim > 1
    setter = grip_setter(dim, given, grip_v, list(range(len(given)))) if gripped else None

    @ti.func
    def far_grip(I, u):
        held = False
        if ti.static(gripped):
            u, components = setter(ti.cast(grid.vec["grip"][I][1], ti.i32), u)
            held = components.sum() > 0
        return u, held
    return far_grip


def _pair_friction(ctx):
    """With crack.friction_pairs: @ti.func (I) -> the coefficient between node I's owner (its own field's interface
    body) and its second field's body (crack_sf); else None (crack.friction everywhere)."""
    table = ctx.pair_mu
    if table is None or not ctx.fields.needs.friction:
        return None
    grid, mu = ctx.view.grid, ti.field(float, table.shape)
    mu.from_numpy(table)   # (Taichi casts to the field's precision)
    owner, far = grid.scalar["crack_owner"], grid.scalar["crack_sf"]
    _, side_of = owner_key_funcs(ctx.view.precision)
    default = float(ctx.cc.friction)

    @ti.func
    def pair_mu(I):
        a, b = side_of(owner[I]) - 1, ti.cast(far[I], ti.i32) - 1
        res = ti.cast(default, float)   # a Taichi variable (a Python float would be rebound at compile time)
        if a >= 0 and b >= 0:
            res = mu[a, b]
        return res
    return pair_mu
