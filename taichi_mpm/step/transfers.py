"""The transfers between particles and grid: P2G (mass, momentum, force impulse), G2P (velocity by PIC, FLIP or
APIC; positions, F, checks) and MUSL's second P2G of the updated momentum. An extension's
ParticleTransfer (step.moments; the crack finder's, near a discontinuity) takes the particles it names over; its
NodeFields (multi-field contact's body fields) get each particle's node contributions too and give G2P its
velocities.

The stencil loop: `for o in ti.grouped(ti.ndrange(*outer))` then `for k in ti.static(range(len(inner)))` with
off = o + inner[k]; solver.unroll chooses the split (stencils._loops; costs in docs/performance.md).

Physics code only: no CLI, rendering or file I/O here.
"""

from typing import Callable, NamedTuple

import taichi as ti
from taichi.lang.matrix import make_matrix

from .. import traced
from ..bases import separable
from ..bases.corners import make_domain_check
from ..bases.stencils import make_wall_hold
from ..schemes.gradient import make_gradient
from .affine import gradient_affine

FLUID_J_MIN = 0.2           # a weakly compressible fluid squeezed below this volume ratio has collapsed
DEFORM_F, DEFORM_X = 2, 3   # g2p's deform for one half of the update (USF: F before the forces, x after them)


def make_add(coloured: bool):
    """@ti.func (g, I, value): g[I] += value."""
    @ti.func
    def add(g: ti.template(), I, value):
        """g[I] += value: a plain add when P2G scatters by colours (no other thread touches the node, see
        scatter.py), else an atomic one."""
        if ti.static(coloured):
            g[I] = g[I] + value
        else:
            g[I] += value
    return add


def make_external_force(ctx, mf):
    """@ti.func (p) -> body force and traction on the particle (N); gravity is a potential (see energy_balance)."""
    dim, vol0, body_acc, load = ctx.dim, ctx.vol0, ctx.body_acc, ctx.load
    has_body_acc, has_load = body_acc is not None, ctx.feat.tractions
    density = mf.density

    @ti.func
    def external_force(p):
        force = ti.Vector.zero(float, dim)
        if ti.static(has_body_acc):
            force += density(p) * vol0[p] * body_acc[p]
        if ti.static(has_load):
            force += load[p]
        return force
    return external_force


def colour_loop(ctx, particle):
    """@ti.func (colour, arg) -> particle(p, arg) for every particle: of the blocks of `colour` with the coloured
    scatter (scatter.BlockBins, one kernel call per colour), else all of them (the colour is then unused)."""
    x, bins = ctx.x, ctx.bins
    coloured = bins is not None
    by_colour = bins.colour_loop(particle) if coloured else None

    @ti.func
    def loop(colour, arg):
        if ti.static(coloured):
            by_colour(colour, arg)
        else:
            for p in x:
                particle(p, arg)
    return loop


