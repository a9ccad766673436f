"""P2G and G2P of a particle near a discontinuity through the tensor weights W_ip = Nt I + (Nn - Nt) n n^T: the
@ti.funcs the solver's transfer kernels call for such particles (its ParticleTransfer: p2g, p2g_momentum, g2p).
With crack.friction, P2G adds to each node what the particles in contact across it bring (their normal momentum
and force impulse, and their mass, momentum and normals in their normal functions), and G2P gives them the
reaction of the friction the grid solve applied there (tensor_grid.node_friction)."""

from typing import Callable, NamedTuple

import taichi as ti

from ...step.transfers import moves_x


class Transfers(NamedTuple):
    p2g: Callable            # (p, st, mp, stress, vp, Ap, force_density, kick)
    p2g_momentum: Callable   # (p, st, mp, vp, Ap): MUSL's remap
    g2p: Callable            # (p, st, deform) -> (v_pic, FLIP increment, APIC B, velocity gradient)


def transfer_funcs(ctx, sf) -> Transfers:
    f, dim, sten, add, vgrad = ctx.fields, ctx.fields.dim, ctx.solver.stencil, ctx.solver.add, ctx.solver.vgrad
    normal, cent = f.normal if f.cnormal is None else f.cnormal, f.cent   # the normal of a particle in contact
    grid, flip, apic = ctx.view.grid, ctx.view.flip, ctx.view.apic
    gm, gv = grid.m, grid.vec["v"]
    gv_old, gv2 = grid.vec.get("v_old"), grid.vec.get("v2")
    Arows = [grid.vec[f"A{a}"] for a in range(dim)]
    family, tangential, normal_family = sf.family, sf.tangential, sf.normal_family
    friction = f.needs.friction
    gdv, gpf, gnf, gvc = ((grid.vec["crack_dv"], grid.vec["crack_pf"], grid.vec["crack_nf"], grid.vec["crack_vc"])
                          if friction else (None,) * 4)
    gmf, gmw = (grid.scalar["crack_mf"], grid.scalar["crack_mw"]) if friction else (None,) * 2
    lost, density, vol0 = ctx.friction_lost, ctx.solver.density, ctx.view.vol0

    @ti.func
    def momentum_origins(p, vp, Ap):
        """APIC about each family's centroid c: a node sees vp + Ap (r - c) = (vp - Ap c) + Ap r, so
        sum_i W_ip mom_i = v_p exactly; returns vp - Ap c of the tangential and the normal family."""
        vt, vn = vp, vp
        if ti.static(apic):
            ct = ti.Vector([cent[p][0, a] for a in ti.static(range(dim))])
            cn = ti.Vector([cent[p][1, a] for a in ti.static(range(dim))])
            vt, vn = vp - Ap @ ct, vp - Ap @ cn
        return vt, vn

    @ti.func
    def node_momentum(v0, Ap, r):
        mom = v0
        if ti.static(apic):
            mom = v0 + Ap @ r
        return mom

    @ti.func
    def p2g(p, st, mp, stress, vp, Ap, force_density, kick):
        """P2G of a particle near a discontinuity: mass, momentum (APIC about each family's centroid), stress
        force and body force through W_ip; the normal family's terms only for a particle in contact."""
        n = normal[p]
        fam = family(p)
        vt, vn = momentum_origins(p, vp, Ap)
        for o in ti.grouped(ti.ndrange(*sten.outer)):
          for k in ti.static(range(len(sten.inner))):  # noqa: E111 (the solver's split of the stencil loop)
            off = o + sten.inner[k]
            I, w, gw, r = sten.node(st, off)
            wt, gt = tangential(fam, off, w, gw)
            mom_t = node_momentum(vt, Ap, r)
            f_t = stress @ gt + wt * force_density
            mv = mp * wt * mom_t + kick * f_t
            dw = 0.0   # Nn - Nt
            if fam[1]:
                wn, gn = normal_family(fam, w, gw)
                dw = wn - wt
                f_n = stress @ gn + wn * force_density
                mom_n = node_momentum(vn, Ap, r)
                across = (mp * (wn * n.dot(mom_n) - wt * n.dot(mom_t)) + kick * n.dot(f_n - f_t)) * n
                mv += across
                if ti.static(friction):
                    if wt == 0:   # a node across: what this side brings to friction there (tensor_grid)
                        add(gdv, I, across)
                        add(gmf, I, mp * wn)
                        add(gmw, I, mp * wn * wn)
                        add(gpf, I, mp * wn * mom_n)
                        add(gnf, I, mp * wn * n)
                for a in ti.static(range(dim)):
                    add(Arows[a], I, mp * dw * n[a] * n)
            add(gm, I, wt * mp)   # plain adds inside the solver's colour loop (no other thread at this node)
            add(gv, I, mv)
            if ti.static(flip):
                add(gv_old, I, mp * (wt * vp + dw * n.dot(vp) * n))

    @ti.func
    def p2g_momentum(p, st, mp, vp, Ap):
        n = normal[p]
        fam = family(p)
        vt, vn = momentum_origins(p, vp, Ap)
        for o in ti.grouped(ti.ndrange(*sten.outer)):
          for k in ti.static(range(len(sten.inner))):  # noqa: E111
            off = o + sten.inner[k]
            I, w, gw, r = sten.node(st, off)
            wt, _ = tangential(fam, off, w, gw)
            mom_t = node_momentum(vt, Ap, r)
            mv = mp * wt * mom_t
            if fam[1]:
                wn, _ = normal_family(fam, w, gw)
                mv += mp * (wn * n.dot(node_momentum(vn, Ap, r)) - wt * n.dot(mom_t)) * n
            add(gv2, I, mv)

    @ti.func
    def g2p(p, st, deform: ti.template()):
        """(v_pic, FLIP increment, APIC B, velocity gradient G) with the modified functions.
        APIC's affine C of such a particle is its velocity gradient: B = G D_p makes the solver's
        C = B D_p^-1 equal G."""
        n = normal[p]
        fam = family(p)
        v_pic = ti.Vector.zero(float, dim)
        dv = ti.Vector.zero(float, dim)
        G = ti.Matrix.zero(float, dim, dim)
        # friction's changes (tensor_grid.node_friction): the reaction from the nodes across, the nodes' own loss
        reaction, own = ti.Vector.zero(float, dim), ti.Vector.zero(float, dim)
        for o in ti.grouped(ti.ndrange(*sten.outer)):
          for k in ti.static(range(len(sten.inner))):  # noqa: E111 (the solver's split of the stencil loop)
            off = o + sten.inner[k]
            I, w, gw, r = sten.node(st, off)
            wt, gt = tangential(fam, off, w, gw)
            vi = gv[I]
            vg = vi
            if ti.static(deform):  # MUSL's deform pass reads the remapped velocities
                vg = vgrad[I]
            dvi = ti.Vector.zero(float, dim)
            if ti.static(flip):
                dvi = vi - gv_old[I]
            v_pic += wt * vi
            dv += wt * dvi
            if ti.static(friction):
                own -= wt * gvc[I]
            G += vg.outer_product(gt)
            if fam[1]:   # (Pt vg) gt^T + (Pn vg) gn^T
                wn, gn = normal_family(fam, w, gw)
                v_pic += (wn - wt) * n.dot(vi) * n
                dv += (wn - wt) * n.dot(dvi) * n
                G += (n.dot(vg) * n).outer_product(gn - gt)
                if ti.static(friction):
                    own -= (wn - wt) * n.dot(gvc[I]) * n
                    if wt == 0:   # a node across: friction's reaction there, shared in the normal functions
                        reaction += wn * gdv[I]
        if ti.static(friction):
            if ti.static(moves_x(deform)):   # once a step (MUSL and USF read the grid twice)
                # the kinetic energy friction took from this particle: v_pic holds its own nodes' change already
                change = own + reaction
                lost[0][None] -= density(p) * vol0[p] * ((v_pic - own).dot(change) + 0.5 * change.dot(change))
            v_pic += reaction
            dv += reaction
        return v_pic, dv, G @ sten.inertia(st), G

    return Transfers(p2g=p2g, p2g_momentum=p2g_momentum, g2p=g2p)