def make_p2g(ctx, mf, af, external_force):
    """Kernels p2g(kick, colour) and, for MUSL, p2g_momentum(colour)."""
    v, F, vol0, work = ctx.v, ctx.F, ctx.vol0, ctx.work
    sten, add, pt, dg = ctx.stencil, ctx.add, ctx.particle_transfer, ctx.degradation
    outer, inner = sten.outer, sten.inner
    gm, gv, gv_old, gv2 = ctx.gm, ctx.gv, ctx.gv_old, ctx.gv2
    flip, viscosity, taken, degraded = ctx.feat.flip, ctx.feat.viscosity, pt is not None, dg is not None
    asflip, nf, fs = ctx.feat.asflip, ctx.node_fields, ctx.force_sums
    keeps_old = ctx.feat.old_grid   # the momentum before forces
    own, sums = nf is not None, fs is not None
    density, kirchhoff, viscous_power = mf.density, mf.kirchhoff, mf.viscous_power
    affine, node_momentum = af.affine, af.node_momentum
    grad = make_gradient(sten, ctx.feat.mls)   # grad w, or MLS-MPM's w D_p^-1 r

    @ti.func
    def p2g_particle(p, kick):
        st = sten.at(p)
        M = grad.prepare(st)
        Fp = F[p]
        mp = density(p) * vol0[p]
        stress = -vol0[p] * kirchhoff(p, Fp)
        if ti.static(degraded):
            stress = -dg.stress(p, -stress)
        vp = v[p]
        Ap = affine(p, st)
        force_density = external_force(p)  # body force + tractions (loads.py: traction x area x ramp)
        volume = 0.0
        if ti.static(sums):   # the current volume, for the local stress difference's node sums
            volume = vol0[p] * Fp.determinant()
        if ti.static(viscosity):
            work[1][None] += kick * vol0[p] * viscous_power(p, Fp)
        modified = False
        if ti.static(taken):
            modified = pt.takes(p)
            if modified:
                pt.p2g(p, st, mp, stress, vp, Ap, force_density, kick)
        if not modified:
            for o in ti.grouped(ti.ndrange(*outer)):
              for k in ti.static(range(len(inner))):  # noqa: E111 (one loop over the stencil, see `unroll`)
                I, w, gw, r = sten.node(st, o + inner[k])
                add(gm, I, w * mp)
                mom = node_momentum(p, vp, Ap, r)
                gf = grad.force(M, w, gw, r)
                value = w * mp * mom + kick * (stress @ gf + w * force_density)
                add(gv, I, value)
                if ti.static(sums):   # the local stress difference's node sums (extensions/stress_difference.py)
                    fs.scatter(p, I, w, gf, -stress, volume)
                old = w * mp * vp
                if ti.static(asflip or not flip):   # ASFLIP's v_old, and the fold's: the affine part too
                    old = w * mp * mom
                if ti.static(keeps_old):
                    add(gv_old, I, old)
                if ti.static(own):   # an extension's node fields (multi-field contact: the particle's body field)
                    nf.scatter(p, I, w, gw, r, mp, value, old)

    @ti.func
    def p2g_momentum_particle(p, unused):
        st = sten.at(p)
        mp = density(p) * vol0[p]
        vp = v[p]
        Ap = affine(p, st)
        modified = False
        if ti.static(taken):
            modified = pt.takes(p)
            if modified:
                pt.p2g_momentum(p, st, mp, vp, Ap)
        if not modified:
            for o in ti.grouped(ti.ndrange(*outer)):
              for k in ti.static(range(len(inner))):  # noqa: E111 (one loop over the stencil, see `unroll`)
                I, w, gw, r = sten.node(st, o + inner[k])
                add(gv2, I, w * mp * node_momentum(p, vp, Ap, r))

    p2g_loop = colour_loop(ctx, p2g_particle)
    momentum_loop = colour_loop(ctx, p2g_momentum_particle)

    @ti.kernel
    def p2g(kick: float, colour: int):
        """Particles to grid: mass, momentum, and the impulse of the forces over `kick` (the leapfrog kick: the
        mean of the previous and this step's dt, half the step on the first one; see Simulation.step).
        Coloured scatter: the blocks of one colour (scatter.BlockBins), one call per colour."""
        p2g_loop(colour, kick)

    @ti.kernel
    def p2g_momentum(colour: int):
        """MUSL: map the updated particle momentum back to the grid (same weights as the first P2G)."""
        momentum_loop(colour, 0.0)

    return dict(p2g=p2g, p2g_momentum=p2g_momentum)


def make_failure_code(ctx, mf):
    """Func failure(p, xp, Fp, J, speed2): the cause code of a failed particle after G2P."""
    lower, upper = ctx.lower, ctx.upper
    out_tol = 1e-6 * ctx.dx  # a particle on a wall that round-off moves a hair beyond it has not left the domain
    fluid_j_min = FLUID_J_MIN
    domain_check = make_domain_check(ctx)
    is_fluid = mf.is_fluid

    @ti.func
    def failure(p, xp, Fp, J, speed2):
        """The cause code of a failed particle (solver.FAIL_CAUSES), 0 when it is fine."""
        code = 0
        domain_code = domain_check(p, xp, Fp)   # cpdi: a domain corner past a wall, a folded cpdi2 domain
        if not (ti.abs(J) < 1e30 and speed2 < 1e60 and xp.norm_sqr() < 1e60):  # false for NaN too
            code = 2
        elif J <= 0:
            code = 1
        elif (xp < lower - out_tol).any() or (xp > upper + out_tol).any():
            code = 3
        elif domain_code != 0:
            code = domain_code
        elif J < fluid_j_min:
            if is_fluid(p):
                code = 4
        return code

    return failure


def _moves_F(deform) -> bool:
    """g2p's deform (False, True, DEFORM_F, DEFORM_X): whether the pass updates F."""
    return deform in (True, DEFORM_F)


def moves_x(deform) -> bool:
    return deform in (True, DEFORM_X)


def make_velocity_update(ctx):
    """@ti.func (v_p, v_pic, dv) -> the new v_p of the transfer; dv = sum w (v_i - v_old_i) (FLIP, ASFLIP) or
    sum w (v*_i - v_old_i) (XPIC)."""
    f, alpha = ctx.feat, ctx.flip_blend
    flip, xpic, asflip, as_flip = f.flip, f.xpic, f.asflip, ctx.asflip[0]

    @ti.func
    def velocity(v_old, v_pic, dv):
        out = v_pic
        if ti.static(xpic):
            out = v_pic + dv
        elif ti.static(asflip):   # v_pic - dv = sum w v_old_i
            out = v_pic + as_flip * (v_old - v_pic + dv)
        elif ti.static(flip):
            a = alpha[None]
            out = a * (v_old + dv) + (1.0 - a) * v_pic
        return out
    return velocity


def make_position_update(ctx, read_v):
    """@ti.func (p, st, dt, v_pic) -> the particle's new position, after G2P set v_p: x + dt v_pic, and ASFLIP's
    correction b (v_p - v_pic); B-spline particles in a holding face's wall layer stay inside. cpdi2: its corners
    move with the node velocities read_v(p, I) at them and the particle to their domain's centroid."""
    x, v, F = ctx.x, ctx.v, ctx.F
    asflip, (_, beta_min, beta) = ctx.feat.asflip, ctx.asflip
    keep_inside = make_wall_hold(ctx)
    tracked = ctx.stencil.advance is not None
    advance = ctx.stencil.advance(read_v) if tracked else None

    @ti.func
    def position(p, st, dt, v_pic):
        out = x[p]
        if ti.static(tracked):
            out = advance(p, st, dt)
        else:
            step = v_pic
            if ti.static(asflip):   # the FLIP part moves the particle too, fully where it is not compressed
                b = beta if F[p].determinant() >= 1.0 else beta_min
                step += b * (v[p] - v_pic)
            out = keep_inside(p, x[p], x[p] + dt * step)
        return out
    return position


class NodeReads(NamedTuple):
    velocity: Callable            # @ti.func (p, I) -> v_i
    velocity_old: Callable        # @ti.func (p, I) -> FLIP's v_old_i
    gradient_velocity: Callable   # @ti.func (p, I, v_i) -> the velocity grad v is taken of
    gradient_is_velocity: bool    # that is v_i itself (no second load)


def make_node_reads(ctx) -> NodeReads:
    """The node values G2P reads for particle p: the grid's (MUSL's grad v from the remapped v2), or an
    extension's NodeFields (multi-field contact: the particle's own body field; usl only, so grad v takes v_i)."""
    gv, gv_old, vgrad, nf = ctx.gv, ctx.gv_old, ctx.vgrad, ctx.node_fields
    if nf is not None and nf.velocity is not None:
        @ti.func
        def own_grad(p, I, vi):
            return vi
        return NodeReads(nf.velocity, nf.velocity_old, own_grad, True)

    @ti.func
    def velocity(p, I):
        return gv[I]

    @ti.func
    def velocity_old(p, I):
        return gv_old[I]

    same = not ctx.feat.musl   # USL and USF: grad v of the same velocities, v_i itself (no second load)

    @ti.func
    def gradient_velocity(p, I, vi):
        res = vi
        if ti.static(not same):
            res = vgrad[I]
        return res
    return NodeReads(velocity, velocity_old, gradient_velocity, same)


def make_factorised_sums(ctx, sten, grad, reads: NodeReads, apic_gradient):
    """(p, st, o, velocity, deform) -> one run-time iteration's (v_pic, dv, B, G) terms of g2p_sums, by sum
    factorisation on a tensor stencil (bases/separable.py), for the same sums as the node-by-node loop."""
    dim, f = ctx.dim, ctx.feat
    xpic, flip, apic, v_star, gv_old = f.xpic, f.flip, f.apic, ctx.grid.vec.get("xpic_sum"), ctx.gv_old
    W, MOMENT, SLOPE = separable.WEIGHT, separable.MOMENT, separable.SLOPE
    every = tuple([W] * dim)
    read_v, read_old, read_grad = reads.velocity, reads.velocity_old, reads.gradient_velocity

    @traced.traced
    def sums(p, st, o, velocity, deform):
        base = st[0]
        values, requests = [lambda off: read_v(p, base + off)], [(0, every)]
        with_dv = velocity and (xpic or flip)
        if velocity and xpic:
            values.append(lambda off: traced.at(v_star, base + off) - traced.at(gv_old, base + off))
        elif velocity and flip:
            values.append(lambda off: read_v(p, base + off) - read_old(p, base + off))
        if with_dv:
            requests.append((1, every))
        b_at = len(requests)
        with_b = velocity and apic and not apic_gradient
        if with_b:
            requests += [(0, separable.unit_rows(dim, a, MOMENT)) for a in range(dim)]
        g_at = len(requests)
        with_g = _moves_F(deform) or (apic and apic_gradient)
        if _moves_F(deform):
            k = 0
            if not reads.gradient_is_velocity:   # MUSL: grad v of the remapped velocities
                values.append(lambda off: read_grad(p, base + off, read_v(p, base + off)))
                k = len(values) - 1
            g_row = MOMENT if grad.moment_matrix else SLOPE   # MLS: sum w v r^T, times D^-1 in grad.finish
            requests += [(k, separable.unit_rows(dim, a, g_row)) for a in range(dim)]
        elif with_g:   # MUSL velocity pass of TPIC / multilinear APIC: v2 is not mapped yet
            requests += [(0, separable.unit_rows(dim, a, SLOPE)) for a in range(dim)]
        out = separable.contract(sten.factor, st, o, sten.outer, sten.inner, values, requests)
        zero_v = make_matrix([0.0] * dim, float)
        zero_m = make_matrix([[0.0] * dim for _ in range(dim)], float)
        return (out[0], out[1] if with_dv else zero_v,
                separable.columns(out[b_at:b_at + dim]) if with_b else zero_m,
                separable.columns(out[g_at:g_at + dim]) if with_g else zero_m)

    return sums


def make_g2p(ctx, mf, af, external_force):
    """Kernel g2p(dt, kick, velocity, deform)."""
    dim = ctx.dim
    x, v, F, C, grad_v = ctx.x, ctx.v, ctx.F, ctx.C, ctx.grad_v
    sten, pt = ctx.stencil, ctx.particle_transfer
    outer, inner = sten.outer, sten.inner
    reads = make_node_reads(ctx)
    read_v, read_old, read_grad = reads.velocity, reads.velocity_old, reads.gradient_velocity
    gv_old = ctx.gv_old
    f = ctx.feat
    flip, apic, taken, has_C = f.flip, f.apic, pt is not None, C is not None
    own_grad_v = grad_v is not None
    xpic, v_star = f.xpic, ctx.grid.vec.get("xpic_sum")   # XPIC's v* (step/xpic.py)
    transfer_velocity, new_position = make_velocity_update(ctx), make_position_update(ctx, read_v)
    apic_gradient = gradient_affine(ctx)   # C_p = sum v_i grad w^T: TPIC, or APIC on multilinear weights
    works = ctx.body_acc is not None or f.tractions
    project_here = f.plastic and not ctx.project_after_g2p   # with F-bar: after its average (project_all)
    work, fail, vmax2, n_codes = ctx.work, ctx.fail, ctx.vmax2, ctx.fail_codes
    failure = make_failure_code(ctx, mf)
    grad = make_gradient(sten, f.mls)   # grad v from grad w, or MLS-MPM's w D_p^-1 r
    is_fluid, project = mf.is_fluid, mf.project
    fit = af.make_fit(read_v, mf.density)   # polypic's fit of the stencil's velocities

    # 3D with two or three axes unrolled (3D quadratic G2P 20 % faster); node by node with fewer unrolled axes
    # (the whole stencil at run time: 9.4 against 7.6 ms; 3D cubic's one unrolled axis: the same) and in 2D
    # (quadratic 2D: 1.9-2.5 against 1.8-1.9 ms): docs/performance.md, "G2P by sum factorisation"
    factorised = sten.factor is not None and dim == 3 and sum(n == 1 for n in outer) >= 2
    sums_by_axis = make_factorised_sums(ctx, sten, grad, reads, apic_gradient) if factorised else None

    @ti.func
    def g2p_sums(p, st, velocity: ti.template(), deform: ti.template()):
        """A particle's G2P sums over its stencil: (v_pic, FLIP or XPIC increment, APIC B, velocity gradient G)."""
        v_pic = ti.Vector.zero(float, dim)
        dv = ti.Vector.zero(float, dim)
        B = ti.Matrix.zero(float, dim, dim)
        G = ti.Matrix.zero(float, dim, dim)
        M = grad.prepare(st)
        for o in ti.grouped(ti.ndrange(*outer)):
            if ti.static(factorised):   # the same sums, one axis at a time (bases/separable.py)
                v_o, dv_o, B_o, G_o = sums_by_axis(p, st, o, velocity, deform)
                v_pic += v_o
                dv += dv_o
                B += B_o
                G += G_o
            else:
                for k in ti.static(range(len(inner))):
                    I, w, gw, r = sten.node(st, o + inner[k])
                    vi = read_v(p, I)
                    v_pic += w * vi
                    if ti.static(velocity and xpic):
                        dv += w * (v_star[I] - gv_old[I])
                    elif ti.static(velocity and flip):
                        dv += w * (vi - read_old(p, I))
                    if ti.static(velocity and apic and not apic_gradient):
                        B += w * vi.outer_product(r)
                    if ti.static(_moves_F(deform)):
                        G += grad.term(M, read_grad(p, I, vi), w, gw, r)
                    elif ti.static(apic and apic_gradient):  # MUSL velocity pass: v2 is not mapped yet
                        G += vi.outer_product(gw)
        return v_pic, dv, B, grad.finish(M, G)

    @ti.func
    def new_velocity(p, st, kick, v_pic, dv, B, G):
        """v_p by PIC, FLIP, APIC or XPIC, APIC's C_p or polypic's node velocities, and the work of body forces and
        tractions over the kick."""
        v_old = v[p]
        v[p] = transfer_velocity(v_old, v_pic, dv)
        if ti.static(works):
            work[0][None] += 0.5 * kick * external_force(p).dot(v_old + v[p])
        if ti.static(apic):
            if ti.static(apic_gradient):
                C[p] = G
            else:
                C[p] = B  # store_B
        fit(p, st)

    @ti.func
    def deform_particle(p, st, dt, v_pic, G, deform: ti.template()):
        """Positions x += dt v_grid, F = (I + dt grad v) F (fluids keep only J), return mapping, checks.
        deform True: both; DEFORM_F or DEFORM_X: only that (USF updates F before the forces, x after them)."""
        xp = x[p]
        if ti.static(moves_x(deform)):
            xp = new_position(p, st, dt, v_pic)
        Fp = F[p]
        if ti.static(_moves_F(deform)):
            Fp = (ti.Matrix.identity(float, dim) + dt * G) @ F[p]
        J = Fp.determinant()
        if ti.static(_moves_F(deform)):
            if is_fluid(p):
                Fp = ti.Matrix.identity(float, dim) * ti.pow(ti.abs(J), 1.0 / dim)
            if ti.static(project_here):
                Fp = project(p, Fp)
        x[p] = xp
        F[p] = Fp
        if ti.static(has_C and not apic and _moves_F(deform)):
            C[p] = G
        if ti.static(own_grad_v and _moves_F(deform)):
            grad_v[p] = G
        speed2 = v[p].norm_sqr()
        ti.atomic_max(vmax2[None], speed2)
        code = failure(p, xp, Fp, J, speed2)
        if code != 0:
            ti.atomic_min(fail[None], p * n_codes + code)

    status_values = ctx.status.values

    @ti.kernel
    def g2p(dt: float, kick: float, velocity: ti.template(), deform: ti.template()) -> ti.types.vector(2, ti.f64):
        """Grid to particles. velocity: new v (PIC, FLIP or APIC) and APIC's C, and the work of body forces
        and tractions over the kick, by the trapezoid of the old and new velocities (exact for a uniform force:
        the kinetic energy's change). deform: positions x += dt v_grid, F = (I + dt grad v) F, and checks
        (True; DEFORM_F or DEFORM_X for one of them). USL does both in one pass; MUSL does them in two passes
        around the momentum remap; USF updates F (DEFORM_F) before the forces and the rest (DEFORM_X) after them.
        Returns the step's status as it stands after the pass (StepStatus.values: the step reads it from the last
        pass where no extension acts after G2P, without a launch of its own)."""
        for p in x:
            st = sten.at(p)
            v_pic = ti.Vector.zero(float, dim)
            dv = ti.Vector.zero(float, dim)
            B = ti.Matrix.zero(float, dim, dim)
            G = ti.Matrix.zero(float, dim, dim)
            modified = False
            if ti.static(taken):   # an extension's particle (the crack finder's near a discontinuity)
                modified = pt.takes(p)
                if modified:
                    v_pic, dv, B, G = pt.g2p(p, st, deform)
            if not modified:
                v_pic, dv, B, G = g2p_sums(p, st, velocity, deform)
            if ti.static(velocity):
                new_velocity(p, st, kick, v_pic, dv, B, G)
            if ti.static(deform):
                deform_particle(p, st, dt, v_pic, G, deform)
        return status_values()

    return dict(g2p=g2p)
